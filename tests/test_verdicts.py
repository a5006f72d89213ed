"""Sector verdicts: the nearest credible obstacle, and "free" only when earned
(atris_node.pipeline.verdicts), on synthetic points with known truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atris_node.pipeline.obstacles import SectorSettings
from atris_node.pipeline.sectors import SectorLayout
from atris_node.pipeline.verdicts import (
    ColumnEvidence,
    ObstaclePoints,
    nearest_credible,
    sector_verdicts,
)
from atris_node.types import SectorState

LAYOUT = SectorLayout(2, math.radians(70.0))
SETTINGS = SectorSettings(min_points=5, min_confidence=0.6, snr_min=6.0)
WIDTH = 64


def _points(ranges, lines, columns, obstacle=True, sector=0):
    n = len(ranges)
    return ObstaclePoints(np.asarray(ranges, float), np.full(n, sector, np.int64),
                          np.full(n, obstacle, bool), np.asarray(lines, np.int64),
                          np.asarray(columns, np.int64), np.full(n, 0.01), np.full(n, 20.0))


def _join(*parts):
    return ObstaclePoints(*(np.concatenate([getattr(p, f) for p in parts]) for f in (
        "range_m", "sector", "obstacle", "line", "column", "sigma_m", "snr")))


def _evidence(**counts):
    zero = np.zeros(WIDTH, np.int64)
    sector = np.where(np.arange(WIDTH) < WIDTH // 2, 0, 1).astype(np.int64)
    return ColumnEvidence(sector, counts.get("doubtful", zero), counts.get("ambiguous", zero),
                          counts.get("missing", zero))


def _wall(range_m=3.0, n=300):
    rng = np.random.default_rng(1)
    return _points(range_m + rng.uniform(0, 0.3, n), rng.integers(0, 6, n),
                   rng.integers(0, 32, n))


def test_feature_thin_pole_in_front_of_a_wall_is_the_distance() -> None:
    """Six samples of a pole (two lines, three columns) at 1.67 m in front of 300 wall
    samples at 3-3.3 m: the old 0.1-quantile reported the wall; the nearest credible
    cluster is the pole."""
    pole = _points([1.66, 1.67, 1.67, 1.68, 1.67, 1.66], [2, 2, 2, 3, 3, 3], [10, 11, 12] * 2)
    found = nearest_credible(_join(pole, _wall()), np.ones(306, bool), 5)
    assert found is not None and found.distance_m == pytest.approx(1.67, abs=0.02)
    assert found.support == 6 and found.nearer == 0


def test_feature_short_run_of_one_line_blocks_the_wall_behind() -> None:
    """Six near samples of one line over six columns (a wrong identity looks like this,
    and so does a sliver): not credible, so no distance at 0.9 m; nor is the wall behind
    them the distance: the sector is INVALID. (With the nearer count ignored in _verdict
    this test failed: VALID at the wall, 3.0 m, farther than what stands there.)"""
    run = _points([0.9] * 6, [4] * 6, [5, 6, 7, 8, 9, 10])
    found = nearest_credible(_join(run, _wall()), np.ones(306, bool), 5)
    assert found is not None and found.distance_m > 2.9 and found.nearer == 6
    out = sector_verdicts(_join(run, _wall()), _evidence(), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.INVALID and out[0].distance_m == 0.0


def test_feature_long_run_of_one_line_is_credible() -> None:
    """A sliver hit by one line over 15 columns is an obstacle in its own right."""
    run = _points([0.9] * 15, [4] * 15, np.arange(15))
    out = sector_verdicts(_join(run, _wall()), _evidence(), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID
    assert out[0].distance_m == pytest.approx(0.9, abs=0.01)


def test_feature_noisy_far_surface_is_its_centre() -> None:
    """A wall at 9 m whose points scatter by σ = 0.5 m: the window spans the noise and
    the distance is its centre, not its nearest noise."""
    rng = np.random.default_rng(2)
    n = 40
    wall = ObstaclePoints(9.0 + rng.normal(0, 0.5, n), np.zeros(n, np.int64),
                          np.ones(n, bool), rng.integers(0, 3, n), rng.integers(0, 32, n),
                          np.full(n, 0.5), np.full(n, 20.0))
    found = nearest_credible(wall, np.ones(n, bool), 5)
    assert found is not None and abs(found.distance_m - 9.0) < 0.27
    assert 0.0 < found.sigma_m < 0.5


def test_feature_noise_outliers_make_no_phantom() -> None:
    """Four scattered near outliers (fewer than min_points in any window) move nothing."""
    noise = _points([0.5, 0.9, 1.3, 1.7], [0, 1, 2, 3], [1, 9, 17, 25])
    found = nearest_credible(_join(noise, _wall()), np.ones(304, bool), 5)
    assert found is not None and found.distance_m == pytest.approx(3.0, abs=0.08)
    out = sector_verdicts(_join(noise, _wall()), _evidence(), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID


def _ground(sector=0, n=60):
    cols = np.arange(n) % 32 + (0 if sector == 0 else 32)
    return _points(np.full(n, 2.0), np.arange(n) % 4, cols, obstacle=False, sector=sector)


@pytest.mark.parametrize("blocker", ["ambiguous", "doubtful", "missing"])
def test_feature_free_must_be_earned(blocker: str) -> None:
    """Ground samples alone give NO_RETURN; one ambiguous, doubtful (dropped, lone,
    saturated, foreign) or missing-where-expected sample in the sector makes it INVALID.
    (Protection removed once - the doubtful/missing counts ignored in _verdict - and this
    test failed for "doubtful" and "missing"; ambiguity ignored, it failed for
    "ambiguous".)"""
    points = _join(_ground(0), _ground(1))
    free = sector_verdicts(points, _evidence(), LAYOUT, SETTINGS)
    assert [s.state for s in free] == [SectorState.NO_RETURN] * 2
    counts = np.zeros(WIDTH, np.int64)
    counts[3] = 1  # a column of sector 0
    blocked = sector_verdicts(points, _evidence(**{blocker: counts}), LAYOUT, SETTINGS)
    assert blocked[0].state is SectorState.INVALID
    assert blocked[1].state is SectorState.NO_RETURN


def test_feature_ambiguous_sample_makes_a_valid_sector_invalid() -> None:
    """An ambiguous sample may be the nearest obstacle: no distance is published."""
    counts = np.zeros(WIDTH, np.int64)
    counts[40] = 1
    out = sector_verdicts(_join(_wall(), _points([2.0] * 20, np.arange(20) % 3,
                                                 32 + np.arange(20), sector=1)),
                          _evidence(ambiguous=counts), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID and out[1].state is SectorState.INVALID
    assert out[1].distance_m == 0.0


def test_feature_valid_distance_carries_sigma() -> None:
    out = sector_verdicts(_wall(), _evidence(), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID
    assert 0.0 < out[0].sigma_m < 0.2 and math.isfinite(out[0].sigma_m)
    assert out[1].state is SectorState.INVALID and out[1].sigma_m == 0.0


def test_feature_few_or_weak_points_lower_confidence_to_invalid() -> None:
    """Six wall points (a credible cluster, but 6 of the 15 that give full confidence)
    are not trusted with a distance; 300 are. Peaks below snr_min (which the extraction
    never lets through) would lower it too."""
    few = _wall(n=6)
    assert sector_verdicts(few, _evidence(), LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    faint = _wall()
    faint = ObstaclePoints(faint.range_m, faint.sector, faint.obstacle, faint.line,
                           faint.column, faint.sigma_m, np.full(faint.snr.size, 4.0))
    assert sector_verdicts(faint, _evidence(), LAYOUT, SETTINGS)[0].state is (
        SectorState.INVALID)
    assert sector_verdicts(_wall(), _evidence(), LAYOUT, SETTINGS)[0].state is (
        SectorState.VALID)
