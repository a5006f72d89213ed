"""``atris bench profile``: where the per-map time goes, and how it grows.

    atris bench profile                  # stage profile at 640x400, 1280x800, 2048x1088
    atris bench profile --sweep --plot docs/cost_growth.png

Profile (default): for each resolution, the scene (indoor_lab, scaled with the same optics
as ``atris bench realtime``) is rendered for ``--maps`` + 1 code periods, demodulated in
block and sliding mode (median ms per sub-frame ``push``), and the block maps go through
the node's pipeline (default settings of ``pipeline.*``). The pipeline's own stage laps
(``PipelineResult.diagnostics.timings_ms``, of the fastest of REPEATS runs on each map)
give ``lines`` (band search, peaks, line identity), ``triangulate`` (sample cleaning,
undistortion, Eq. 1), ``sectors`` (ground, interference, sector verdicts, nearest
obstacle) and ``rest`` (ROI update, export), each a median ms per map, beside the wall
``total`` and the process's CPU ms ``cpu``. ``top`` lists the functions with the most
own time under cProfile (ms per map, cProfile's overhead included, so compare them with
each other only).

Sweep (``--sweep``): per-map cost against resolution (N = 16, 8 lines, 8 sectors), code
length N, number of projector lines and sector count (each at 1280x800, the others as
before). Per-map cost = demodulation of one map (block: N pushes; sliding: one push per
output map) + pipeline CPU ms per map. Rows carry ``axis`` and ``value`` beside the times.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from atris_node import codes
from atris_node.bench.accuracy import scaled
from atris_node.demod import BlockDemodulator, SlidingDemodulator
from atris_node.pipeline.chain import Pipeline, PipelineConfig
from atris_node.sim import Scene, Simulator, load_scene
from atris_node.types import DistortionMap, SubFrame

RESOLUTIONS = ((640, 400, 8), (1280, 800, 8), (2048, 1088, 10))
STAGE_LAPS = ("lines", "triangulate", "sectors", "total")  # cumulative laps of a map
TOP = 8
#: runs of the pipeline on each map; the fastest counts
REPEATS = 3


@dataclass(frozen=True)
class Case:
    """One configuration: pixels, bits, code length N, projector lines, sectors."""

    width: int
    height: int
    bits: int = 8
    code_length: int = 16
    lines: int = 8
    sectors: int = 8


def scene_for(case: Case, name: str = "indoor_lab") -> Scene:
    """``name`` scaled to the case's resolution, with ``case.lines`` lines spread evenly
    over the scene's own angular range of lines."""
    base = scaled(load_scene(name), case.width, case.height)
    alphas = base.projector.alpha_rad
    spread = tuple(float(a) for a in np.linspace(min(alphas), max(alphas), case.lines))
    return replace(base, camera=replace(base.camera, bits=case.bits),
                   projector=replace(base.projector, alpha_rad=spread))


def render(case: Case, maps: int) -> tuple[Simulator, list[SubFrame]]:
    """The simulator and (maps + 1) * N sub-frames of the case's scene."""
    chips = codes.walsh_chips(case.code_length, codes.code_set(case.code_length)[0])
    sim = Simulator(scene_for(case), chips=chips, seed=1)
    return sim, [sim.render(i) for i in range((maps + 1) * case.code_length)]


def demod_ms(sim: Simulator, subs: list[SubFrame]) -> tuple[dict[str, float],
                                                            list[DistortionMap]]:
    """Median ms per push, block and sliding (the first period untimed), and the block
    maps."""
    times: dict[str, float] = {}
    maps: list[DistortionMap] = []
    n = int(sim.chips.size)
    for mode, kind in (("block", BlockDemodulator), ("sliding", SlidingDemodulator)):
        demod = kind(sim.chips, bits=sim.camera.bits, lag=0)
        samples = []
        for i, sub in enumerate(subs):
            start = time.perf_counter()
            dmap = demod.push(sub)
            if i >= n:
                samples.append(time.perf_counter() - start)
            if mode == "block" and dmap is not None:
                maps.append(dmap)
        times[mode] = float(np.median(samples)) * 1e3
    return times, maps


def pipeline_of(sim: Simulator, sectors: int) -> Pipeline:
    """The node's pipeline (default ``pipeline.*`` settings) for the simulated unit."""
    config = PipelineConfig(sector_count=sectors)
    return Pipeline(config, sim.calibration(), sim.mounting, config.layout())


def _fastest_laps(pipe: Pipeline, dmap: DistortionMap) -> list[float]:
    """The cumulative laps (wall ms) of the fastest of REPEATS runs on ``dmap`` and, last,
    that run's CPU ms of the whole process (the machine is shared: CPU time does not count
    the time other processes took the core, and the fastest run is the least disturbed)."""
    runs = []
    for _ in range(REPEATS):
        cpu = time.process_time()
        timings = pipe.process(dmap).diagnostics.timings_ms
        runs.append([timings[k] for k in STAGE_LAPS] + [(time.process_time() - cpu) * 1e3])
    return min(runs, key=lambda laps: laps[-1])


def stage_ms(pipe: Pipeline, maps: list[DistortionMap]) -> dict[str, float]:
    """Median ms per map of each stage (the differences of a map's cumulative laps; the
    medians of the stages need not add up to the median total), of the total (wall) and of
    the CPU time (``cpu``)."""
    laps = np.array([_fastest_laps(pipe, m) for m in maps])
    own = np.median(np.diff(laps[:, :4], axis=1, prepend=0.0), axis=0)  # per map, median
    laps = np.median(laps, axis=0)
    out = {k: round(float(v), 3) for k, v in zip(("lines", "triangulate", "sectors"),
                                                  own[:3], strict=True)}
    out["rest"] = round(float(own[3]), 3)
    out["total"] = round(float(laps[3]), 3)
    out["cpu"] = round(float(laps[4]), 3)
    return out


def top_functions(pipe: Pipeline, maps: list[DistortionMap]) -> list[dict[str, Any]]:
    """The TOP functions by own time under cProfile, ms per map."""
    profiler = cProfile.Profile()
    profiler.enable()
    for m in maps:
        pipe.process(m)
    profiler.disable()
    entries = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    rows = sorted(((v[2], f"{Path(k[0]).name}:{k[1]}({k[2]})") for k, v in entries.items()),
                  reverse=True)[:TOP]
    return [{"function": name, "ms": round(1e3 * t / len(maps), 3)} for t, name in rows]


def measure(case: Case, maps: int, *, top: bool = False) -> dict[str, Any]:
    """One row: demodulation per sub-frame and per map, pipeline stages per map."""
    sim, subs = render(case, maps)
    demod, dmaps = demod_ms(sim, subs)
    pipe = pipeline_of(sim, case.sectors)
    pipe.process(dmaps[0])  # first-call work (ground plane, ROI) out of the figures
    stages = stage_ms(pipe, dmaps[1:])
    row: dict[str, Any] = {
        "width": case.width, "height": case.height, "bits": case.bits,
        "code_length": case.code_length, "lines": case.lines, "sectors": case.sectors,
        "demod_block_ms": round(demod["block"], 4), "demod_sliding_ms": round(demod["sliding"], 4),
        "pipeline": stages,
        "per_map_block_ms": round(case.code_length * demod["block"] + stages["cpu"], 3),
        "per_map_sliding_ms": round(demod["sliding"] + stages["cpu"], 3)}
    if top:
        row["top"] = top_functions(pipe, dmaps[1:])
    return row


def sweep_cases() -> list[tuple[str, Any, Case]]:
    """(axis, value, case) of the sweep: one axis varied at a time around 1280x800."""
    base = Case(1280, 800)
    cases: list[tuple[str, Any, Case]] = [
        ("resolution", f"{w}x{h}", Case(w, h, b))
        for w, h, b in ((320, 200, 8), (640, 400, 8), (1280, 800, 8), (2048, 1088, 10))]
    cases += [("code_length", n, replace(base, code_length=n)) for n in (4, 8, 16, 32)]
    cases += [("lines", k, replace(base, lines=k)) for k in (2, 4, 8, 16)]
    cases += [("sectors", s, replace(base, sectors=s)) for s in (2, 4, 8, 16)]
    return cases


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    """Per-map cost (demodulation + pipeline, block and sliding) against each swept axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(14, 3.6), sharey=True)
    for ax, axis in zip(axes, ("resolution", "code_length", "lines", "sectors"), strict=True):
        part = [r for r in rows if r["axis"] == axis]
        x = [r["width"] * r["height"] / 1e6 if axis == "resolution" else r["value"]
             for r in part]
        for key, label in (("per_map_block_ms", "block map"),
                           ("per_map_sliding_ms", "sliding map"),):
            ax.plot(x, [r[key] for r in part], "o-", label=label)
        ax.plot(x, [r["pipeline"]["cpu"] for r in part], "s--", label="pipeline only")
        ax.set(xlabel="megapixels" if axis == "resolution" else axis.replace("_", " "),
               title=axis.replace("_", " "))
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("ms per map")
    axes[0].legend(fontsize=8)
    fig.suptitle("Per-map cost (1280x800, N = 16, 8 lines, 8 sectors unless varied)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--maps", type=int, default=10, help="maps per row (default 10)")
    parser.add_argument("--sweep", action="store_true",
                        help="per-map cost against resolution, N, lines and sectors")
    parser.add_argument("--plot", type=Path, help="with --sweep: write the plot (PNG) here")
    parser.add_argument("--json", action="store_true", help="print the rows as a JSON list")


def _print_profile(rows: list[dict[str, Any]]) -> None:
    print(f"{'format':<18} {'demod blk':>9} {'sliding':>8} {'lines':>7} {'triang':>7} "
          f"{'sectors':>7} {'rest':>6} {'pipeline':>8} {'cpu':>6}  (ms)")
    for r in rows:
        p = r["pipeline"]
        print(f"{r['width']}x{r['height']} {r['bits']}-bit".ljust(18)
              + f" {r['demod_block_ms']:>9.3f} {r['demod_sliding_ms']:>8.3f} {p['lines']:>7.2f}"
              f" {p['triangulate']:>7.2f} {p['sectors']:>7.2f} {p['rest']:>6.2f}"
              f" {p['total']:>8.2f} {p['cpu']:>6.2f}")
        for f in r.get("top", []):
            print(f"    {f['ms']:>7.3f} ms  {f['function']}")


def _print_sweep(rows: list[dict[str, Any]]) -> None:
    print(f"{'axis':<12} {'value':>10} {'demod blk':>9} {'sliding':>8} {'pipe cpu':>8} "
          f"{'block map':>9} {'sliding map':>11}  (ms)")
    for r in rows:
        print(f"{r['axis']:<12} {r['value']!s:>10} {r['demod_block_ms']:>9.3f} "
              f"{r['demod_sliding_ms']:>8.3f} {r['pipeline']['cpu']:>8.2f} "
              f"{r['per_map_block_ms']:>9.2f} {r['per_map_sliding_ms']:>11.2f}")


def sweep(maps: int) -> list[dict[str, Any]]:
    """The sweep's rows (each distinct case measured once, the base case for every axis)."""
    measured: dict[Case, dict[str, Any]] = {}
    for _, _, case in sweep_cases():
        if case not in measured:
            measured[case] = measure(case, maps)
    return [{"axis": axis, "value": value, **measured[case]}
            for axis, value, case in sweep_cases()]


def run(args: argparse.Namespace) -> int:
    maps = max(2, int(args.maps))
    if args.sweep:
        rows = sweep(maps)
        if args.plot is not None:
            plot(rows, args.plot)
    else:
        rows = [measure(Case(w, h, b), maps, top=True) for w, h, b in RESOLUTIONS]
    if args.json:
        print(json.dumps(rows))
    else:
        (_print_sweep if args.sweep else _print_profile)(rows)
    return 0
