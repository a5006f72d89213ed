"""``atris bench bus [--json]``: cost of one publish cycle and the publisher's timing.

``encode`` row: microseconds to compose and encode one cycle of a unit with 8 sectors
(Status, Quality, Nearest, 4 x Sectors through cantools with E2E), median of many.
``period`` rows, one per period: a Publisher on an in-process virtual bus for
``--seconds``; a receiver on the same bus time-stamps the Status frames. Fields:
``period_ms``, ``median_ms``, ``p99_ms`` and ``max_ms`` (gaps between Status frames),
``deadline_misses`` (publisher's count), ``e2e_bad`` (frames the receiver's E2E checker
did not accept). A virtual bus does not model arbitration or bus load.
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import time
import uuid
from typing import Any

import can

from atris_node.bus.can.e2e import E2EChecker
from atris_node.bus.can.ids import FrameKind, frame_id
from atris_node.bus.can.publisher import Publisher
from atris_node.types import Measurement, SectorDistance, SectorState, UnitState, UnitStatus

STATUS = UnitStatus(UnitState.RUNNING, 3, 16, 480.0, 0)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the rows as a JSON list")
    parser.add_argument("--seconds", type=float, default=3.0, help="run time per period, s")
    parser.add_argument("--periods-ms", type=float, nargs="+", default=[50.0, 10.0],
                        help="publish periods to time, ms (default 50 10)")


def measurement(age_s: float = 0.0) -> Measurement:
    """8 valid sectors, newest sub-frame ``age_s`` seconds old."""
    sectors = tuple(SectorDistance(i, 0.0, SectorState.VALID, 1.0 + i, 0.9) for i in range(8))
    return Measurement(1, sectors, time.monotonic() - age_s, 1, nearest=sectors[0])


def encode_row(cycles: int = 2000) -> dict[str, Any]:
    """Median microseconds of composing and encoding one cycle."""
    with can.Bus(interface="virtual", channel=f"bench-{uuid.uuid4().hex}") as bus:
        publisher = Publisher(bus, 0)
        samples = []
        for _ in range(cycles):
            start = time.perf_counter()
            publisher.compose(measurement(), STATUS, time.monotonic())
            samples.append(time.perf_counter() - start)
    return {"row": "encode", "frames": 7, "us": round(statistics.median(samples) * 1e6, 1)}


def period_row(period_s: float, seconds: float) -> dict[str, Any]:
    """Timing of a running publisher with ``period_s``, observed on the bus."""
    channel = f"bench-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as tx, \
            can.Bus(interface="virtual", channel=channel) as rx:
        publisher = Publisher(tx, 1, period_s=period_s, max_age_s=seconds + 1.0)
        publisher.update(measurement(), STATUS)
        publisher.start()
        times, bad = _receive(rx, seconds)
        publisher.stop()
    gaps = sorted(b - a for a, b in itertools.pairwise(times))
    return {"row": "period", "period_ms": period_s * 1e3,
            "median_ms": round(statistics.median(gaps) * 1e3, 2),
            "p99_ms": round(gaps[int(0.99 * (len(gaps) - 1))] * 1e3, 2),
            "max_ms": round(gaps[-1] * 1e3, 2),
            "deadline_misses": publisher.stats.deadline_misses,
            "cycles": publisher.stats.cycles, "e2e_bad": bad}


def _receive(rx: can.BusABC, seconds: float) -> tuple[list[float], int]:
    status_id = frame_id(1, FrameKind.STATUS)
    checker, times, bad = E2EChecker(status_id), [], 0
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        msg = rx.recv(timeout=left)
        if msg is not None and msg.arbitration_id == status_id:
            times.append(time.monotonic())
            bad += int(not checker.check(bytes(msg.data), times[-1]).valid)
    return times, bad


def run(args: argparse.Namespace) -> int:
    rows = [encode_row()]
    rows += [period_row(p / 1e3, args.seconds) for p in args.periods_ms]
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for row in rows:
            print("  ".join(f"{k}={v}" for k, v in row.items()))
    return 0
