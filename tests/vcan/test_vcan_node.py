"""Whole units: two ``atris run`` processes (simulator backend) on vcan0.

The test reads their frames as the controller would (cantools, shipped DBC, independent
E2E model) and checks that both end up RUNNING on different codes. How many measurements
the simulator delivers without KVM, and their data age, is recorded, not asserted.
"""

from __future__ import annotations

from typing import Any

import can
import cantools
import pytest
from e2e_reference import P01Receiver
from unit_frames import DBC_PATH, Received, check_and_decode, listen

from atris_node.bus.can.ids import FrameKind, frame_id

pytestmark = pytest.mark.vcan

UNIT_IDS = (6, 7)
RUN_S = 50.0
STATE_RUNNING = 2


def run_args(unit_id: int) -> list[str]:
    settings = {"bus.interface": "socketcan", "bus.channel": "vcan0", "unit.unit_id": unit_id,
                "unit.name": 0x0A70_0000_0000_0000 + unit_id, "unit.label": f"u{unit_id}",
                "code.length": 8, "driver.seed": unit_id}
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
        frames = listen(bus, RUN_S - 2.0)
    results = [unit.wait_for("done", 120.0) for unit in units]
    assert [r["exit_code"] for r in results] == [0, 0]
    receivers: dict[int, P01Receiver] = {}
    received = check_and_decode(cantools.database.load_file(DBC_PATH), frames, receivers)
    statuses = [last_status(received, uid) for uid in UNIT_IDS]
    summaries = [e for u in units for e in u.events if "sub_frames" in e]
    record_property("atris_run_summaries", summaries)
    qualities = [f.signals for f in received if f.name.endswith("_Quality")]
    record_property("max_measurement_counter", max(q["MeasurementCounter"] for q in qualities))
    assert [s["State"] for s in statuses] == [STATE_RUNNING, STATE_RUNNING]
    rows = [s["CodeRow"] for s in statuses]
    assert rows[0] != rows[1], f"both units strobe code row {rows[0]}"
