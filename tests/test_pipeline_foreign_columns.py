"""With ``invalid_on_interference = False`` only the sectors that look into columns with
foreign light (here the gray trails of a walking pedestrian) go INVALID; no sector is
reported farther than the truth because the nearer obstacle's columns were left out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atris_node.codes import walsh_chips
from atris_node.demod import BlockDemodulator
from atris_node.pipeline.chain import Pipeline, PipelineConfig, PipelineResult, foreign_energy
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim import Simulator, load_scene
from atris_node.types import DistortionMap, SectorState

N, ROW = 16, 2


def maps_and_truth(frames: int) -> list[tuple[PipelineResult, tuple[float | None, ...]]]:
    sim = Simulator(load_scene("fleet"), seed=3, unit=1)
    chips = walsh_chips(N, ROW)
    demod = BlockDemodulator(chips, bits=sim.camera.bits, lag=0)
    config = PipelineConfig(invalid_on_interference=False)
    layout = SectorLayout(config.sector_count, math.radians(config.fov_deg))
    pipeline = Pipeline(config, sim.calibration(), sim.mounting, layout)
    out = []
    for sequence in range(N * frames):
        dmap = demod.push(sim.render(sequence, int(chips[sequence % N])))
        if dmap is not None:
            truth = sim.truth(dmap.last_sequence, layout).sector_distance_m
            out.append((pipeline.process(dmap), tuple(truth)))
    return out


def test_only_sectors_with_foreign_columns_go_invalid_and_none_reads_too_far() -> None:
    results = maps_and_truth(frames=3)
    flagged = [(r, t) for r, t in results if r.diagnostics.interference]
    assert flagged, "the walking pedestrian's trails should be flagged in this scene"
    for result, truth in results:
        sectors = result.measurement.sectors
        for sector, true_m in zip(sectors, truth, strict=True):
            if sector.state is SectorState.VALID and true_m is not None:
                assert sector.distance_m <= true_m * 1.03 + 0.05, (sector, true_m)
    for result, _ in flagged:
        states = [s.state for s in result.measurement.sectors]
        assert SectorState.INVALID in states and SectorState.VALID in states


def _foreign_by_definition(values: np.ndarray, saturated: np.ndarray, background: float,
                           threshold: float) -> tuple[float, np.ndarray]:
    """foreign_energy written out with whole-image masks (one span, all rows)."""
    block = values.astype(np.float32) - np.float32(background)
    block[saturated] = 0.0
    low = block < -threshold
    low[:, 1:] &= block[:, :-1] < -threshold / 2
    low[:, :-1] &= block[:, 1:] < -threshold / 2
    low[:, [0, -1]] = False
    negative = float(-block[low].sum())
    positive = float(block[block > threshold].sum())
    energy = 0.0 if negative == 0.0 else negative / max(positive, threshold, 1.0)
    return energy, low.any(axis=0)


def test_foreign_energy_reads_line_like_negative_pixels() -> None:
    rng = np.random.default_rng(17)
    values = np.round(rng.normal(5.0, 8.0, (120, 640))).astype(np.int16)
    values[40, 100:160] -= 200  # a negative trail
    values[41:44, 0:3] -= 300  # at the image edge
    values[70, 300] -= 400  # one lone pixel: not line-like
    values[90, 200:260] += 500  # our own line
    saturated = np.zeros(values.shape, bool)
    saturated[40, 150:155] = True
    dmap = DistortionMap(values, saturated, N, 0, N - 1, 0.0, 0.1)
    energy, columns = foreign_energy(dmap, ((0, 120),), 5.0, 48.0)
    expected_energy, expected_columns = _foreign_by_definition(values, saturated, 5.0, 48.0)
    # the kernel adds in float64 one pixel at a time, numpy in float32 by pairs
    assert energy == pytest.approx(expected_energy, rel=1e-6) and energy > 0.0
    np.testing.assert_array_equal(columns, expected_columns)
    # the 5 saturated pixels count as 0, and take a neighbour from the pixels beside them
    assert columns[101:159].sum() == 58 - 7 and not columns[300]
