"""Rows of ``atris bench adaptive --skips``: what leaving out unneeded work saves.

- interference analysis only for codes in use (sync plan, N = 16: 15 rows, two in use)
  against every code of the plan, ms per sub-frame, with the reported energies compared;
- the phase search (lag correlation) per sub-frame against the locked demodulator's
  re-check once per lock history, ms per sub-frame;
- the line search over the whole bands against ROI narrowing (``atris_node.pipeline.roi``), ms of
  the pipeline per map on the simulated indoor_lab scene, samples and sectors compared.

Sub-frames of the first two are synthetic 640x400 10-bit frames with the own line and one
other unit.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from atris_node import codes
from atris_node.adaptive.controller import used_chips
from atris_node.bench.accuracy import scaled
from atris_node.demod import BlockDemodulator
from atris_node.pipeline.chain import Pipeline, PipelineConfig, PipelineResult
from atris_node.pipeline.interference import InterferenceMeter
from atris_node.sim import Simulator, load_scene
from atris_node.types import DistortionMap, SubFrame

N = 16


def _frames(count: int, own: Any, other: Any) -> list[SubFrame]:
    rng = np.random.default_rng(3)
    out = []
    for seq in range(count):
        pixels = rng.normal(300.0, 6.0, (400, 640))
        pixels[200:202] += 80.0 * own[seq % N]
        pixels[260:262] += 50.0 * other[(seq - 5) % N]
        out.append(SubFrame(np.clip(pixels, 0, 1023).astype(np.uint16), seq, seq / 240.0,
                            seq / 240.0, 500.0, bits=10))
    return out


def _ms_per_item(fn: Callable[[], object], items: int) -> float:
    start = time.perf_counter()
    fn()
    return (time.perf_counter() - start) * 1e3 / items


def interference_row() -> dict[str, Any]:
    """Meter over every plan code vs only the codes in use; energies must agree."""
    plan = {r: codes.walsh_chips(N, r) for r in codes.code_set(N, "sync")}
    frames = _frames(8 * N, plan[2], plan[7])
    full, used = InterferenceMeter(plan, 2), InterferenceMeter(used_chips(plan, 2, [7]), 2)
    full_reports: list[Any] = []
    used_reports: list[Any] = []
    full_ms = _ms_per_item(lambda: full_reports.extend(full.push(s) for s in frames),
                           len(frames))
    used_ms = _ms_per_item(lambda: used_reports.extend(used.push(s) for s in frames),
                           len(frames))
    same = all((a is None and b is None) or (a is not None and b is not None and np.isclose(
        a.foreign[7], b.foreign[7], rtol=1e-12)) for a, b in zip(full_reports, used_reports,
                                                                 strict=True))
    return {"skip": "interference codes not in use", "codes_full": len(plan) - 1,
            "codes_skipped_to": len(used.rows), "ms_full": full_ms, "ms_skipped": used_ms,
            "result_unchanged": bool(same)}


def phase_search_row() -> dict[str, Any]:
    """Correlation every sub-frame (cost of one search) vs once per lock history."""
    chips = codes.walsh_chips(N, 9)
    frames = _frames(8 * N, chips, codes.walsh_chips(N, 5))
    demod = BlockDemodulator(chips, bits=10, lag=None)
    for sub in frames:
        demod.push(sub)
    lock = demod._lock
    search_ms = _ms_per_item(lambda: [lock._decide() for _ in range(200)], 200)
    return {"skip": "phase search once locked", "lag": demod.lag,
            "ms_full": search_ms, "ms_skipped": search_ms / lock.history,
            "result_unchanged": demod.relocks == 0}


def _roi_maps(count: int) -> tuple[Simulator, list[DistortionMap]]:
    """``count`` block maps of indoor_lab at 640x400, N = 4."""
    sim = Simulator(scaled(load_scene("indoor_lab"), 640, 400), chips=codes.walsh_chips(4, 2),
                    seed=1)
    demod = BlockDemodulator(sim.chips, bits=sim.camera.bits)
    maps = (demod.push(sim.render(seq)) for seq in range(4 * count))
    return sim, [m for m in maps if m is not None]


def _same(a: PipelineResult, b: PipelineResult) -> bool:
    fields = ("line", "row_px", "col_px", "snr", "sigma_u_px", "saturated")
    return a.measurement.sectors == b.measurement.sectors and all(
        np.array_equal(getattr(a.samples, f), getattr(b.samples, f)) for f in fields)


def roi_row(count: int = 48) -> dict[str, Any]:
    """Whole-band search vs ROI narrowing on the same maps, each map timed back to back."""
    sim, maps = _roi_maps(count)
    parts = (sim.calibration(), sim.mounting, PipelineConfig().layout())
    full = Pipeline(PipelineConfig(), *parts)
    narrow = Pipeline(PipelineConfig(roi_narrowing=True), *parts)
    full_ms, narrow_ms, same = [], [], True
    for dmap in maps:
        a = full.process(dmap)
        b = narrow.process(dmap)
        same = same and _same(a, b)
        full_ms.append(a.diagnostics.timings_ms["lines"])
        narrow_ms.append(b.diagnostics.timings_ms["lines"])
    assert narrow.roi is not None
    return {"skip": "line search outside the recent rows", "maps": len(maps),
            "narrowed_maps": len(maps) - narrow.roi.full_searches,
            "ms_full": float(np.mean(full_ms)), "ms_skipped": float(np.mean(narrow_ms)),
            "result_unchanged": bool(same)}


def rows() -> list[dict[str, Any]]:
    """Every skip row."""
    return [interference_row(), phase_search_row(), roi_row()]
