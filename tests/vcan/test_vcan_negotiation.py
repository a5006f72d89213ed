"""Code negotiation among three unit processes on vcan0, one of them crashing and restarting.

Each unit reports every change of (code row, may strobe) with the time its negotiator made
it (CLOCK_MONOTONIC, one clock for every process of the machine), not the time it noticed.
From those reports the test rebuilds who strobed which code when, and checks that two
units never strobed the same code at the same time, before or after the restart.
"""

from __future__ import annotations

import itertools
import time
from typing import Any

import pytest
from vcan_support import UnitProcess

pytestmark = pytest.mark.vcan

#: (NAME, unit_id) of the three units; N = 16 async gives log2 16 = 4 codes
UNITS = (("0x1000", "1"), ("0x2000", "2"), ("0x3000", "3"))
Interval = tuple[float, float, int]  # strobing from, until (CLOCK_MONOTONIC s), code row


def wait_owned(unit: UnitProcess, timeout_s: float = 60.0) -> dict[str, Any]:
    """The first report after which ``unit`` may strobe."""
    deadline = time.monotonic() + timeout_s
    while True:
        report = unit.wait_for("state", max(deadline - time.monotonic(), 0.01))
        if report["strobe"]:
            return report


def settled_rows(units: list[UnitProcess], timeout_s: float = 30.0) -> list[int]:
    """Waits until every unit may strobe, on pairwise different rows; returns the rows.

    A unit may own a row for a while and lose it to a lower NAME that started later (it
    stops at once, the winner strobes only after its contest window), so the first owned
    rows need not be the final ones.
    """
    deadline, rows = time.monotonic() + timeout_s, list[Any]()
    while time.monotonic() < deadline:
        for unit in units:
            unit.drain()
        last = [unit.of("state")[-1] if unit.of("state") else {"strobe": False}
                for unit in units]
        rows = [r["code_row"] if r["strobe"] else None for r in last]
        if None not in rows and len(set(rows)) == len(rows):
            return [int(r) for r in rows]
        time.sleep(0.1)
    pytest.fail(f"no settled, unique codes within {timeout_s} s: {rows}")


def strobe_intervals(reports: list[dict[str, Any]], end_s: float) -> list[Interval]:
    """The (from, until, row) intervals in which a unit may strobe, from its reports."""
    intervals: list[Interval] = []
    since, row = None, 0
    for report in [*reports, {"t": end_s, "strobe": False, "code_row": None}]:
        if since is not None and (not report["strobe"] or report["code_row"] != row):
            intervals.append((since, report["t"], row))
            since = None
        if report["strobe"] and since is None:
            since, row = report["t"], report["code_row"]
    return intervals


def assert_no_shared_code(per_unit: list[list[Interval]]) -> None:
    for a, b in itertools.combinations(per_unit, 2):
        for (a0, a1, row_a), (b0, b1, row_b) in itertools.product(a, b):
            overlap = min(a1, b1) - max(a0, b0)
            assert row_a != row_b or overlap <= 0.0, f"code {row_a} strobed by two units"


def test_three_units_claim_unique_codes_and_a_restarted_unit_rejoins(
        spawn: Any, record_property: Any) -> None:
    units = [spawn("negotiator", "vcan0", name, uid, "16") for name, uid in UNITS]
    started = time.monotonic()
    settled_rows(units)
    record_property("all_owned_after_s", round(time.monotonic() - started, 3))
    time.sleep(1.0)
    units[1].drain()
    units[1].kill()
    killed_at = time.monotonic()
    reborn = spawn("negotiator", "vcan0", *UNITS[1], "16")
    rejoined = wait_owned(reborn)
    record_property("restart_to_owned_s", round(rejoined["t"] - killed_at, 3))
    settled_rows([units[0], units[2], reborn])
    finals = [u.stop() for u in (units[0], units[2], reborn)]
    assert all(f["malformed"] == 0 for f in finals)
    record_property("receive_deferrals", [f["deferrals"] for f in finals])
    ends = [time.monotonic(), killed_at, time.monotonic(), time.monotonic()]
    per_unit = [strobe_intervals(u.of("state"), end)
                for u, end in zip([*units, reborn], ends, strict=True)]
    assert_no_shared_code(per_unit)
    final_rows = [per_unit[i][-1][2] for i in (0, 2, 3)]
    assert len(set(final_rows)) == 3, f"codes after the restart not unique: {final_rows}"


def test_a_unit_whose_receive_thread_stalls_does_not_strobe_a_code_it_has_not_heard_taken(
        spawn: Any, record_property: Any) -> None:
    """The second unit's receive thread stalls 1 s on the first frame (a starved thread):
    the first unit's claim waits unread in its socket. It must hear that claim before it
    chooses and promotes a code, so the two never strobe the same one."""
    first = spawn("negotiator", "vcan0", "0x1000", "1", "16")
    wait_owned(first)
    second = spawn("negotiator", "vcan0", "0x2000", "2", "16", "1.0")
    settled_rows([first, second])
    finals = [u.stop() for u in (first, second)]
    ends = [time.monotonic()] * 2
    per_unit = [strobe_intervals(u.of("state"), end)
                for u, end in zip((first, second), ends, strict=True)]
    record_property("deferrals_of_the_stalled_unit", finals[1]["deferrals"])
    assert_no_shared_code(per_unit)
    assert finals[1]["deferrals"] > 0, "the stalled unit never waited for its socket"
    assert per_unit[1][0][2] != per_unit[0][0][2]
