"""``atris sim SCENE --frames K``: render a scene, demodulate it, measure, compare with the truth.

    atris sim indoor_lab --frames 4 --json
    atris sim two_units_orthogonal --frames 1 --out figs/

SCENE is a shipped scene name (``launch/scenes/NAME.toml``) or a path. K is the number of
output frames (distortion maps); each takes N sub-frames of the code (Walsh row ``--row``
of length ``--code-length``, default the scene's ``[code]``). Each map runs through the
pipeline (lines, triangulation, sectors) with the simulator's true calibration and
mounting. ``--json`` prints one object per map with the measured and the true sector
distances side by side (null where there is no return); ``--out DIR`` writes the plain
sub-frame and the demodulated map of each output frame as PNGs (the paper's Figs. 5-11).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from atris_node.codes import walsh_chips
from atris_node.errors import ConfigError
from atris_node.pipeline.sectors import SectorLayout
from atris_node.progress import progress
from atris_node.types import DistortionMap, SectorState, SubFrame

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="shipped scene name or scene file path")
    parser.add_argument("--frames", type=int, default=1, help="output frames (maps), >= 1")
    parser.add_argument("--out", default=None, help="folder for plain and demodulated PNGs")
    parser.add_argument("--json", action="store_true", help="one JSON object per frame")
    parser.add_argument("--seed", type=int, default=None, help="noise seed (default: scene)")
    parser.add_argument("--unit", type=int, default=0, help="which mounting of the scene")
    parser.add_argument("--code-length", type=int, default=None, help="code length N")
    parser.add_argument("--row", type=int, default=None, help="1-based Walsh row")
    parser.add_argument("--sectors", type=int, default=8, help="sector count")
    parser.add_argument("--fov-deg", type=float, default=70.0, help="sector field of view")


def _plain_png(sub: SubFrame) -> np.ndarray:
    """8-bit view of a raw sub-frame (full scale -> 255)."""
    return (sub.pixels.astype(np.float32) * (255.0 / sub.full_scale)).astype(np.uint8)


def _demod_png(dmap: DistortionMap) -> np.ndarray:
    """8-bit view of a distortion map: negatives black, the 99.9th percentile white."""
    values = np.clip(dmap.values.astype(np.float32), 0.0, None)
    top = max(float(np.percentile(values, 99.9)), 1.0)
    return (np.clip(values / top, 0.0, 1.0) * 255.0).astype(np.uint8)


def write_pngs(out: Path, frame: int, sub: SubFrame, dmap: DistortionMap) -> None:
    """Write ``NNNN_plain.png`` and ``NNNN_demod.png`` into ``out``."""
    import cv2

    out.mkdir(parents=True, exist_ok=True)
    for name, image in (("plain", _plain_png(sub)), ("demod", _demod_png(dmap))):
        path = out / f"{frame:04d}_{name}.png"
        if not cv2.imwrite(str(path), image):
            raise OSError(f"cannot write {path}")


def _sectors(result: Any, truth: Any, layout: SectorLayout) -> list[dict[str, Any]]:
    rows = []
    measured = {s.index: s for s in result.measurement.sectors} if result else {}
    for index, true_m in enumerate(truth.sector_distance_m):
        sector = measured.get(index)
        valid = sector is not None and sector.state == SectorState.VALID
        rows.append({"index": index,
                     "bearing_deg": round(math.degrees(layout.bearing_of(index)), 3),
                     "state": sector.state.name if sector is not None else None,
                     "distance_m": round(sector.distance_m, 4) if valid and sector else None,
                     "sigma_m": round(sector.sigma_m, 4) if valid and sector else None,
                     "confidence": round(sector.confidence, 3) if sector else None,
                     "truth_m": None if true_m is None else round(true_m, 4)})
    return rows


def _map_fields(result: Any) -> dict[str, Any]:
    """The per-map keys of the JSON record (None where the chain did not run)."""
    if result is None:
        return dict.fromkeys(("nearest_m", "closing_speed_mps", "ttc_s", "interference",
                              "ambiguous_samples", "too_faint_samples", "near_stripes",
                              "pipeline_ms"))
    m, d = result.measurement, result.diagnostics
    return {"nearest_m": None if m.nearest is None else round(m.nearest.distance_m, 4),
            "closing_speed_mps": _rounded(m.closing_speed_mps, 3),
            "ttc_s": _rounded(m.time_to_collision_s, 3),
            "interference": bool(d.interference), "ambiguous_samples": int(d.ambiguous),
            "too_faint_samples": int(d.too_faint), "near_stripes": int(d.near),
            "pipeline_ms": round(d.timings_ms.get("total", 0.0), 3)}


def _rounded(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)


def _row_error(result: Any, truth: Any) -> float | None:
    """Median |measured - true| line row (px) over samples whose line the truth has."""
    if result is None or len(result.samples) == 0:
        return None
    line = result.samples.line
    col = np.clip(np.rint(result.samples.col_px).astype(np.int64), 0,
                  truth.line_rows.shape[1] - 1)
    seen = truth.line_visible[line, col]
    if not seen.any():
        return None
    error = np.abs(result.samples.row_px[seen] - truth.line_rows[line[seen], col[seen]])
    return round(float(np.median(error)), 4)


def frame_record(frame: int, scene: str, dmap: DistortionMap, result: Any, truth: Any,
                 layout: SectorLayout) -> dict[str, Any]:
    """The JSON object of one output frame."""
    return {"frame": frame, "scene": scene, "first_sequence": dmap.first_sequence,
            "last_sequence": dmap.last_sequence,
            "processing_gain": round(dmap.processing_gain, 3), "snr": round(dmap.snr, 3),
            "line_samples": 0 if result is None else len(result.samples),
            "truth_line_samples": int(truth.line_visible.sum()),
            "line_row_error_px": _row_error(result, truth),
            **_map_fields(result),
            "sectors": _sectors(result, truth, layout)}


def _pipeline(sim: Any, layout: SectorLayout) -> Any:
    """The unit's processing chain with the true calibration, or None if not available."""
    try:
        from atris_node.pipeline.chain import Pipeline, PipelineConfig
    except ImportError:  # the chain is optional for rendering and truth
        logger.warning("atris_node.pipeline.chain is not available: sectors are not measured")
        return None
    from atris_node.bench.safety import scene_settings

    config = PipelineConfig(sector_count=layout.count, fov_deg=math.degrees(layout.fov_rad),
                            **scene_settings(sim.scene))
    return Pipeline(config, sim.calibration(), sim.mounting, layout)


def run(args: argparse.Namespace) -> int:
    from atris_node.demod import BlockDemodulator
    from atris_node.sim import Simulator, load_scene

    if args.frames < 1:
        raise ConfigError(f"--frames must be >= 1, got {args.frames}")
    scene = load_scene(args.scene)
    chips = walsh_chips(args.code_length or scene.code_length, args.row or scene.code_row)
    sim = Simulator(scene, chips=chips, seed=args.seed, unit=args.unit)
    layout = SectorLayout(args.sectors, math.radians(args.fov_deg))
    demod = BlockDemodulator(chips, bits=scene.camera.bits, lag=0)
    pipeline = _pipeline(sim, layout)
    frame, last_lit = 0, None
    total = args.frames * chips.size
    for sequence in progress(range(total), f"sim {scene.name}", "sub-frame", total):
        sub = sim.render(sequence)
        last_lit = sub if sub.chip else last_lit
        dmap = demod.push(sub)
        if dmap is None:
            continue
        result = pipeline.process(dmap) if pipeline is not None else None
        truth = sim.truth((dmap.first_sequence + dmap.last_sequence) // 2, layout)
        record = frame_record(frame, scene.name, dmap, result, truth, layout)
        print(json.dumps(record) if args.json else _text(record))
        if args.out:
            write_pngs(Path(args.out), frame, last_lit or sub, dmap)
        frame += 1
    return 0


def _text(record: dict[str, Any]) -> str:
    """One line per map: each sector as measured/true metres, ``free`` for NO_RETURN and
    ``  ?  `` for INVALID (unknown: never free)."""
    def fmt(v: float | None) -> str:
        return "  -  " if v is None else f"{v:5.2f}"

    def measured(s: dict[str, Any]) -> str:
        return {"NO_RETURN": " free", "INVALID": "  ?  "}.get(s["state"] or "",
                                                                fmt(s["distance_m"]))
    sectors = " ".join(f"{measured(s)}/{fmt(s['truth_m'])}" for s in record["sectors"])
    return (f"frame {record['frame']}: {record['line_samples']} samples, "
            f"row error {record['line_row_error_px']} px; measured/true m "
            f"(? unknown): {sectors}")
