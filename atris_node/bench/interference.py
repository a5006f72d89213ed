"""``atris bench interference [--maps N] [--seed S] [--cases NAME ...] [--json]``: how far
the foreign-light verdict sits from its limit, both ways.

The pipeline flags foreign light (``Diagnostics.interference``) when ``max(foreign_energy,
unassigned_fraction - moving_fraction - step_fraction)`` (the *metric*, docs/pipeline.md
section 4: the unassigned peaks that are neither moving edges of own stripes nor the
steps of a background) exceeds ``foreign_limit``. A
unit on our own code must be flagged at any fractional phase at which its pulses overlap
our exposures; our own moving stripes, flickering lamps and units on other (orthogonal)
codes must not. For each case, ``--maps`` maps of a simulated scene (block demodulation,
known lag, the pipeline's defaults) give the metric per map; the *margin* is ``min metric
/ limit`` for a case that must be flagged and ``limit / max metric`` for one that must not
(infinite when the metric is 0). Below 1 the verdict is wrong on some map; the target is 3
both ways.

Rows (JSON keys): ``case``, ``scene``, ``must_flag``, ``maps``, ``metric_min``,
``metric_median``, ``metric_max``, ``flagged`` (maps), ``limit``, ``margin`` (null when
infinite).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from atris_node.bench.safety import LAYOUT, block_maps, scene_settings
from atris_node.errors import UsageError
from atris_node.sim import load_scene
from atris_node.sim.scene import Scene

#: maps per case by default
MAPS = 4


def _neighbour(row: int, phase: float) -> Callable[[Scene], Scene]:
    """The scene's interfering unit moved to Walsh row ``row`` at ``phase`` sub-frames."""
    def change(scene: Scene) -> Scene:
        return replace(scene, interferers=tuple(
            replace(i, code_row=row, phase_sub_frames=phase) for i in scene.interferers))
    return change


def _same(scene: Scene) -> Scene:
    return scene


@dataclass(frozen=True)
class Case:
    """One situation: ``scene`` changed by ``change``; whether it must be flagged."""

    name: str
    scene: str
    must_flag: bool
    change: Callable[[Scene], Scene] = _same


#: own code row of the two-unit scenes (their unit strobes row 2 of N = 16)
OWN_ROW = 2
#: The two-unit scene's exposures are 1 ms of a 4.17 ms sub-frame: a neighbour's pulse
#: overlaps ours only within 0.24 sub-frames of phase. Beyond that its light never enters
#: our exposure (nothing to flag, nothing to harm): the metric must then be 0.
CASES: tuple[Case, ...] = (
    *(Case(f"same_code_phase_{p:g}", "two_units_orthogonal", True, _neighbour(OWN_ROW, p))
      for p in (0.0, 0.06, 0.12, 0.18, 0.22, 0.88)),
    Case("same_code_no_overlap_phase_0.5", "two_units_orthogonal", False,
         _neighbour(OWN_ROW, 0.5)),
    *(Case(f"other_code_row_{r}_phase_{p:g}", "two_units_orthogonal", False, _neighbour(r, p))
      for r, p in ((3, 1.1), (4, 0.0), (4, 0.5), (8, 0.25))),
    Case("flicker_100hz", "flicker_100hz", False),
    Case("lamps_three_flicker", "lamps_three_flicker", False),
    Case("flicker_dark_corridor", "flicker_dark_corridor", False),
    Case("own_stripes_approach_6mps", "approach_6mps", False),
    Case("own_stripes_approach_8mps", "approach_8mps", False),
    Case("own_stripes_crossing_8mps", "crossing_8mps", False),
    Case("own_stripes_pedestrian", "parking_pedestrian", False),
    Case("clean_indoor_lab", "indoor_lab", False),
)


def metrics(scene: Scene, maps: int, seed: int) -> tuple[list[float], float]:
    """The metric of the first ``maps`` maps of ``scene`` (unit 0, its own code), and the
    limit it is compared with."""
    from atris_node.pipeline.chain import Pipeline, PipelineConfig

    config = PipelineConfig(sector_count=LAYOUT.count, fov_deg=math.degrees(LAYOUT.fov_rad),
                            **scene_settings(scene))
    sim, dmaps = block_maps(scene, seed)
    pipe = Pipeline(config, sim.calibration(), sim.mounting, LAYOUT)
    out: list[float] = []
    for dmap in itertools.islice(dmaps, maps):
        diag = pipe.process(dmap).diagnostics
        out.append(foreign_metric(diag))
    return out, float(config.foreign_limit)


def foreign_metric(diag: Any) -> float:
    """The metric the pipeline's ``interference`` flag compares with ``foreign_limit``."""
    return max(float(diag.foreign_energy),
               float(diag.unassigned_fraction) - float(diag.moving_fraction)
               - float(diag.step_fraction))


def margin(values: list[float], limit: float, must_flag: bool) -> float:
    """min/limit for a case that must be flagged, limit/max for one that must not; inf
    when the metric is 0 where it must not be flagged."""
    if must_flag:
        return min(values) / limit
    worst = max(values)
    return math.inf if worst <= 0.0 else limit / worst


def measure(case: Case, maps: int, seed: int) -> dict[str, Any]:
    """The row of one case (module docstring)."""
    values, limit = metrics(case.change(load_scene(case.scene)), maps, seed)
    found = margin(values, limit, case.must_flag)
    return {"case": case.name, "scene": case.scene, "must_flag": case.must_flag,
            "maps": maps, "metric_min": round(min(values), 5),
            "metric_median": round(statistics.median(values), 5),
            "metric_max": round(max(values), 5),
            "flagged": sum(v > limit for v in values), "limit": limit,
            "margin": None if math.isinf(found) else round(found, 2)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--maps", type=int, default=MAPS, help=f"maps per case ({MAPS})")
    parser.add_argument("--seed", type=int, default=1, help="noise seed of the renders (1)")
    parser.add_argument("--cases", nargs="+", default=None, metavar="NAME",
                        help="case names (default: all): " + ", ".join(c.name for c in CASES))
    parser.add_argument("--json", action="store_true", help="print the rows as a JSON list")


def _text(row: dict[str, Any]) -> str:
    shown = "inf" if row["margin"] is None else f"{row['margin']:.2f}"
    return (f"{row['case']:34s} {'flag' if row['must_flag'] else 'pass'}  metric "
            f"{row['metric_min']:.4f} / {row['metric_median']:.4f} / {row['metric_max']:.4f}"
            f"  flagged {row['flagged']}/{row['maps']}  margin {shown}")


def run(args: argparse.Namespace) -> int:
    if args.maps < 1:
        raise UsageError(f"--maps must be >= 1, got {args.maps}")
    known = {c.name: c for c in CASES}
    unknown = sorted(set(args.cases or ()) - set(known))
    if unknown:
        raise UsageError(f"unknown case(s) {unknown}; accepted: {sorted(known)}")
    rows = []
    for case in (known[n] for n in args.cases) if args.cases else CASES:
        rows.append(measure(case, args.maps, args.seed))
        if not args.json:
            print(_text(rows[-1]), flush=True)
    if args.json:
        print(json.dumps(rows, indent=1))
    return 0
