"""Whole units: two ``atris run`` processes (simulator backend) on vcan0.

The test reads their frames as the controller would (cantools, shipped DBC, independent
E2E model) and checks that both reach RUNNING (within START_S of starting, then heard for
LISTEN_S more; stopped with SIGINT) on different codes and end RUNNING, or in a
FAULT whose only cause is DeadlineMiss (a starved loop: with another CPU-heavy process
beside the VM one unit's last Status said so, which is the unit doing its job). How many
measurements the simulator delivers without KVM, and their data age, is recorded, not
asserted.
"""

from __future__ import annotations

import os
import signal
from typing import Any

import can
import cantools
import pytest
from e2e_reference import P01Receiver
from unit_frames import DBC_PATH, IN_ORDER, Received, check_and_decode, listen, until_every_unit
from vcan_support import starved_vm_settings

from atris_node.bus.can.ids import FrameKind, frame_id

pytestmark = pytest.mark.vcan

UNIT_IDS = (6, 7)
#: seconds both units may take to be heard RUNNING once they said ready (the emulated CPUs
#: of the test VM: a unit's windows restart while its loop is late for the projector's lease)
START_S = 240.0
#: seconds the test listens once both were heard RUNNING
LISTEN_S = 20.0
#: the units' --duration, a cap only: the test stops them with SIGINT when it has listened
RUN_S = START_S + LISTEN_S + 30.0
STATE_RUNNING = 2
STATE_FAULT = 4
FAULT_SIGNALS = ("Fault_CameraLost", "Fault_LaserFault", "Fault_DeadlineMiss",
                 "Fault_PlanConflict", "Fault_ForeignCode", "Fault_Calibration")


def run_args(unit_id: int) -> list[str]:
    settings = {"bus.interface": "socketcan", "bus.channel": "vcan0", "unit.unit_id": unit_id,
                "unit.name": 0x0A70_0000_0000_0000 + unit_id, "unit.label": f"u{unit_id}",
                "code.length": 8, "driver.seed": unit_id,
                # paced, the small scene, a wide strobe margin (vcan_support): unpaced, the
                # emulated CPUs took longer than the projector's lease for a sub-frame now
                # and then, windows restarted dark (correctly: DeadlineMiss), and in two of
                # four runs of 50 s a unit never reached RUNNING; paced at 30 sub-frames/s
                # on indoor_lab with a 0.05 s margin, in a VM that booted in 62 s (the
                # host loaded), both units restarted their windows for the whole 240 s
                **starved_vm_settings()}
    args = ["run", "--duration", str(RUN_S), "--json"]
    for key, value in settings.items():
        args += ["--set", f"{key}={value}"]
    return args


def last_status(frames: list[Received], unit_id: int) -> dict[str, Any]:
    mine = [f for f in frames if f.name == f"Atris{unit_id}_Status"]
    assert mine, f"unit {unit_id} sent no Status frame"
    return mine[-1].signals


def test_two_atris_run_units_negotiate_and_publish(spawn: Any, record_property: Any) -> None:
    units = [spawn("atris", *run_args(uid)) for uid in UNIT_IDS]
    for unit in units:
        unit.wait_for("ready")
    with can.Bus(interface="socketcan", channel="vcan0",
                 can_filters=[{"can_id": frame_id(6, FrameKind.STATUS), "can_mask": 0x7F8,
                               "extended": False}]) as bus:
        frames, started_s, _ = until_every_unit(bus, UNIT_IDS,
                                                lambda state: state == STATE_RUNNING, START_S)
        record_property("running_after_s", round(started_s, 1))
        frames += listen(bus, LISTEN_S)
    for unit in units:
        os.kill(unit.pid, signal.SIGINT)
    results = [unit.wait_for("done", 120.0) for unit in units]
    assert [r["exit_code"] for r in results] == [0, 0]
    receivers: dict[int, P01Receiver] = {}
    # a frame lost after it was queued makes the next one's counter jump, and the reference
    # receiver says so ("wrong_sequence"): recorded, not a failure. The unit no longer
    # skips the counter of a frame it could not queue (tests/test_bus_publisher.py -k
    # halfway); a jump was still seen (Atris7_Sectors, once, in a VM starved by two other
    # CPU-heavy processes): a frame lost on the receiving side, which E2E exists to
    # detect. A wrong CRC or a repeated counter still fails.
    received = check_and_decode(cantools.database.load_file(DBC_PATH), frames, receivers,
                                (*IN_ORDER, "wrong_sequence"))
    record_property("e2e_losses_detected", sum(
        r.verdicts.count("wrong_sequence") for r in receivers.values()))
    statuses = [last_status(received, uid) for uid in UNIT_IDS]
    summaries = [e for u in units for e in u.events if "sub_frames" in e]
    record_property("atris_run_summaries", summaries)
    qualities = [f.signals for f in received if f.name.endswith("_Quality")]
    record_property("max_measurement_counter", max(q["MeasurementCounter"] for q in qualities))
    record_property("last_states", [s["State"] for s in statuses])
    running = [[f.signals for f in received if f.name == f"Atris{uid}_Status"
                and f.signals["State"] == STATE_RUNNING] for uid in UNIT_IDS]
    assert all(running), "a unit never reported RUNNING"
    rows = [r[-1]["CodeRow"] for r in running]
    assert rows[0] != rows[1], f"both units strobe code row {rows[0]}"
    for status in statuses:
        assert status["State"] == STATE_RUNNING or starved(status), status


def starved(status: dict[str, Any]) -> bool:
    """A FAULT whose only cause is a late cycle or a silent loop (DeadlineMiss): what a
    unit must say when the machine does not give its loop the time (seen with another
    CPU-heavy process beside the test VM), not a failure of the unit."""
    others = [name for name in FAULT_SIGNALS if name != "Fault_DeadlineMiss" and status[name]]
    return status["State"] == STATE_FAULT and status["Fault_DeadlineMiss"] == 1 and not others
