"""Bus-level faults on real SocketCAN: a link that goes down, and a babbling node.

- A unit's negotiator owns a code on vcan1; the link goes down (``ip link set vcan1
  down``). Its frames are refused from then on, so it must stop strobing by its next
  frame at the latest: within one re-announce period (1 s), the bound of its lease.
- Two whole ``atris run`` units publish on vcan0 while a node floods the bus with
  high-priority frames (can-utils ``cangen``, ~90 % of a 500 kbit/s bus). Whatever the
  load does to them, no unit may report RUNNING on a code another unit reports RUNNING on
  at the same time, and no distance may go out valid with a data age above the
  publisher's max age (MAX_AGE_S). A frame lost after it was queued (a receive queue
  that overflows under the flood) makes the receiver's E2E check see a counter jump
  ("wrong_sequence"), which is recorded; a wrong CRC or a repeated counter still fails.
  (One run of four beside a CPU hog once saw a jump on one Atris9_Sectors frame. Its
  likely cause, found later: a frame the unit's transmit queue refused kept its counter,
  a gap with no frame lost; the publisher now gives that counter back, shown by
  tests/test_bus_publisher.py -k halfway. A jump was still seen once in the node test,
  in a VM starved by two CPU-heavy processes: a loss on the receiving side.)

In the link test the kernel's receive error (ENETDOWN) darkens the unit first, 4-27 ms
after the link went down; the refusal lease (0.1 s of refused frames) is the second line,
shown to be needed by the host tests (tests/test_reliability_negotiation.py -k refuses).
The babble test is not shown to fail reliably without its protection (the units' receive
filters): in control runs without them, once both units owned code 2 for 1.35 s (unit
logs), once they only ran far less (2.9 s and 1.4 s RUNNING instead of 17 s).
"""

from __future__ import annotations

import collections
import itertools
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import can
import cantools
import pytest
from e2e_reference import P01Receiver
from test_load import cangen_babblers
from test_vcan_negotiation import strobe_intervals, wait_owned
from unit_frames import DBC_PATH, IN_ORDER, Received, check_and_decode, listen, until_every_unit
from vcan_support import UNIT_MAX_AGE_S, starved_vm_settings

from atris_node.bus.can.ids import FrameKind, frame_id

pytestmark = pytest.mark.vcan

REANNOUNCE_S = 1.0
#: link-down cycles tried until one catches the unit strobing: one on a quiet machine; a
#: VM starved beside a CPU-heavy process leaves the unit silent for 3-4 s at times, after
#: which it drops its laser and claims again (its own safety rule), and three attempts once
#: all missed its lit spells; the precondition only, the bounds below are not relaxed
ATTEMPTS = 8
STATE_RUNNING = 2
#: the largest distance a valid sector carries, m (raw 65532; above: no-sector, no-return,
#: invalid codes)
DISTANCE_MAX_M = 65.532
MAX_AGE_S = UNIT_MAX_AGE_S
PERIOD_S = 0.05
UNIT_IDS = (8, 9)
#: seconds the babblers flood the bus while the test listens
BABBLE_S = 26.0
#: seconds each unit may take to start (the zygote compiles the kernels before forking; if
#: that failed, each unit compiles its own in the VM, slowly beside a CPU-heavy process)
#: before it must be heard NEGOTIATING or RUNNING
START_S = 300.0
#: the units' --duration, a cap only: the test stops them with SIGINT when it has listened
RUN_S = START_S + BABBLE_S + 30.0


def wait_lit(unit: Any) -> None:
    """Until the unit's newest report says it may strobe (it may have lost the permission
    after its first claim when the VM starves it, and it claims again)."""
    unit.drain()
    states = unit.of("state")
    if not states or not states[-1]["strobe"]:
        wait_owned(unit)


@contextmanager
def link_down(iface: str) -> Iterator[float]:
    """``iface`` down for the block (the time it went down, CLOCK_MONOTONIC); up after."""
    ip = shutil.which("ip")
    if ip is None:
        pytest.fail("no `ip` command: the link cannot be taken down")
    subprocess.run([ip, "link", "set", iface, "down"], check=True)
    try:
        yield time.monotonic()
    finally:
        subprocess.run([ip, "link", "set", iface, "up"], check=True)


def test_a_unit_whose_link_goes_down_stops_strobing_within_its_lease(
        spawn: Any, record_property: Any) -> None:
    unit = spawn("negotiator", "vcan1", "0x4000", "4", "16")
    attempts = 0
    for _ in range(ATTEMPTS):
        attempts += 1
        wait_lit(unit)
        with link_down("vcan1") as down_at:
            time.sleep(REANNOUNCE_S + 1.0)
            unit.drain()
        intervals = strobe_intervals(unit.of("state"), time.monotonic())
        lit_at_down = [i for i in intervals if i[0] <= down_at < i[1]]
        if lit_at_down:
            break
    final = unit.stop()
    record_property("attempts", attempts)
    assert lit_at_down, "the unit was not strobing when the link went down: proves nothing"
    dark_after_s = lit_at_down[0][1] - down_at
    record_property("link_down_to_dark_s", round(dark_after_s, 3))
    assert dark_after_s <= REANNOUNCE_S + 0.25
    assert not [i for i in intervals if down_at < i[0] < down_at + REANNOUNCE_S + 1.0]
    record_property("bus_errors_while_down", final.get("bus_errors"))


def run_args(unit_id: int) -> list[str]:
    settings = {"bus.interface": "socketcan", "bus.channel": "vcan0", "unit.unit_id": unit_id,
                "unit.name": 0x0B80_0000_0000_0000 + unit_id, "unit.label": f"b{unit_id}",
                "code.length": 8, "driver.seed": unit_id, "publish.period_s": PERIOD_S,
                **starved_vm_settings()}
    args = ["run", "--duration", str(RUN_S), "--json"]
    for key, value in settings.items():
        args += ["--set", f"{key}={value}"]
    return args


def cycles(received: list[Received], unit_id: int) -> list[tuple[Received, list[Received]]]:
    """(status frame, the sector frames that followed it) of one unit, in order."""
    out: list[tuple[Received, list[Received]]] = []
    for frame in received:
        if frame.name == f"Atris{unit_id}_Status":
            out.append((frame, []))
        elif frame.name.startswith(f"Atris{unit_id}_Sectors") and out:
            out[-1][1].append(frame)
    return out


def running_spans(received: list[Received], unit_id: int) -> list[tuple[float, float, int]]:
    """(from, until, code row) in which the unit's status said RUNNING."""
    statuses = [f for f in received if f.name == f"Atris{unit_id}_Status"]
    spans = []
    for here, after in itertools.pairwise(statuses):
        if int(here.signals["State"]) == STATE_RUNNING:
            spans.append((here.timestamp, after.timestamp, int(here.signals["CodeRow"])))
    return spans


def wait_started(bus: can.BusABC, timeout_s: float) -> float:
    """Seconds until every unit's status frame says more than INIT (its loop runs)."""
    _, seconds, started = until_every_unit(bus, UNIT_IDS, lambda state: state != 0, timeout_s)
    if started != set(UNIT_IDS):
        pytest.fail(f"units {sorted(set(UNIT_IDS) - started)} did not leave INIT within "
                    f"{timeout_s:.0f} s")
    return seconds


def test_a_babbling_node_makes_no_unit_share_a_code_or_publish_stale_distances(
        spawn: Any, record_property: Any) -> None:
    """The babblers start only once both units' loops run (a unit still compiling its
    kernels under a CPU-heavy neighbour reports INIT, and a test that babbles over that
    proves nothing); the units are stopped with SIGINT once the babble window was heard."""
    units = [spawn("atris", *run_args(uid)) for uid in UNIT_IDS]
    for unit in units:
        unit.wait_for("ready")
    ids = [frame_id(uid, FrameKind.STATUS) for uid in UNIT_IDS]
    with can.Bus(interface="socketcan", channel="vcan0", can_filters=[
            {"can_id": i, "can_mask": 0x7FC, "extended": False} for i in ids]) as bus:
        record_property("start_s", round(wait_started(bus, START_S), 1))
        with cangen_babblers():
            frames = listen(bus, BABBLE_S)
    for unit in units:
        os.kill(unit.pid, signal.SIGINT)
    results = [unit.wait_for("done", 120.0) for unit in units]
    # a frame lost after it was queued (a receive queue overflowing under the flood): the
    # next one's counter jumps and the receiver's E2E check says so ("wrong_sequence"); a
    # wrong CRC or a repeated counter would be the unit's fault and still fails here
    receivers = dict[int, P01Receiver]()
    received = check_and_decode(cantools.database.load_file(DBC_PATH), frames, receivers,
                                (*IN_ORDER, "wrong_sequence"))
    record_property("e2e_losses_detected", sum(
        r.verdicts.count("wrong_sequence") for r in receivers.values()))
    running = [running_spans(received, uid) for uid in UNIT_IDS]
    record_property("running_s", [round(sum(b - a for a, b, _ in s), 1) for s in running])
    record_property("states_seen", [dict(collections.Counter(
        int(f.signals["State"]) for f in received if f.name == f"Atris{uid}_Status"))
        for uid in UNIT_IDS])
    assert any(running), "no unit ever ran under the load: the test proves nothing"
    slack_s = 2 * PERIOD_S
    for a0, a1, row_a in running[0]:
        for b0, b1, row_b in running[1]:
            overlap = min(a1, b1) - max(a0, b0)
            assert row_a != row_b or overlap <= slack_s, f"both RUNNING on code {row_a}"
    valid_cycles = 0
    for uid in UNIT_IDS:
        for status, sectors in cycles(received, uid):
            distances = [v for f in sectors for k, v in f.signals.items()
                         if k.startswith("Distance") and v <= DISTANCE_MAX_M + 1e-6]
            if distances:
                valid_cycles += 1
                assert int(status.signals["State"]) == STATE_RUNNING
                assert float(status.signals["DataAge"]) <= MAX_AGE_S + 0.01
    record_property("valid_cycles", valid_cycles)
    assert valid_cycles, "no distance went out valid: the age check above proves nothing"
    assert all(r["exit_code"] == 0 for r in results)
