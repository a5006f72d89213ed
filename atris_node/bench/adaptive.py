"""``atris bench adaptive``: adaptive code length against a fixed N = 32, per scene.

One simulated unit on an in-process virtual bus, stepped in the calling thread (not paced):
first ``--settle`` sub-frames for the adaptation to settle, then ``--measure`` sub-frames
measured. Per scene the row holds the N chosen at the end (``code_length``), the output
rate (maps whose window lies inside the measured sub-frames, per sub-frame, times the
scene's sub-frame rate, Hz), ``ms_per_frame`` (median
wall time of demodulation + pipeline + assessment per output map, rendering excluded) and
``range_rmse_m`` (camera range of the valid line samples against the simulator's truth, m;
None when no sample was valid), beside the same scene at a fixed N = 32
(``fixed32_output_hz``, ``fixed32_range_rmse_m``).
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import can
import numpy as np

from atris_node import config as cfg
from atris_node.bench import skips
from atris_node.bench.accuracy import range_errors
from atris_node.node.unit import Unit
from atris_node.types import DistortionMap, FaultBits, SubFrame

SCENES = ("indoor_lab", "window_sun", "outdoor_medium_sun", "outdoor_strong_sun")
CHANNEL = "atris-bench-adaptive"
#: longest wait for the unit's code before the settle steps start, seconds (wall clock)
OWN_TIMEOUT_S = 5.0


class _Probe:
    """Wall time spent per output map and range errors of every map of a unit."""

    def __init__(self, unit: Unit) -> None:
        self.unit = unit
        self.busy_s = 0.0
        self.frame_ms: list[float] = []
        self.errors: list[np.ndarray] = []
        self.recording = False
        self.first_sequence = 0  # maps starting before this are not counted
        self.maps = 0
        demodulate, on_map = unit._demodulate, unit._on_map

        def timed_demodulate(sub: SubFrame) -> DistortionMap | None:
            start = time.perf_counter()
            dmap = demodulate(sub)
            self.busy_s += time.perf_counter() - start
            return dmap

        def timed_on_map(dmap: DistortionMap) -> None:
            start = time.perf_counter()
            on_map(dmap)
            self.busy_s += time.perf_counter() - start
            if self.recording and dmap.first_sequence >= self.first_sequence:
                self._record(dmap)
            self.busy_s = 0.0

        unit._demodulate = timed_demodulate  # type: ignore[method-assign]
        unit._on_map = timed_on_map  # type: ignore[method-assign]

    def _record(self, dmap: DistortionMap) -> None:
        self.maps += 1
        self.frame_ms.append(self.busy_s * 1e3)
        simulator = getattr(self.unit.camera, "simulator", None)
        work = self.unit.measure
        if simulator is not None and work is not None and work.last_result is not None:
            truth = simulator.truth(dmap.last_sequence, work.pipeline.layout)
            self.errors.append(range_errors(work.last_result, truth))


def run_scene(scene: str, overrides: list[str], settle: int, measure: int) -> dict[str, Any]:
    """Settle, then measure one unit on ``scene``; the figures of one half of a row."""
    bus = can.Bus(interface="virtual", channel=f"{CHANNEL}-{scene}")
    unit = Unit(cfg.load(environ={}, overrides=[f"driver.scene={scene}",
                                                "negotiation.window_s=0.05", *overrides]), bus)
    try:
        unit.configure()
        unit.activate(threaded=False)
        probe = _Probe(unit)
        _step_until_owned(unit)
        for _ in range(settle):
            unit.step()
        probe.recording, probe.first_sequence = True, int(unit._next_seq or 0)
        for _ in range(measure):
            unit.step()
        return _figures(unit, probe, probe.maps, measure)
    finally:
        unit.shutdown()
        bus.shutdown()


def _step_until_owned(unit: Unit) -> None:
    """Step until the unit may strobe: the contest window runs on the wall clock, which the
    simulated sub-frames outpace on a fast machine (bounded by OWN_TIMEOUT_S)."""
    deadline = time.monotonic() + OWN_TIMEOUT_S
    while not unit.negotiator.may_strobe and time.monotonic() < deadline:
        unit.step()


def _figures(unit: Unit, probe: _Probe, maps: int, sub_frames: int) -> dict[str, Any]:
    rate_hz = float(getattr(unit.camera, "rate_hz", 0.0))
    errors = np.concatenate(probe.errors) if probe.errors else np.zeros(0)
    return {"code_length": int(unit.negotiator.plan.code_length),
            "output_hz": maps / sub_frames * rate_hz,
            "ms_per_frame": float(np.median(probe.frame_ms)) if probe.frame_ms else None,
            "range_rmse_m": float(np.sqrt(np.mean(errors**2))) if errors.size else None,
            "low_signal": bool(unit.status().faults & FaultBits.LOW_SIGNAL)}


def row(scene: str, settle: int, measure: int) -> dict[str, Any]:
    """The adaptive run and the fixed N = 32 run of one scene."""
    adaptive = run_scene(scene, ["adaptive.enabled=true", "code.length=16"], settle, measure)
    fixed = run_scene(scene, ["code.length=32"], settle, measure)
    return {"scene": scene, **adaptive, "fixed32_output_hz": fixed["output_hz"],
            "fixed32_ms_per_frame": fixed["ms_per_frame"],
            "fixed32_range_rmse_m": fixed["range_rmse_m"]}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), help="scene names")
    parser.add_argument("--settle", type=int, default=480, help="sub-frames to settle")
    parser.add_argument("--measure", type=int, default=384, help="sub-frames measured")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    parser.add_argument("--skips", action="store_true",
                        help="instead: what leaving out unneeded work saves (bench/skips.py)")


def _text(r: dict[str, Any]) -> str:
    def rmse(v: float | None) -> str:
        return "-" if v is None else f"{v:.4f}"
    ms = "-" if r["ms_per_frame"] is None else f"{r['ms_per_frame']:.2f}"
    return (f"{r['scene']:20s} N={r['code_length']:3d} {r['output_hz']:7.2f} Hz "
            f"{ms:>7s} ms rmse {rmse(r['range_rmse_m']):>7s} m"
            f"{' LOW_SIGNAL' if r['low_signal'] else ''} | N=32 "
            f"{r['fixed32_output_hz']:6.2f} Hz rmse {rmse(r['fixed32_range_rmse_m']):>7s} m")


def run(args: argparse.Namespace) -> int:
    if args.skips:
        print(json.dumps(skips.rows(), indent=1))
        return 0
    rows = [row(scene, args.settle, args.measure) for scene in args.scenes]
    print(json.dumps(rows, indent=1) if args.json else "\n".join(_text(r) for r in rows))
    return 0
