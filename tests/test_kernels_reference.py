"""Compiled passes that replaced numpy steps give the numpy steps' numbers, bitwise, on
simulated maps: the numpy forms are kept here as the reference."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from atris_node.codes import walsh_chips
from atris_node.demod import BlockDemodulator
from atris_node.pipeline import peaks
from atris_node.pipeline.bands import line_bands, read_rows
from atris_node.pipeline.noise import NOISE_TILE_PX, NoiseMap, noise_map
from atris_node.sim import Simulator, load_scene
from atris_node.types import DistortionMap

SCENES = ("indoor_lab", "window_sun", "jammer_line")


def _first_map(name: str) -> tuple[DistortionMap, Any]:
    scene = load_scene(name)
    chips = walsh_chips(scene.code_length, scene.code_row)
    sim = Simulator(scene, chips=chips, seed=1)
    demod = BlockDemodulator(chips, bits=scene.camera.bits, lag=0)
    sequence = 0
    while True:
        dmap = demod.push(sim.render(sequence))
        sequence += 1
        if dmap is not None:
            return dmap, sim.calibration()


@pytest.fixture(scope="module", params=SCENES)
def scene_map(request: pytest.FixtureRequest) -> tuple[DistortionMap, list[tuple[int, int]],
                                                          NoiseMap]:
    dmap, calibration = _first_map(request.param)
    bands = line_bands(calibration.camera, calibration.laser, 0.3, 10.0, 3.0)
    spans = read_rows(bands, peaks.read_padding(peaks.ExtractorSettings()),
                      dmap.values.shape[0])
    return dmap, spans, noise_map(dmap.values, spans)


def _peak_snr_numpy(values: npt.NDArray[Any], local: NoiseMap,
                    rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
    """The numpy form peaks._peak_snr had before its compiled pass."""
    width = rows.shape[1]
    cols = np.broadcast_to(np.arange(width), rows.shape)
    at = np.maximum(rows, 0)
    tile_row = local.tile_row[at]
    tile_col = cols // NOISE_TILE_PX
    value = values[at, cols].astype(np.float64)
    snr = (value - local.background_tiles[tile_row, tile_col]) / local.sigma_tiles[
        tile_row, tile_col]
    return np.where(rows >= 0, snr, 0.0)


def test_smoke_peak_snr_is_the_numpy_form(scene_map: tuple[Any, Any, NoiseMap]) -> None:
    dmap, spans, local = scene_map
    found = peaks.strong_maxima(dmap.values, spans, local, 6.0, 3, 12)
    rng = np.random.default_rng(0)
    height, width = dmap.values.shape
    anywhere = rng.integers(-1, height, (4, width))  # rows outside the bands read too
    for rows in (found, anywhere):
        want = _peak_snr_numpy(dmap.values, local, rows)
        got = peaks._peak_snr(dmap.values, local, rows)
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
    assert (found >= 0).sum() > 100



def _bridge_by_definition(rows: np.ndarray, good: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """rivals' bridge written with whole-array numpy (the form it had before the kernel):
    the nearest good column's row on each side, their nearer one where they agree within
    BRIDGE_PX, and how many sides have one."""
    from atris_node.pipeline.rivals import BRIDGE_PX

    k_count, width = rows.shape
    cols = np.broadcast_to(np.arange(width), (k_count, width))
    left = np.maximum.accumulate(np.where(good, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(good, cols, width)[:, ::-1], axis=1)[:, ::-1]
    k = np.arange(k_count)[:, None]
    row_l = np.where(left >= 0, rows[k, np.maximum(left, 0)], np.inf).astype(np.float64)
    row_r = np.where(right < width, rows[k, np.minimum(right, width - 1)],
                     np.inf).astype(np.float64)
    both = np.isfinite(row_l) & np.isfinite(row_r)
    nearer = np.where(cols - left <= right - cols, row_l, row_r)
    with np.errstate(invalid="ignore"):
        agree = np.abs(row_l - row_r) <= BRIDGE_PX
    sides = np.isfinite(row_l).astype(np.int64) + np.isfinite(row_r).astype(np.int64)
    return np.where(both & agree, nearer, np.inf), sides


def test_bridge_is_the_numpy_form() -> None:
    """300 random (K, W) row tables and anchor masks: the compiled bridge equals the numpy
    definition exactly (rows and side counts)."""
    from atris_node.pipeline import rivals_kernels
    from atris_node.pipeline.rivals import BRIDGE_PX

    rng = np.random.default_rng(3)
    for _ in range(300):
        k_count, width = int(rng.integers(1, 6)), int(rng.integers(1, 60))
        rows = rng.integers(-1, 40, (k_count, width)).astype(np.int64)
        good = np.ascontiguousarray((rng.random((k_count, width)) < rng.random()) & (rows >= 0))
        expected = _bridge_by_definition(rows, good)
        got = rivals_kernels.bridge(rows, good, float(BRIDGE_PX))
        np.testing.assert_array_equal(got[0], expected[0])
        np.testing.assert_array_equal(got[1], expected[1])


# --- sector verdicts (atris_node.pipeline.verdicts_kernels) ---------------------------


def _runs_numpy(mask: npt.NDArray[np.bool_]) -> tuple[npt.NDArray[np.int64], ...]:
    """The numpy form verdicts._runs had before its compiled pass."""
    step = np.diff(mask.astype(np.int8), axis=1, prepend=0, append=0)
    row, start = np.nonzero(step == 1)
    stop = np.nonzero(step == -1)[1]
    return row.astype(np.int64), start.astype(np.int64), stop.astype(np.int64)


def test_runs_is_the_numpy_form() -> None:
    """500 random (K, W) masks of every density: the compiled runs equal the numpy
    definition (rows, starts, stops, in order)."""
    from atris_node.pipeline import verdicts_kernels

    rng = np.random.default_rng(5)
    for _ in range(500):
        k_count, width = int(rng.integers(1, 9)), int(rng.integers(1, 70))
        mask = rng.random((k_count, width)) < rng.random()
        if rng.random() < 0.3:
            mask = np.asfortranarray(mask)
        for got, expected in zip(verdicts_kernels.runs(mask), _runs_numpy(mask), strict=True):
            np.testing.assert_array_equal(got, expected)


def _expected_on_surface_numpy(column: Any, depth: Any, line: Any, prior: Any,
                               noisy: Any) -> tuple[int, Any, Any]:
    """The numpy form verdicts._expected_on_surface had before its compiled pass."""
    from atris_node.pipeline.verdicts import SURFACE_ROWS_PX, SURFACE_SEEN_ROWS_PX

    lines = prior.cot_alpha.size
    rank = prior.image_rank
    columns, group = np.unique(column, return_inverse=True)
    z = np.bincount(group, weights=depth) / np.bincount(group)
    held = np.zeros((columns.size, lines), dtype=np.bool_)
    held[group, rank[line]] = True
    top = held.argmax(axis=1)
    low = lines - 1 - held[:, ::-1].argmax(axis=1)
    fb = prior.focal_px * prior.baseline_m
    with np.errstate(divide="ignore", invalid="ignore"):
        rows_off = fb / z[None, :] - fb / prior.ground_range_m[:, columns]
        row = prior.cy_px + prior.focal_px * prior.cot_alpha[:, None] - fb / z[None, :]
    reached = np.asarray(held.any(axis=0), dtype=np.bool_)[rank]
    margin = np.where(reached, SURFACE_SEEN_ROWS_PX, SURFACE_ROWS_PX)
    here = ((rank[:, None] > top[None, :]) & (rows_off >= margin[:, None]) & (row >= 0)
            & (row < prior.height_px))
    if noisy is not None:
        here &= ~noisy[:, columns]
    first, last = int(columns.min()), int(columns.max())
    onto = np.zeros((lines, last - first + 2), dtype=np.bool_)
    onto[:, columns - first] = here
    bottom = np.full(onto.shape[1], -1, dtype=np.int64)
    bottom[columns - first] = low
    return first, onto, bottom


def test_expected_on_surface_is_the_numpy_form() -> None:
    """400 random surfaces (columns with gaps and repeats, depths near the ground rows,
    some zero) under random priors (lines out of image order, ground ranges of inf,
    noisy bands or none): the compiled pass gives the numpy definition's first column,
    expected lines and lowest seen lines, bitwise."""
    from atris_node.pipeline.identity import VisibilityPrior
    from atris_node.pipeline.verdicts import ColumnEvidence, ObstaclePoints
    from atris_node.pipeline.verdicts import _expected_on_surface as compiled

    rng = np.random.default_rng(8)
    for _ in range(400):
        lines, width = int(rng.integers(1, 9)), int(rng.integers(4, 90))
        cot = rng.permutation(np.linspace(-0.4, 0.4, lines)) + rng.normal(0, 0.01, lines)
        ground = rng.uniform(0.5, 12.0, (lines, width))
        ground[rng.random((lines, width)) < 0.2] = np.inf
        prior = VisibilityPrior(cot, float(rng.uniform(300, 900)), float(rng.uniform(150, 500)),
                                int(rng.integers(200, 900)), float(rng.uniform(0.05, 0.1)),
                                10.0, ground)
        n = int(rng.integers(1, 60))
        column = rng.integers(0, width, n).astype(np.int64)
        line = rng.integers(0, lines, n).astype(np.int64)
        depth = rng.choice(ground[line, column], n) * rng.uniform(0.3, 1.2, n)
        depth = np.where(np.isfinite(depth), depth, rng.uniform(0.3, 10.0, n))
        depth[rng.random(n) < 0.05] = 0.0
        noisy = None if rng.random() < 0.5 else rng.random((lines, width)) < 0.2
        surface = ObstaclePoints(depth, np.zeros(n, np.int64), np.ones(n, bool), line, column,
                                 np.full(n, 0.01), np.full(n, 20.0), depth)
        zero = np.zeros(width, np.int64)
        got = compiled(surface, ColumnEvidence(zero, zero, zero, zero, noisy=noisy), prior)
        expected = _expected_on_surface_numpy(column, depth, line, prior, noisy)
        assert got[0] == expected[0]
        np.testing.assert_array_equal(got[1], expected[1])
        np.testing.assert_array_equal(got[2], expected[2])


def _line_holes_numpy(points: Any, seen: Any, noisy: Any, bright_snr: float
                      ) -> tuple[Any, ...]:
    """The numpy form verdicts.LineHoles.of (and the bright flanks that shadowed_columns
    asked of each hole) had before their compiled pass."""
    from atris_node.pipeline.verdicts import GAP_RUN

    lines, width = seen.shape
    flank = np.full((lines, width), np.nan)
    flank[points.line[points.obstacle], points.column[points.obstacle]] = (
        points.range_m[points.obstacle])
    k, start, stop = _runs_numpy(~seen)
    keep = (start > 0) & (stop < width) & (stop - start >= GAP_RUN)
    k, start, stop = k[keep], start[keep], stop[keep]
    left, right = flank[k, start - 1], flank[k, stop]
    flanked = np.isfinite(left) & np.isfinite(right)
    hidden = np.zeros(k.size, dtype=np.bool_)
    if noisy is not None and k.size:
        inside = np.cumsum(np.concatenate([np.zeros((lines, 1), np.int64),
                                           noisy.astype(np.int64)], axis=1), axis=1)
        hidden = 2 * (inside[k, stop] - inside[k, start]) >= stop - start
    keep = flanked | hidden
    nearer = np.where(flanked, np.minimum(left, right), np.inf)
    farther = np.where(flanked, np.maximum(left, right), np.inf)
    k, start, stop = k[keep], start[keep], stop[keep]
    bright = np.zeros(k.size, dtype=np.bool_)
    for i, (line, a, b) in enumerate(zip(k, start, stop, strict=True)):
        mine = (points.line == line) & points.obstacle & (points.snr >= bright_snr)
        before = (points.column >= a - GAP_RUN) & (points.column < a)
        after = (points.column >= b) & (points.column < b + GAP_RUN)
        bright[i] = (np.unique(points.column[mine & before]).size == GAP_RUN
                     and np.unique(points.column[mine & after]).size == GAP_RUN)
    return k, start, stop, nearer[keep], farther[keep], hidden[keep], bright


def test_line_holes_are_the_numpy_form() -> None:
    """400 random maps of seen lines (holes of every width, at the edges too), noisy
    bands or none, and points on them (obstacles or not, several in one line and column,
    bright or not): the compiled LineHoles.of gives the numpy definition's holes, flanks,
    noisy and bright flags, bitwise."""
    from atris_node.pipeline.verdicts import LineHoles, ObstaclePoints

    rng = np.random.default_rng(9)
    for _ in range(400):
        lines, width = int(rng.integers(1, 9)), int(rng.integers(2, 90))
        seen = rng.random((lines, width)) < rng.uniform(0.3, 0.95)
        noisy = None if rng.random() < 0.4 else rng.random((lines, width)) < rng.random()
        k, c = np.nonzero(seen)
        n = k.size
        pick = rng.integers(0, max(n, 1), int(rng.integers(0, 2 * n + 1))) if n else (
            np.zeros(0, np.int64))
        line, column = k[pick].astype(np.int64), c[pick].astype(np.int64)
        m = line.size
        points = ObstaclePoints(rng.uniform(0.3, 10.0, m), np.zeros(m, np.int64),
                                rng.random(m) < rng.choice([0.8, 1.0]), line, column,
                                np.full(m, 0.01), rng.uniform(6.0, 90.0, m))
        snr = float(rng.choice([0.0, 40.0, 60.0, np.inf]))
        got = LineHoles.of(points, seen, noisy, snr)
        expected = _line_holes_numpy(points, seen, noisy, snr)
        for name, value in zip(("line", "start", "stop", "nearer_m", "farther_m", "noisy",
                                "bright"), expected, strict=True):
            np.testing.assert_array_equal(getattr(got, name), value, err_msg=name)
    # bright flanks that just fit: a hole at columns 3..5 of a 9-column line, lit around
    seen = np.array([[True] * 3 + [False] * 3 + [True] * 3])
    edge = ObstaclePoints(np.full(6, 2.0), np.zeros(6, np.int64), np.ones(6, bool),
                          np.zeros(6, np.int64), np.array([0, 1, 2, 6, 7, 8]),
                          np.full(6, 0.01), np.full(6, 50.0))
    for snr in (50.0, 51.0):
        got = LineHoles.of(edge, seen, None, snr)
        expected = _line_holes_numpy(edge, seen, None, snr)
        assert got.bright.tolist() == expected[-1].tolist() == [snr == 50.0]
