"""Digest of what the pipeline gives on every simulator scene: the check that a change made
for speed changes no result.

Every shipped and stress scene (``atris_node.sim``), seeds 1 and 2, the first MAPS block
maps each, plus the profile's scene (``atris bench profile``) at 640x400, 1280x800 and
2048x1088, go through a fresh :class:`atris_node.pipeline.chain.Pipeline` (the safety
bench's settings). Per map the digest holds SHA-256 hashes of the sectors (state,
distance_m, sigma_m), of the samples (row_px, col_px, line; all fields also apart) and of
the diagnostics' counts, bitwise.

    python tests/pipeline_digest.py --write before.json [--cache DIR]
    python tests/pipeline_digest.py --check before.json [--cache DIR]

``--cache`` keeps the rendered maps (pickled, about 1.5 GB at 640x400) so that a check
only runs the pipeline; the maps do not depend on the pipeline code.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import math
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from atris_node.bench.accuracy import scaled
from atris_node.bench.safety import LAYOUT, block_maps, scene_settings
from atris_node.pipeline.chain import Pipeline, PipelineConfig, PipelineResult
from atris_node.sim import Scene, Simulator, load_scene, shipped_scenes, stress_scenes
from atris_node.types import DistortionMap

MAPS = 4
SEEDS = (1, 2)
#: (width, height, bits) of the profile's resolutions
PROFILE = ((640, 400, 8), (1280, 800, 8), (2048, 1088, 10))


def cases() -> list[tuple[str, Scene, int]]:
    """(key, scene, seed) of every run."""
    out = [(f"{name}/seed{seed}", load_scene(name), seed)
           for name in shipped_scenes() + stress_scenes() for seed in SEEDS]
    for width, height, bits in PROFILE:
        base = scaled(load_scene("indoor_lab"), width, height)
        scene = replace(base, camera=replace(base.camera, bits=bits))
        out.append((f"profile_{width}x{height}/seed1", scene, 1))
    return out


def render(scene: Scene, seed: int, maps: int) -> tuple[Simulator, list[DistortionMap]]:
    """The simulator and its first ``maps`` block maps."""
    sim, dmaps = block_maps(scene, seed)
    return sim, list(itertools.islice(dmaps, maps))


def _hash(*arrays: Any) -> str:
    h = hashlib.sha256()
    for array in arrays:
        a = np.ascontiguousarray(array)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:24]


def digest(result: PipelineResult) -> dict[str, str]:
    """Hashes of one map's sectors, samples and diagnostics' counts."""
    sectors = result.measurement.sectors
    state = np.array([s.state.value for s in sectors], dtype=np.int64)
    distance = np.array([np.nan if s.distance_m is None else s.distance_m for s in sectors])
    sigma = np.array([np.nan if s.sigma_m is None else s.sigma_m for s in sectors])
    s = result.samples
    d = result.diagnostics
    counts = np.array([d.weak, d.dropped, d.ambiguous, d.saturated, d.no_return, d.rows_read,
                       d.foreign_columns, int(d.interference)], dtype=np.int64)
    floats = np.array([d.noise_floor_dn, d.valid_fraction, d.foreign_energy,
                       d.unassigned_fraction, *d.line_snr])
    return {"sectors": _hash(state, distance, sigma),
            "samples": _hash(s.row_px, s.col_px, s.line),
            "sample_fields": _hash(s.snr, s.sigma_u_px, s.saturated),
            "points": _hash(result.valid, result.points_vehicle_m, result.sigma_z_m),
            "counts": _hash(counts),
            "diagnostics": _hash(floats)}


def _maps(key: str, scene: Scene, seed: int, cache: Path | None
          ) -> tuple[Any, list[DistortionMap]]:
    # the cache holds the calibration as well: a name per calibration format (v2: with the
    # lines' radiometric calibration), so that an older cache is not read as this one
    path = None if cache is None else cache / (key.replace("/", "_") + ".v2.pkl")
    if path is not None and path.exists():
        with path.open("rb") as f:
            return pickle.load(f)  # our own cache
    sim, maps = render(scene, seed, MAPS)
    calibration = (sim.calibration(), sim.mounting)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as f:
            pickle.dump((calibration, maps), f, protocol=pickle.HIGHEST_PROTOCOL)
    return calibration, maps


def run(cache: Path | None) -> tuple[dict[str, dict[str, str]], float]:
    """The digest of every map of every case, and the pipeline's CPU seconds in all."""
    out: dict[str, dict[str, str]] = {}
    cpu = 0.0
    for key, scene, seed in cases():
        (calibration, mounting), maps = _maps(key, scene, seed, cache)
        config = PipelineConfig(sector_count=LAYOUT.count,
                                fov_deg=math.degrees(LAYOUT.fov_rad), **scene_settings(scene))
        pipe = Pipeline(config, calibration, mounting, LAYOUT)
        for i, dmap in enumerate(maps):
            start = time.process_time()
            result = pipe.process(dmap)
            cpu += time.process_time() - start
            out[f"{key}/map{i}"] = digest(result)
    return out, cpu


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", type=Path, help="write the digest here (JSON)")
    parser.add_argument("--check", type=Path, help="compare with this digest (JSON)")
    parser.add_argument("--cache", type=Path, help="keep the rendered maps here")
    args = parser.parse_args()
    got, cpu = run(args.cache)
    print(f"{len(got)} maps, pipeline CPU {cpu:.2f} s")
    if args.write is not None:
        args.write.write_text(json.dumps(got, indent=1, sort_keys=True))
    if args.check is None:
        return 0
    want = json.loads(args.check.read_text())
    bad = [(k, f) for k in sorted(set(want) | set(got)) for f in want.get(k, got.get(k, {}))
           if want.get(k, {}).get(f) != got.get(k, {}).get(f)]
    for key, part in bad:
        print(f"DIFFERS: {key} {part}")
    print(f"{'identical' if not bad else f'{len(bad)} differences'} over {len(got)} maps")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
