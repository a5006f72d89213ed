"""A still stripe keeps its line (atris_node.pipeline.persistence): the identity of a map
is checked against the map before it, where a stripe has not moved."""

from __future__ import annotations

import numpy as np

from atris_node.pipeline import persistence
from atris_node.pipeline.geometry import Points
from atris_node.pipeline.peaks import LineSamples

WIDTH = 8


def _samples(lines: list[int], rows: list[float], cols: list[int]) -> LineSamples:
    n = len(lines)
    return LineSamples(np.array(lines, np.int64), np.array(rows), np.array(cols, np.float64),
                       np.full(n, 50.0), np.full(n, 0.1), np.zeros(n, bool))


def _points(depth_m: list[float], valid: list[bool] | None = None) -> Points:
    z = np.array(depth_m)
    xyz = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    return Points(xyz, np.array(valid if valid is not None else [True] * z.size),
                  np.zeros(z.size))


def test_feature_a_still_stripe_given_another_line_is_flipped() -> None:
    """The earlier map had line 0 at row 203.5 in column 3 and line 1 at row 250 in
    column 5. Now: line 2 at row 203.1 in column 3 (the same stripe, another line:
    flipped, earlier line 0); line 0 at row 203.3 in column 3 would be the same line (not
    flipped); line 1 at row 262 in column 5 moved (not flipped); line 1 in column 6,
    where the earlier map kept nothing, is not asked; the first map asks nothing."""
    earlier = persistence.rows_by_line(_samples([0, 1], [203.5, 250.0], [3, 5]), 3, WIDTH)
    assert np.isnan(earlier).sum() == 3 * WIDTH - 2
    now = _samples([2, 0, 1, 1], [203.1, 203.3, 262.0, 203.0], [3, 3, 5, 6])
    flip, before = persistence.flipped(now, earlier)
    assert flip.tolist() == [True, False, False, False]
    assert before.tolist() == [0, -1, -1, -1]
    flip, before = persistence.flipped(now, None)
    assert not flip.any() and (before == -1).all()


def test_feature_only_a_flip_to_another_obstacle_conflicts() -> None:
    """0.56 m against 6.2 m (a comb shifted by two lines) and a hypothesis outside the
    range conflict; 8.0 m against 8.1 m (near-parallel sheets, within max(10 %, 20 cm))
    does not."""
    now = _points([0.56, 8.0, 3.0])
    before = _points([6.2, 8.1, 3.0], [True, True, False])
    assert persistence.conflicts(now, before).tolist() == [True, False, True]


def _flipped_numpy(samples: LineSamples, earlier: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reference form of persistence.flipped (whole-array numpy)."""
    n, width = len(samples), earlier.shape[1]
    col = np.clip(np.rint(samples.col_px).astype(np.int64), 0, width - 1)
    line = samples.line.astype(np.int64)
    offset = np.abs(earlier[:, col] - samples.row_px[None, :])
    offset = np.where(np.isnan(offset), np.inf, offset)
    own = offset[line, np.arange(n)] <= persistence.STILL_PX
    offset[line, np.arange(n)] = np.inf
    nearest = np.argmin(offset, axis=0)
    flip = ~own & (offset[nearest, np.arange(n)] <= persistence.STILL_PX)
    return flip, np.where(flip, nearest, -1)


def test_flipped_is_the_numpy_form() -> None:
    """The compiled pass against the numpy form on random combs (rows on a 0.5 px grid, so
    ties and offsets of exactly STILL_PX occur), with gaps in both maps."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        lines, width, n = 5, 40, 120
        earlier = np.round(rng.uniform(0, 30, (lines, width)) * 2) / 2
        earlier[rng.random((lines, width)) < 0.3] = np.nan
        now = LineSamples(rng.integers(0, lines, n), np.round(rng.uniform(0, 30, n) * 2) / 2,
                          rng.integers(-2, width + 2, n).astype(np.float64), np.ones(n),
                          np.ones(n), np.zeros(n, bool))
        flip, before = persistence.flipped(now, earlier)
        want_flip, want_before = _flipped_numpy(now, earlier)
        assert np.array_equal(flip, want_flip) and np.array_equal(before, want_before)
        assert flip.any()
