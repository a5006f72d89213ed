"""``atris soak``: the four-unit simulated fleet runs, reports and leaves nothing behind.

The soak runs in this process through the CLI module, so the JSON it prints is what is
checked and the conftest fixtures catch any thread or bus the fleet leaves behind. Its
targets (RSS growth <= 5 MB, deadline misses <= 0.1 %) are speed and memory figures of a
quiet machine: they are measured with ``atris soak --minutes 10 --json`` and written to
docs/reliability.md, not asserted here, because a shared test host's scheduling decides
them (the same run missed 0.016 % quiet and 3.96 % at load average 7-8).
"""

from __future__ import annotations

import argparse
import json
import math
import random
import threading

import pytest

from atris_node.cli import soak as soak_cli
from atris_node.errors import ConfigError

FIELDS = {"minutes", "units", "rss_start_mb", "rss_end_mb", "rss_growth_mb", "threads_start",
          "threads_end", "cycles", "deadline_misses", "deadline_miss_fraction", "e2e_errors",
          "measurements", "late_cycles_on_bus", "unflagged_late_cycles", "sent_late_cycles",
          "unexplained_late_cycles"}
#: seconds into the half-minute soak (after its 6 s warm-up) when the process stalls
STALL_AT_S = 12.0


def run_cli(*argv: str) -> None:
    parser = argparse.ArgumentParser()
    soak_cli.add_arguments(parser)
    assert soak_cli.run(parser.parse_args(list(argv))) == 0


def stall_the_process(done: threading.Event) -> None:
    """At STALL_AT_S, hold the GIL for about half a second (one sort of shuffled ints is one
    C call with no switch inside): every thread of the process, each unit's publisher
    included, stops. Then wait for ``done``, so the thread count is the same at the soak's
    start and end."""
    numbers = list(range(1_000_000))
    random.Random(1).shuffle(numbers)
    if not done.wait(STALL_AT_S):
        sorted(numbers)
        done.wait()


def test_half_minute_soak_reports_and_leaves_nothing_behind(
        capsys: pytest.CaptureFixture[str]) -> None:
    """The soak's numbers, and what the bus saw: a stall of the whole process half-way
    makes every unit's next Status cycle late on the bus, and each late cycle carries
    DeadlineMiss.

    A cycle whose sender was preempted after reading its clock (or stalled then) reaches
    the bus late without the bit: its sender counts it (``sent_late_cycles``, each send's
    time kept), and only such cycles may lack it: every unflagged late cycle on the bus
    must pair with one of its unit's late sends (``unexplained_late_cycles`` 0). Beside a
    busy loop, with the test suite and a scene batch on the other core, 2 late cycles on
    the bus lacked the bit (the assert was then ``unflagged_late_cycles == 0``, with a
    10 ms allowance for preemption).

    Checked by removing the protection once (``Publisher._faults`` no longer adding
    DEADLINE_MISS for a late cycle): ``unflagged_late_cycles`` was 4 of 4 late cycles and
    the test failed; with the pairing, on a loaded machine, 12 and 8 unexplained (of 24 and
    13 late cycles) in two runs, both failed, and 0 in two runs with it. The pairing
    within 10 ms of the bus timestamp then failed one fresh `make test` beside a busy loop
    (1 unexplained): a late send now pairs when it lies in its cycle, from 10 ms before
    the frame's bus timestamp to the unit's next Status frame. Checked again: without the
    bit, beside a busy loop, 4 unexplained in three runs (all failed); with it, 0 in two."""
    done = threading.Event()
    stall = threading.Thread(target=stall_the_process, args=(done,))
    stall.start()
    try:
        run_cli("--minutes", "0.5", "--json")
    finally:
        done.set()
        stall.join()
    report = json.loads(capsys.readouterr().out)
    assert set(report) >= FIELDS
    assert report["units"] == 4 and report["minutes"] == 0.5
    assert 0.0 < report["rss_start_mb"] < 4000.0 and math.isfinite(report["rss_growth_mb"])
    assert report["threads_start"] >= 1 + 4  # the main thread and one loop per unit
    assert report["threads_end"] == report["threads_start"]
    assert report["e2e_errors"] == 0
    # four units publish at 20 Hz over the 24 s after the warm-up: never more often
    assert 0 < report["cycles"] <= 1.1 * 4 * 20 * 24
    assert report["measurements"] >= 4
    assert report["late_cycles_on_bus"] >= report["units"], "the stall made no cycle late"
    assert report["unexplained_late_cycles"] == 0
    assert report["unflagged_late_cycles"] <= report["sent_late_cycles"]
    assert report["deadline_misses"] >= report["units"]  # the publishers counted them too
    assert report["deadline_miss_fraction"] == pytest.approx(
        report["deadline_misses"] / report["cycles"])


def test_minutes_out_of_range_is_a_clear_error() -> None:
    with pytest.raises(ConfigError, match="--minutes"):
        run_cli("--minutes", "0")
