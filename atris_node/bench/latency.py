"""``atris bench latency``: data age from the newest sub-frame to its frames on the bus.

One simulated unit paced at its sub-frame rate publishes on an in-process virtual bus; a
second bus object receives. For every measurement the age is the send time of the quality
frame that carries its counter minus the host timestamp of the newest sub-frame the
measurement used, in ms (``p50_ms``, ``p99_ms``, ``max_ms``). The send time is the stamp
python-can's virtual bus puts on the frame as it is sent (``time.time()``, brought onto
``time.monotonic()`` with an offset taken at the start). ``receive_p50_ms`` and
``receive_p99_ms`` are the same ages to the moment the receiving bus object's thread got
the frame, which adds that thread's wake-up. ``last_frame_p50_ms`` and
``last_frame_p99_ms`` are the ages at the send of the last frame of the same cycle (its
last sector frame; the frames of a cycle are encoded and sent one after the other).
``pipeline_p50_ms`` is the median time of the line-to-sector pipeline alone, the largest
share of the age.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from typing import Any

import can
import numpy as np

from atris_node import config as cfg
from atris_node.bench._timing import spread_ms
from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.can.ids import FrameKind, unit_of
from atris_node.config import WORKERS
from atris_node.errors import FrameDecodeError
from atris_node.node.unit import Unit
from atris_node.types import Measurement

CHANNEL = "atris-bench-latency"


class Arrivals(can.Listener):
    """Receive time of the first quality frame carrying each measurement counter."""

    def __init__(self) -> None:
        self.codec = FrameCodec()
        self.arrivals: dict[int, float] = {}
        self.sends: dict[int, float] = {}
        self.last_sends: dict[int, float] = {}  # the last frame of the cycle
        self._cycle: int | None = None  # counter of the cycle being received
        self._wall_to_monotonic = time.monotonic() - time.time()
        self._lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        owner = None if msg.is_extended_id else unit_of(msg.arbitration_id)
        if owner is None:
            return
        now, sent = time.monotonic(), msg.timestamp + self._wall_to_monotonic
        if owner[1] is FrameKind.STATUS:  # a cycle starts; its quality frame comes next
            self._cycle = None
        elif owner[1] is FrameKind.QUALITY:
            self._quality(msg, now, sent)
        elif self._cycle is not None:
            with self._lock:
                self.last_sends[self._cycle] = sent

    def _quality(self, msg: can.Message, now: float, sent: float) -> None:
        try:
            counter = int(self.codec.decode_message(msg).signals["MeasurementCounter"])
        except (FrameDecodeError, KeyError, ValueError):
            return
        with self._lock:
            first = counter not in self.sends
            self.arrivals.setdefault(counter, now)
            self.sends.setdefault(counter, sent)
        self._cycle = counter if first else None  # later cycles repeat the measurement

    def on_error(self, exc: Exception) -> None:
        raise exc


def measure(scene: str, seconds: float, code_length: int,
            worker: str = "thread") -> dict[str, Any]:
    """Run one unit for ``seconds`` (maps measured by ``worker``, ``pipeline.worker``)
    and return the latency row."""
    config = cfg.load(environ={}, overrides=[
        f"driver.scene={scene}", "driver.realtime=true", f"code.length={code_length}",
        f"bus.channel={CHANNEL}", f"pipeline.worker={worker}"])
    sent: dict[int, float] = {}
    pipeline_ms: list[float] = []
    arrivals = Arrivals()
    with can.Bus(interface="virtual", channel=CHANNEL) as rx, \
            can.Bus(interface="virtual", channel=CHANNEL) as tx:
        notifier = can.Notifier(rx, [arrivals], timeout=0.05)
        unit = Unit(config, tx)

        def remember(m: Measurement) -> None:
            sent[m.counter & 0xFFFF] = m.newest_time_s
            result = unit.last_result
            if result is not None:
                pipeline_ms.append(float(result.diagnostics.timings_ms.get("total", 0.0)))

        unit.on_measurement = remember
        try:
            unit.configure()
            unit.activate()
            time.sleep(seconds)
        finally:
            unit.shutdown()
            notifier.stop()
    row = _row(scene, unit, sent, arrivals.sends)
    received = _row(scene, unit, sent, arrivals.arrivals)
    row["receive_p50_ms"], row["receive_p99_ms"] = received["p50_ms"], received["p99_ms"]
    last = _row(scene, unit, sent, arrivals.last_sends)
    row["last_frame_p50_ms"], row["last_frame_p99_ms"] = last["p50_ms"], last["p99_ms"]
    row["pipeline_p50_ms"] = round(float(np.median(pipeline_ms)), 3) if pipeline_ms else None
    row["worker"] = worker
    return row


def _row(scene: str, unit: Unit, sent: dict[int, float],
         arrivals: dict[int, float]) -> dict[str, Any]:
    spread = spread_ms([1e3 * (arrivals[c] - t) for c, t in sent.items() if c in arrivals])
    shape = getattr(unit.camera, "size", (0, 0))
    return {"scene": scene, "width": shape[0], "height": shape[1],
            "samples": spread["samples"], "p50_ms": spread["p50"], "p99_ms": spread["p99"],
            "max_ms": spread["max"]}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", default="indoor_lab", help="simulator scene (640x400)")
    parser.add_argument("--seconds", type=float, default=10.0, help="run time, s")
    parser.add_argument("--code-length", type=int, default=8, help="N")
    parser.add_argument("--worker", choices=WORKERS, default="thread",
                        help="where maps are measured (pipeline.worker)")
    parser.add_argument("--json", action="store_true", help="print the row as JSON")


def run(args: argparse.Namespace) -> int:
    row = measure(args.scene, args.seconds, args.code_length, args.worker)
    print(json.dumps(row) if args.json else
          "  ".join(f"{k}={v}" for k, v in row.items()))
    return 0
