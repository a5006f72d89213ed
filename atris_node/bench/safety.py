"""``atris bench safety [--scenes NAME ...] [--stress] [--maps N] [--seed S] [--groups G]
[--json]``: every sector-frame scored against the simulator's truth.

A sector-frame is the verdict of one sector in one map. With ``t`` the true distance of
the nearest obstacle the lines reach in that sector, at any range (None when the lines
reach none) and ``d`` the reported distance (a map integrates its sub-frames, so where the
scene moves ``t`` is the interval of the truths at the map's first, middle and last
sub-frame, and ``d`` is compared with the nearer end when below it, the farther when
above):

- ``near_phantom``: VALID with ``t`` None, or ``d < t - max(10 %, 20 cm)``;
- ``far``: VALID with ``d > t + max(10 %, 20 cm)`` and no neighbouring sector VALID at
  ``t`` plus that tolerance or nearer (a farther-than-truth distance not covered);
- ``false_free``: NO_RETURN while ``t`` is within z_max (the scene's ``z_max_m`` when it
  states one, else the pipeline's default; the pipeline searches to the same range);
- ``accurate``: VALID within ``max(3 %, 5 cm)`` of ``t``;
- ``invalid``: INVALID.

Rows (one per scene; JSON keys relied on by the tests and docs/benchmarks.md):
``scene``, ``maps``, ``sector_frames``, ``valid``, ``no_return``, ``invalid``,
``near_phantom``, ``far``, ``false_free``, ``accurate``, ``invalid_fraction``,
``accurate_fraction`` (of VALID; null without VALID), ``ambiguous_samples`` (per map),
``pipeline_ms`` (median).

``--groups G`` evaluates a fan split into G groups of lines, each on its own orthogonal
code and demodulated on its own: group g holds lines g, g + G, g + 2G... at the same power
per line, rendered alone (the other groups' light cancels in its demodulation; their shot
noise is left out) and measured with its own calibration. A sector-frame is then what a
unit publishing all groups would say, conservatively: INVALID when any group says INVALID,
else the nearest VALID distance of the groups, else NO_RETURN; it is scored against the
truth of the whole fan. ``ambiguous_samples`` and ``pipeline_ms`` are summed over the
groups.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from atris_node.codes import walsh_chips
from atris_node.demod import BlockDemodulator
from atris_node.errors import ConfigError
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim import Simulator, load_scene, shipped_scenes, stress_scenes
from atris_node.types import DistortionMap, Measurement, SectorDistance, SectorState

logger = logging.getLogger(__name__)

#: maps per scene by default (after the first full code period)
MAPS = 6
#: the layout every scene is scored in: 8 sectors over 70°
LAYOUT = SectorLayout(8, math.radians(70.0))
COUNTS = ("valid", "no_return", "invalid", "near_phantom", "far", "false_free", "accurate")


def phantom_tolerance_m(true_m: float) -> float:
    """How far a distance may lie from the truth before it is wrong: max(10 %, 20 cm)."""
    return max(0.10 * true_m, 0.20)


def accuracy_tolerance_m(true_m: float) -> float:
    """How close an accurate distance lies to the truth: max(3 %, 5 cm)."""
    return max(0.03 * true_m, 0.05)


#: the true distance of a sector over a map: None, one value, or (nearest, farthest)
Truth = float | tuple[float, float] | None


def _span(t: Truth) -> tuple[float, float] | None:
    if t is None:
        return None
    return (t, t) if isinstance(t, float | int) else (float(t[0]), float(t[1]))


def score_sector(sectors: tuple[SectorDistance, ...], truth: tuple[Truth, ...],
                 index: int, z_max_m: float = math.inf) -> list[str]:
    """The counts one sector-frame adds to (names of :data:`COUNTS`). ``truth`` holds the
    nearest obstacle at any range: only one within ``z_max_m`` makes NO_RETURN false free,
    but a distance is a phantom only against the real obstacle, wherever it stands (an
    object at 10.04 m read at 9.54 m, with z_max 10 m, is not one)."""
    sector, span = sectors[index], _span(truth[index])
    if sector.state is SectorState.INVALID:
        return ["invalid"]
    if sector.state is SectorState.NO_RETURN:
        in_range = span is not None and span[0] <= z_max_m
        return ["no_return"] + (["false_free"] if in_range else [])
    d, out = sector.distance_m, ["valid"]
    if span is None or d < span[0] - phantom_tolerance_m(span[0]):
        return [*out, "near_phantom"]
    near, far = span
    if d > far + phantom_tolerance_m(far) and not _covered(sectors, far, index):
        out.append("far")
    if near - accuracy_tolerance_m(near) <= d <= far + accuracy_tolerance_m(far):
        out.append("accurate")
    return out


def _covered(sectors: tuple[SectorDistance, ...], true_m: float, index: int) -> bool:
    """True when a neighbouring sector reports the obstacle (VALID, not farther)."""
    limit = true_m + phantom_tolerance_m(true_m)
    return any(0 <= j < len(sectors) and sectors[j].state is SectorState.VALID
               and sectors[j].distance_m <= limit for j in (index - 1, index + 1))


@dataclass
class SceneScore:
    """The counts of one scene (see the module docstring)."""

    scene: str
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(COUNTS, 0))
    maps: int = 0
    ambiguous: list[int] = field(default_factory=list)
    pipeline_ms: list[float] = field(default_factory=list)

    def add(self, measurement: Measurement, truth: tuple[Truth, ...],
            z_max_m: float = math.inf) -> None:
        self.maps += 1
        for i in range(len(measurement.sectors)):
            for name in score_sector(measurement.sectors, truth, i, z_max_m):
                self.counts[name] += 1

    def row(self) -> dict[str, Any]:
        c = self.counts
        frames = c["valid"] + c["no_return"] + c["invalid"]
        return {"scene": self.scene, "maps": self.maps, "sector_frames": frames, **c,
                "invalid_fraction": round(c["invalid"] / frames, 4) if frames else None,
                "accurate_fraction": (round(c["accurate"] / c["valid"], 4) if c["valid"]
                                      else None),
                "ambiguous_samples": (round(float(np.mean(self.ambiguous)), 1)
                                      if self.ambiguous else 0.0),
                "pipeline_ms": (round(float(np.median(self.pipeline_ms)), 2)
                                if self.pipeline_ms else None)}


def over_window(truths: list[tuple[float | None, ...]]) -> tuple[Truth, ...]:
    """Per sector the (nearest, farthest) of the truths at several instants, None when
    none of them has an obstacle there."""
    out: list[Truth] = []
    for values in zip(*truths, strict=True):
        known = [v for v in values if v is not None]
        out.append((min(known), max(known)) if known else None)
    return tuple(out)


def score_scene(name: str, maps: int = MAPS, groups: int = 1, seed: int = 1) -> SceneScore:
    """Render ``maps`` maps of scene ``name`` (unit 0, its own code), run the pipeline the
    node would run on them, and score every sector-frame (``groups``: see the module
    docstring)."""
    from atris_node.pipeline.chain import PipelineConfig

    scene = load_scene(name)
    config = PipelineConfig(sector_count=LAYOUT.count, fov_deg=math.degrees(LAYOUT.fov_rad),
                            **scene_settings(scene))
    whole = Simulator(scene, chips=walsh_chips(scene.code_length, scene.code_row), seed=1)
    runs = [_measure(_group(scene, g, groups), maps, config, seed=seed + g)
            for g in range(groups)]
    score = SceneScore(name)
    for per_group in zip(*runs, strict=True):
        measurement, _, _, span = per_group[0]
        sectors = _combined([m.sectors for m, _, _, _ in per_group])
        score.add(replace(measurement, sectors=sectors), sector_truth(whole, span), config.z_max_m)
        score.ambiguous.append(sum(a for _, a, _, _ in per_group))
        score.pipeline_ms.append(sum(ms for _, _, ms, _ in per_group))
    return score


def scene_settings(scene: Any) -> dict[str, Any]:
    """The pipeline settings a scene states (``z_max_m``), as PipelineConfig keywords."""
    return {} if scene.z_max_m is None else {"z_max_m": scene.z_max_m}


def _group(scene: Any, group: int, groups: int) -> Any:
    """``scene`` with only lines ``group``, ``group + groups``... at the same power per
    line (and their calibration errors, if any)."""
    if groups == 1:
        return scene
    laser, wrong = scene.projector, scene.miscalibration
    alpha = tuple(laser.alpha_rad[group::groups])
    power = laser.power_w * len(alpha) / len(laser.alpha_rad)
    wrong = replace(wrong, alpha_offset_rad=wrong.alpha_offset_rad[group::groups])
    return replace(scene, projector=replace(laser, alpha_rad=alpha, power_w=power),
                   miscalibration=wrong)


def _measure(scene: Any, maps: int, config: Any, seed: int
             ) -> list[tuple[Measurement, int, float, tuple[int, int]]]:
    """(measurement, ambiguous samples, pipeline ms, (first, last) sub-frame) of the first
    ``maps`` maps."""
    from atris_node.pipeline.chain import Pipeline

    sim, dmaps = block_maps(scene, seed)
    pipe = Pipeline(config, sim.calibration(), sim.mounting, LAYOUT)
    out: list[tuple[Measurement, int, float, tuple[int, int]]] = []
    for dmap in itertools.islice(dmaps, maps):
        result = pipe.process(dmap)
        out.append((result.measurement, result.diagnostics.ambiguous,
                    result.diagnostics.timings_ms.get("total", 0.0),
                    (dmap.first_sequence, dmap.last_sequence)))
    return out


def block_maps(scene: Any, seed: int) -> tuple[Simulator, Iterator[DistortionMap]]:
    """The simulator of ``scene`` (unit 0, its own code, noise ``seed``) and its block
    maps one after the other (known lag), as the node's demodulator makes them."""
    chips = walsh_chips(scene.code_length, scene.code_row)
    sim = Simulator(scene, chips=chips, seed=seed)

    def maps() -> Iterator[DistortionMap]:
        demod = BlockDemodulator(chips, bits=scene.camera.bits, lag=0)
        for sequence in itertools.count():
            dmap = demod.push(sim.render(sequence))
            if dmap is not None:
                yield dmap

    return sim, maps()


def _combined(groups: list[tuple[SectorDistance, ...]]) -> tuple[SectorDistance, ...]:
    """Per sector: INVALID when any group says so, else the nearest VALID, else NO_RETURN."""
    out = []
    for sectors in zip(*groups, strict=True):
        if any(s.state is SectorState.INVALID for s in sectors):
            out.append(next(s for s in sectors if s.state is SectorState.INVALID))
            continue
        valid = [s for s in sectors if s.state is SectorState.VALID]
        out.append(min(valid, key=lambda s: s.distance_m) if valid else sectors[0])
    return tuple(out)


def sector_truth(sim: Simulator, span: tuple[int, int],
                 layout: SectorLayout = LAYOUT) -> tuple[Truth, ...]:
    """The sector truth of a map of sub-frames ``span`` (first, last): at its middle
    sub-frame, or over its first, middle and last when the scene moves."""
    first, last = span
    instants = [first, (first + last) // 2, last] if sim.dynamic else [(first + last) // 2]
    return over_window([sim.truth(i, layout).sector_distance_m for i in instants])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the rows as a JSON list")
    parser.add_argument("--scenes", nargs="+", default=None, metavar="NAME",
                        help="scene names (default: every shipped scene)")
    parser.add_argument("--stress", action="store_true", help="also every stress scene")
    parser.add_argument("--maps", type=int, default=MAPS, help=f"maps per scene ({MAPS})")
    parser.add_argument("--seed", type=int, default=1, help="noise seed of the renders (1)")
    parser.add_argument("--groups", type=int, default=1,
                        help="split the fan into G groups of lines on their own codes (1)")


def _text(row: dict[str, Any]) -> str:
    return (f"{row['scene']:28s} frames {row['sector_frames']:4d}  invalid "
            f"{row['invalid_fraction']:.2f}  phantom {row['near_phantom']:3d}  far "
            f"{row['far']:3d}  false-free {row['false_free']:3d}  accurate "
            f"{row['accurate_fraction'] if row['accurate_fraction'] is not None else '-'}")


def run(args: argparse.Namespace) -> int:
    if args.maps < 1:
        raise ConfigError(f"--maps must be >= 1, got {args.maps}")
    if not 1 <= args.groups <= 4:
        raise ConfigError(f"--groups must be in 1..4, got {args.groups}")
    names = list(args.scenes or shipped_scenes()) + (stress_scenes() if args.stress else [])
    rows = []
    for name in names:
        rows.append(score_scene(name, args.maps, args.groups, args.seed).row())
        if not args.json:
            print(_text(rows[-1]), flush=True)
    if args.json:
        print(json.dumps(rows, indent=1))
    return 0
