"""``atris bench accuracy [--json] [--quick] [--plot PNG]``: range error against run time.

For every shipped simulator scene (unit 0) and every configuration - code length N in
{4, 8, 16, 32}, peak method, ROI bands on/off, resolution 640x400 / 1280x800, block or
sliding demodulation - sub-frames are rendered once per (scene, resolution, N), pushed
through the demodulator and each map through :class:`~atris_node.pipeline.chain.Pipeline`.

Each row (JSON fields relied on by other tools): ``config`` (object: ``code_length``,
``peak_method``, ``roi_bands``, ``resolution``, ``demod``), ``scene``, ``ms_per_frame``
(demodulation per output map + pipeline, median), ``range_rmse_m`` (camera range of every
valid sample against the true surface in its column, whatever line it was given: a
misidentified sample is an error, not skipped; see :func:`surface_errors`; null when no
sample), ``no_surface_samples`` (valid samples where the truth sees no surface at all),
``valid_fraction`` (valid points per line and column), the sector-frames scored as
:mod:`atris_node.bench.safety` scores them (``sectors_valid``, ``near_phantom``, ``far``,
``false_free``, ``invalid_fraction``; over the map's time where the scene moves), plus
``demod_ms``, ``pipeline_ms`` and ``median_abs_error_m``. Pipeline times are the best of
three runs per map; demodulation is timed once per sub-frame as it streams. ``--quick``
runs one scene, 640x400, N = 16, block demodulation: a minute on a loaded machine.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from atris_node import codes
from atris_node.bench.safety import Truth as SectorTruth
from atris_node.bench.safety import scene_settings, score_sector, sector_truth
from atris_node.demod import BlockDemodulator, SlidingDemodulator
from atris_node.pipeline.chain import Pipeline, PipelineConfig, PipelineResult
from atris_node.pipeline.peaks import IDENTITY_MODES, PEAK_METHODS
from atris_node.progress import progress
from atris_node.sim import Simulator, Truth, load_scene, shipped_scenes
from atris_node.sim.scene import Scene
from atris_node.types import DistortionMap

logger = logging.getLogger(__name__)

CODE_LENGTHS = (4, 8, 16, 32)
RESOLUTIONS = ((640, 400), (1280, 800))
DEMODS = {"block": BlockDemodulator, "sliding": SlidingDemodulator}
#: maps evaluated per (scene, resolution, N, demodulator)
MAPS = 2
#: timed runs of the pipeline per map (best kept)
TIMING_REPEATS = 3
#: stripe σ (px) the pipeline assumes at 640x400; doubled at 1280x800
STRIPE_SIGMA_PX = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the rows as a JSON list")
    parser.add_argument("--quick", action="store_true",
                        help="one scene, 640x400, N = 16, block demodulation")
    parser.add_argument("--scenes", nargs="+", default=None, metavar="NAME",
                        help="shipped scene names (default: all)")
    parser.add_argument("--plot", type=Path, default=None, metavar="PNG",
                        help="write the work-precision diagram (matplotlib, Agg)")
    parser.add_argument("--identity", nargs="+", default=["aligned"], choices=IDENTITY_MODES,
                        help="line identity modes to compare (default: aligned)")


@dataclass(frozen=True)
class Grid:
    """The configurations to run."""

    scenes: tuple[str, ...]
    code_lengths: tuple[int, ...] = CODE_LENGTHS
    resolutions: tuple[tuple[int, int], ...] = RESOLUTIONS
    demods: tuple[str, ...] = tuple(DEMODS)
    methods: tuple[str, ...] = PEAK_METHODS
    roi: tuple[bool, ...] = (True, False)
    identities: tuple[str, ...] = ("aligned",)


def grid_of(args: argparse.Namespace) -> Grid:
    """The full grid, or the ``--quick`` subset, over the chosen scenes."""
    scenes = tuple(args.scenes or shipped_scenes())
    identities = tuple(getattr(args, "identity", None) or ("aligned",))
    if args.quick:
        return Grid(scenes=tuple(args.scenes or ("indoor_lab",)), code_lengths=(16,),
                    resolutions=((640, 400),), demods=("block",), identities=identities)
    return Grid(scenes=scenes, identities=identities)


def scaled(scene: Scene, width: int, height: int) -> Scene:
    """``scene`` seen by the same optics at another resolution (f, principal point, pixel
    pitch and blur scaled with the width)."""
    cam = scene.camera
    k = width / cam.width_px
    camera = replace(cam, width_px=width, height_px=height, focal_px=cam.focal_px * k,
                     cx_px=(cam.cx_px + 0.5) * k - 0.5, cy_px=(cam.cy_px + 0.5) * k - 0.5,
                     pixel_pitch_um=cam.pixel_pitch_um / k, psf_sigma_px=cam.psf_sigma_px * k)
    return replace(scene, camera=camera)


def _simulator(scene: Scene, n: int) -> Simulator:
    row = scene.code_row if scene.code_length == n and scene.code_row <= n else 2
    return Simulator(scene, chips=codes.walsh_chips(n, row), seed=1)


def demodulate(sim: Simulator, subs: list[Any], demod: str) -> tuple[list[DistortionMap],
                                                                     float]:
    """The last MAPS maps of ``demod`` over ``subs``, and its median ms per output map."""
    kind = DEMODS[demod]
    demodulator = kind(sim.chips, bits=sim.camera.bits)
    maps, per_map, spent = [], [], 0.0
    for sub in subs:
        start = time.perf_counter()
        dmap = demodulator.push(sub)
        spent += time.perf_counter() - start
        if dmap is not None:
            maps.append(dmap)
            per_map.append(spent * 1e3)
            spent = 0.0
    return maps[-MAPS:], float(np.median(per_map[-MAPS:]))


def range_errors(result: PipelineResult, truth: Truth) -> np.ndarray:
    """(m,) camera-range errors (m) of the valid samples where the truth has the line."""
    s = result.samples
    line, col = s.line[result.valid], s.col_px[result.valid].astype(np.int64)
    seen = truth.line_visible[line, col]
    return np.asarray(result.points_camera_m[seen, 2] - truth.line_points_m[line[seen],
                                                                            col[seen], 2])


def surface_errors(result: PipelineResult, truth: Truth) -> tuple[np.ndarray, int]:
    """(m,) camera-range errors (m) of the valid samples against the true surface in their
    column, whatever line they were given, and how many valid samples have no surface.

    A sample is compared with the true depth of the pixels within a row of its centre, the
    one nearest to its own range: a stripe cut by a depth edge (a floor/wall corner) sits
    between two surfaces and is right against either. A sample whose line identity is
    wrong lies far from every one of them and counts in full; one where the truth sees no
    surface in any of those rows (sky) counts in ``no_surface``.
    """
    s = result.samples
    valid = result.valid
    z = result.points_camera_m[:, 2]
    row = np.rint(s.row_px[valid]).astype(np.int64)
    col = s.col_px[valid].astype(np.int64)
    height = truth.depth_m.shape[0]
    near = np.stack([truth.depth_m[np.clip(row + d, 0, height - 1), col]
                     for d in (-1, 0, 1)])  # (3, m)
    diff = np.where(near > 0.0, z[None, :] - near, np.inf)
    best = np.take_along_axis(diff, np.abs(diff).argmin(axis=0)[None, :], axis=0)[0]
    found = np.isfinite(best)
    return best[found], int((~found).sum())


#: per-row counts of sector-frames, scored as atris_node.bench.safety scores them
SECTOR_COUNTS = ("sectors_valid", "invalid", "near_phantom", "far", "false_free")


def sector_counts(result: PipelineResult, truth: tuple[SectorTruth, ...],
                  z_max_m: float) -> dict[str, int]:
    """The sector-frames of one map scored against its sector truth (over the map's time
    when the scene moves, :func:`atris_node.bench.safety.sector_truth`): VALID, INVALID,
    near phantom, far not covered, false free."""
    sectors = result.measurement.sectors
    counts = dict.fromkeys(SECTOR_COUNTS, 0)
    for index in range(len(sectors)):
        for name in score_sector(sectors, truth, index, z_max_m):
            key = "sectors_valid" if name == "valid" else name
            if key in counts:
                counts[key] += 1
    return counts


def _timed(pipe: Pipeline, dmap: DistortionMap) -> tuple[PipelineResult, float]:
    """The result of ``pipe.process(dmap)`` and the best of TIMING_REPEATS runs, ms (the
    machine is shared: the best run is the one least disturbed by other work)."""
    best, result = np.inf, None
    for _ in range(TIMING_REPEATS):
        start = time.perf_counter()
        out = pipe.process(dmap)
        best = min(best, (time.perf_counter() - start) * 1e3)
        result = result or out
    assert result is not None
    return result, float(best)


def _pipeline_rows(sim: Simulator, maps: list[DistortionMap], truths: list[Truth],
                   sectors: list[tuple[SectorTruth, ...]], grid: Grid, k: float
                   ) -> Iterator[tuple[dict[str, Any], dict[str, Any]]]:
    """(config part, measurement part) per peak method, ROI setting and identity mode;
    ``truths`` at each map's middle sub-frame, ``sectors`` over its time."""
    for method, roi, identity in itertools.product(grid.methods, grid.roi, grid.identities):
        config = PipelineConfig(peak_method=method, roi_bands=roi, identity=identity,
                                stripe_sigma_px=STRIPE_SIGMA_PX * k,
                                **scene_settings(sim.scene))
        pipe = Pipeline(config, sim.calibration(), sim.mounting, config.layout())
        times, errors, valid, no_surface = [], [], [], 0
        counts = dict.fromkeys(SECTOR_COUNTS, 0)
        for dmap, truth, known in zip(maps, truths, sectors, strict=True):
            result, ms = _timed(pipe, dmap)
            times.append(ms)
            err, missing = surface_errors(result, truth)
            errors.append(err)
            no_surface += missing
            valid.append(result.diagnostics.valid_fraction)
            for key, n in sector_counts(result, known, config.z_max_m).items():
                counts[key] += n
        err = np.concatenate(errors)
        frames = len(maps) * config.sector_count
        yield ({"peak_method": method, "roi_bands": roi, "identity": identity}, {
            "pipeline_ms": float(np.median(times)),
            "range_rmse_m": float(np.sqrt(np.mean(err**2))) if err.size else None,
            "median_abs_error_m": float(np.median(np.abs(err))) if err.size else None,
            "no_surface_samples": no_surface,
            "valid_fraction": float(np.mean(valid)),
            "invalid_fraction": round(counts["invalid"] / frames, 4) if frames else None,
            **counts})


def scene_rows(name: str, grid: Grid) -> Iterator[dict[str, Any]]:
    """Every row of one scene."""
    base = load_scene(name)
    for width, height in grid.resolutions:
        scene = scaled(base, width, height)
        for n in grid.code_lengths:
            sim = _simulator(scene, n)
            subs = [sim.render(seq) for seq in range(2 * n)]
            for demod in grid.demods:
                maps, demod_ms = demodulate(sim, subs, demod)
                layout = PipelineConfig().layout()
                truths = [sim.truth((m.first_sequence + m.last_sequence) // 2, layout)
                          for m in maps]
                sectors = [sector_truth(sim, (m.first_sequence, m.last_sequence), layout)
                           for m in maps]
                for config, measured in _pipeline_rows(sim, maps, truths, sectors, grid,
                                                       width / base.camera.width_px):
                    config.update(code_length=n, resolution=f"{width}x{height}", demod=demod)
                    yield {"config": config, "scene": name,
                           "ms_per_frame": demod_ms + measured["pipeline_ms"],
                           "demod_ms": demod_ms, **measured}
            logger.info("%s %dx%d N=%d done", name, width, height, n)


def _key(config: dict[str, Any]) -> tuple[Any, ...]:
    return tuple(sorted(config.items()))


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per configuration over the scenes: mean ms, median RMSE (scenes with samples) and
    mean valid fraction."""
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(_key(row["config"]), []).append(row)
    out = []
    for group in groups.values():
        rmse = [r["range_rmse_m"] for r in group if r["range_rmse_m"] is not None]
        out.append({"config": group[0]["config"],
                    "ms_per_frame": float(np.mean([r["ms_per_frame"] for r in group])),
                    "range_rmse_m": float(np.median(rmse)) if rmse else None,
                    "valid_fraction": float(np.mean([r["valid_fraction"] for r in group])),
                    **{k: sum(int(r.get(k, 0)) for r in group) for k in SECTOR_COUNTS}})
    return out


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    """Work-precision diagram: ms per output frame against range RMSE, one point per
    configuration (scenes summarised), colour = peak method, marker = resolution, size =
    N, hollow = ROI bands off."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = dict(zip(PEAK_METHODS, ("C0", "C1", "C2", "C3", "C4"), strict=True))
    markers = {"640x400": "o", "1280x800": "s"}
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for row in summarise(rows):
        c = row["config"]
        if row["range_rmse_m"] is None:
            continue
        colour = colours[c["peak_method"]]
        ax.scatter(row["ms_per_frame"], row["range_rmse_m"], s=8 * np.sqrt(c["code_length"]) * 3,
                   marker=markers.get(c["resolution"], "^"), edgecolors=colour,
                   facecolors=colour if c["roi_bands"] else "none", alpha=0.7)
    for method, colour in colours.items():
        ax.scatter([], [], color=colour, label=method)
    ax.set(xscale="log", yscale="log", xlabel="ms per output frame (demodulation + pipeline)",
           ylabel="range RMSE, m (median over scenes)",
           title="Accuracy against run time (o 640x400, s 1280x800; hollow: ROI off)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _line(row: dict[str, Any]) -> str:
    c = row["config"]
    rmse = "-" if row["range_rmse_m"] is None else f"{row['range_rmse_m']:.4f}"
    return (f"{row.get('scene', 'all'):26s} N={c['code_length']:<3d} {c['resolution']:9s} "
            f"{c['demod']:8s} {c['peak_method']:12s} roi={'on ' if c['roi_bands'] else 'off'} "
            f"{c.get('identity', 'greedy'):7s} {row['ms_per_frame']:8.2f} ms  "
            f"rmse {rmse:>7s} m  valid {row['valid_fraction']:.3f}  sectors phantom/far/"
            f"false-free {row.get('near_phantom', 0)}/{row.get('far', 0)}/"
            f"{row.get('false_free', 0)} of {row.get('sectors_valid', 0)} valid")


def run(args: argparse.Namespace) -> int:
    grid = grid_of(args)
    scenes = progress(grid.scenes, "accuracy", "scene", len(grid.scenes))
    rows = [row for name in scenes for row in scene_rows(name, grid)]
    if args.plot is not None:
        plot(rows, args.plot)
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        for row in rows:
            print(_line(row))
    return 0
