"""``atris bench adaptive``: adaptive code length against a fixed N = 32, per scene.

One simulated unit on an in-process virtual bus, stepped in the calling thread (not paced)
on the simulated clock (:class:`drivers.sim.SimulatedClock`): its contest windows and
time-outs count sub-frames, not wall time, so two runs of one scene and seed see the same
sub-frames and make the same choices however fast or loaded the machine is. First the unit
steps until it owns its code, then ``--settle`` sub-frames for the adaptation to settle,
then ``--measure`` sub-frames measured. Per scene the row holds:

- ``code_length``: the N in force at the end; ``measured_lengths``: the N of every map
  measured (more than one when N changed inside the measured span); ``choices``: every
  change of the plan's N seen by a map, as ``[first sub-frame, N]`` (the first map too);
- ``output_hz``: maps whose window lies inside the measured sub-frames, per sub-frame,
  times the scene's sub-frame rate (Hz);
- ``ms_per_frame``: median wall time of demodulation + pipeline + assessment per output
  map (rendering excluded);
- ``range_rmse_m``: camera range of the pipeline's valid line samples against the
  simulator's truth (m; None when no sample was valid). These are the samples before any
  verdict: under LOW_SIGNAL they are computed and withheld;
- ``published_valid``, ``published_rmse_m``, ``published_phantoms``: the VALID sector
  distances the unit published (after LOW_SIGNAL withholding) in the measured span, the
  RMSE of those against the sector truth (the nearest obstacle a line reaches in the
  sector; 0 error inside the truth's interval where the scene moves; m, None when none had
  a truth), and the VALID ones with no obstacle there or nearer than it by more than
  max(10 %, 20 cm) (:func:`atris_node.bench.safety.score_sector`);
- ``low_signal``: LOW_SIGNAL set at the end;

beside the same scene at a fixed N = 32 without adaptation (``fixed32_*``). ``--seed``
sets both runs' noise seed (``driver.seed``, reported as ``seed``); ``--set KEY=VALUE``
changes a parameter of the adaptive run only (a bad one fails as the CLI's config does).
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
from atris_node.bench.safety import score_sector, sector_truth
from atris_node.demod import PendingMap
from atris_node.node.unit import Unit
from atris_node.types import FaultBits, Measurement, SectorState, SubFrame
from drivers import sim as sim_driver

SCENES = ("indoor_lab", "window_sun", "outdoor_medium_sun", "outdoor_strong_sun")
CHANNEL = "atris-bench-adaptive"
#: longest wait for the unit's code before the settle steps start, simulated seconds
OWN_TIMEOUT_S = 5.0


class _Probe:
    """Wall time spent per output map, range errors of every map of a unit, the published
    sector distances against the truth, and the N of every map."""

    def __init__(self, unit: Unit) -> None:
        self.unit = unit
        self.busy_s = 0.0
        self.frame_ms: list[float] = []
        self.errors: list[np.ndarray] = []
        self.sector_errors: list[float] = []
        self.valid = self.phantoms = 0
        self.lengths: set[int] = set()
        self.choices: list[tuple[int, int]] = []  # (first sub-frame, N) at every change
        self.recording = False
        self.first_sequence = 0  # maps starting before this are not counted
        self.maps = 0
        self.published: Measurement | None = None
        demodulate, on_map = unit._demodulate, unit._on_map

        def timed_demodulate(sub: SubFrame) -> PendingMap | None:
            start = time.perf_counter()
            dmap = demodulate(sub)
            self.busy_s += time.perf_counter() - start
            return dmap

        def timed_on_map(pending: PendingMap) -> None:
            start = time.perf_counter()
            self.published = None
            on_map(pending)
            self.busy_s += time.perf_counter() - start
            if not self.choices or self.choices[-1][1] != pending.code_length:
                self.choices.append((pending.first_sequence, pending.code_length))
            if self.recording and pending.first_sequence >= self.first_sequence:
                self._record(pending)
            self.busy_s = 0.0

        unit._demodulate = timed_demodulate  # type: ignore[method-assign]
        unit._on_map = timed_on_map  # type: ignore[method-assign]
        unit.on_measurement = self._on_measurement

    def _on_measurement(self, measurement: Measurement) -> None:
        self.published = measurement

    def _record(self, dmap: PendingMap) -> None:
        self.maps += 1
        self.lengths.add(dmap.code_length)
        self.frame_ms.append(self.busy_s * 1e3)
        simulator = getattr(self.unit.camera, "simulator", None)
        work = self.unit.measure
        if simulator is None or work is None or work.last_result is None:
            return
        layout = work.pipeline.layout
        self.errors.append(range_errors(work.last_result,
                                        simulator.truth(dmap.last_sequence, layout)))
        if self.published is not None:
            self._score(self.published, sector_truth(simulator, (dmap.first_sequence,
                                                                 dmap.last_sequence), layout))

    def _score(self, measurement: Measurement, truth: tuple[Any, ...]) -> None:
        """Errors (m) of the published VALID sector distances against their truth."""
        for s in measurement.sectors:
            if s.state is not SectorState.VALID:
                continue
            self.valid += 1
            if "near_phantom" in score_sector(measurement.sectors, truth, s.index):
                self.phantoms += 1
            t = truth[s.index]
            if t is None:
                continue
            near, far = (float(t), float(t)) if isinstance(t, float | int) else t
            self.sector_errors.append(min(s.distance_m - near, 0.0)
                                      + max(s.distance_m - far, 0.0))


def stepped_unit(scene: str, overrides: list[str], bus: can.BusABC) -> Unit:
    """A configured, activated unit on ``scene`` to be stepped in the calling thread, on
    the simulated clock of its own camera (windows and time-outs count sub-frames)."""
    clock = sim_driver.SimulatedClock()

    def opener(name: str, **settings: Any) -> Any:
        return sim_driver.open_backend(**settings, clock=clock)

    unit = Unit(cfg.load(environ={}, overrides=[f"driver.scene={scene}",
                                                "negotiation.window_s=0.05", *overrides]),
                bus, open_backend=opener, clock=clock)
    unit.configure()
    unit.activate(threaded=False)
    return unit


def run_scene(scene: str, overrides: list[str], settle: int, measure: int) -> dict[str, Any]:
    """Settle, then measure one unit on ``scene``; the figures of one half of a row."""
    bus = can.Bus(interface="virtual", channel=f"{CHANNEL}-{scene}")
    unit = stepped_unit(scene, overrides, bus)
    try:
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
    """Step until the unit may strobe (listen + contest window), at most OWN_TIMEOUT_S of
    simulated time."""
    limit = int(OWN_TIMEOUT_S * float(getattr(unit.camera, "rate_hz", 240.0)))
    for _ in range(limit):
        if unit.negotiator.may_strobe:
            return
        unit.step()


def _rms(values: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(values**2))) if values.size else None


def _figures(unit: Unit, probe: _Probe, maps: int, sub_frames: int) -> dict[str, Any]:
    rate_hz = float(getattr(unit.camera, "rate_hz", 0.0))
    errors = np.concatenate(probe.errors) if probe.errors else np.zeros(0)
    return {"code_length": int(unit.negotiator.plan.code_length),
            "measured_lengths": sorted(probe.lengths),
            "choices": [list(c) for c in probe.choices],
            "output_hz": maps / sub_frames * rate_hz,
            "ms_per_frame": float(np.median(probe.frame_ms)) if probe.frame_ms else None,
            "range_rmse_m": _rms(errors),
            "published_valid": probe.valid,
            "published_rmse_m": _rms(np.asarray(probe.sector_errors)),
            "published_phantoms": probe.phantoms,
            "low_signal": bool(unit.status().faults & FaultBits.LOW_SIGNAL)}


def row(scene: str, settle: int, measure: int, seed: int = 1,
        settings: tuple[str, ...] = ()) -> dict[str, Any]:
    """The adaptive run (``settings``: extra KEY=VALUE for it) and the fixed N = 32 run of
    one scene, both rendered with noise seed ``seed``."""
    seeded = [f"driver.seed={seed}"]
    adaptive = run_scene(scene, [*seeded, "adaptive.enabled=true", "code.length=16",
                                 *settings], settle, measure)
    fixed = run_scene(scene, [*seeded, "code.length=32"], settle, measure)
    return {"scene": scene, "seed": seed, **adaptive,
            **{f"fixed32_{k}": fixed[k] for k in (
                "output_hz", "ms_per_frame", "range_rmse_m", "published_valid",
                "published_rmse_m", "published_phantoms")}}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), help="scene names")
    parser.add_argument("--settle", type=int, default=480, help="sub-frames to settle")
    parser.add_argument("--measure", type=int, default=384, help="sub-frames measured")
    parser.add_argument("--seed", type=int, default=1, help="noise seed of the renders (1)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a parameter of the adaptive run (repeatable), e.g. "
                             "adaptive.max_range_sigma_m=10")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    parser.add_argument("--skips", action="store_true",
                        help="instead: what leaving out unneeded work saves (bench/skips.py)")


def _text(r: dict[str, Any]) -> str:
    def rmse(v: float | None) -> str:
        return "-" if v is None else f"{v:.4f}"
    ms = "-" if r["ms_per_frame"] is None else f"{r['ms_per_frame']:.2f}"
    return (f"{r['scene']:20s} N={r['code_length']:3d} {r['output_hz']:7.2f} Hz "
            f"{ms:>7s} ms rmse {rmse(r['range_rmse_m']):>7s} m published "
            f"{r['published_valid']:4d} rmse {rmse(r['published_rmse_m']):>7s} m"
            f"{' LOW_SIGNAL' if r['low_signal'] else ''} | N=32 "
            f"{r['fixed32_output_hz']:6.2f} Hz rmse {rmse(r['fixed32_range_rmse_m']):>7s} m "
            f"published {r['fixed32_published_valid']:4d} rmse "
            f"{rmse(r['fixed32_published_rmse_m']):>7s} m")


def run(args: argparse.Namespace) -> int:
    if args.skips:
        print(json.dumps(skips.rows(), indent=1))
        return 0
    rows = [row(scene, args.settle, args.measure, args.seed, tuple(args.set))
            for scene in args.scenes]
    print(json.dumps(rows, indent=1) if args.json else "\n".join(_text(r) for r in rows))
    return 0
