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


# --- line identity: the continuity reference and the bookkeeping of the rival test ---


def _local_by_definition(rows: np.ndarray, anchored: np.ndarray, reach: int) -> np.ndarray:
    """The row of each line in the nearest anchored column (not the column itself) within
    ``reach`` holding it, the left one on a tie, inf where none (whole-array numpy)."""
    k_count, width = rows.shape
    cols = np.broadcast_to(np.arange(width), (k_count, width))
    good = (rows >= 0) & anchored[None, :]
    left = np.maximum.accumulate(np.where(good, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(good, cols, width)[:, ::-1], axis=1)[:, ::-1]
    left = np.concatenate([np.full((k_count, 1), -1), left[:, :-1]], axis=1)
    right = np.concatenate([right[:, 1:], np.full((k_count, 1), width)], axis=1)
    left_gap = np.where(left >= 0, cols - left, reach + 1)
    right_gap = np.where(right < width, right - cols, reach + 1)
    k = np.arange(k_count)[:, None]
    row_l = rows[k, np.maximum(left, 0)].astype(np.float64)
    row_r = rows[k, np.minimum(right, width - 1)].astype(np.float64)
    return np.where((left_gap <= reach) & (left_gap <= right_gap), row_l,
                    np.where(right_gap <= reach, row_r, np.inf))


def _reference_by_definition(rows: np.ndarray, anchored: np.ndarray) -> np.ndarray:
    """rivals._reference as it was composed before its single kernel: the local row, the
    block median, the bridge, the line's median where the comb lies on the medians."""
    from atris_node.pipeline import identity_kernels
    from atris_node.pipeline.identity import CONTINUITY_BLOCK, MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES
    from atris_node.pipeline.rivals import CONTINUITY_REACH, MEDIAN_PX

    local = _local_by_definition(rows, anchored, CONTINUITY_REACH)
    good = np.ascontiguousarray((rows >= 0) & anchored[None, :])
    block = identity_kernels.continuity_reference(rows, good, CONTINUITY_BLOCK,
                                                  MIN_BLOCK_SAMPLES, rows.shape[1] + 1)
    line = identity_kernels.continuity_reference(rows, good, rows.shape[1],
                                                 MIN_LINE_SAMPLES, MIN_LINE_SAMPLES)
    bridge, sides = _bridge_by_definition(rows, good)
    far = ~np.isfinite(local) & ~np.isfinite(block) & (sides < 2)
    off = far & (rows >= 0) & (np.abs(rows - line) > MEDIAN_PX)
    line = np.where(off.any(axis=0)[None, :], np.inf, line)
    wide = np.where(np.isfinite(block), block, np.where(sides == 2, bridge, line))
    return np.where(np.isfinite(local), local, wide)


def _random_rows(rng: np.random.Generator, k_count: int, width: int) -> np.ndarray:
    """(K, W) rows of lines on a few surfaces (steps of a few px, gaps), -1 = none."""
    base = 20 * np.arange(k_count)[:, None] + 100
    steps = np.cumsum(rng.integers(-1, 2, (1, width)) * (rng.random((1, width)) < 0.3),
                      axis=1)
    jumps = rng.integers(0, 12, (1, width)) * (rng.random((1, width)) < 0.02)
    rows = base + steps + np.cumsum(jumps, axis=1) + rng.integers(-3, 4, (k_count, width))
    holes = rng.random((k_count, width)) < rng.random()
    return np.where(holes, -1, rows).astype(np.int64)


def test_continuity_reference_of_the_rival_test_is_the_composed_form() -> None:
    """400 random row tables and anchor masks (sparse to dense, widths past a block and
    the continuity reach): rivals._reference, one kernel, equals the composition of the
    local row, block median, bridge and line median it replaced, bitwise."""
    from atris_node.pipeline.rivals import _reference

    rng = np.random.default_rng(21)
    for _ in range(400):
        k_count, width = int(rng.integers(1, 9)), int(rng.integers(1, 200))
        rows = _random_rows(rng, k_count, width)
        anchored = rng.random(width) < rng.random()
        if rng.random() < 0.3:  # anchored runs with wide gaps between them
            anchored = np.repeat(rng.random(width // 20 + 1) < 0.4, 20)[:width]
        got = _reference(rows, anchored)
        want = _reference_by_definition(rows, anchored)
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)


def _set_aside_numpy(peaks: np.ndarray, drop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """rivals.set_aside as it was in numpy: a sort of every column."""
    big = np.iinfo(np.int64).max
    kept = np.sort(np.where(drop | (peaks < 0), big, peaks), axis=0)
    return np.where(kept == big, -1, kept), drop.sum(axis=0).astype(np.int64)


def _random_peaks(rng: np.random.Generator, m_count: int, width: int) -> np.ndarray:
    """(M, W) distinct peak rows per column, sorted down with -1 padding last, or in any
    order with -1 anywhere."""
    rows = np.sort(rng.permuted(np.tile(np.arange(400), (width, 1)), axis=1)[:, :m_count],
                   axis=1).T.astype(np.int64)
    n = rng.integers(0, m_count + 1, width)
    peaks = np.where(np.arange(m_count)[:, None] < n[None, :], rows, -1)
    return rng.permuted(peaks, axis=0) if rng.random() < 0.3 else peaks


def test_set_aside_is_the_numpy_sort() -> None:
    """300 random peak tables (sorted columns and columns in any order) and drop masks
    (also on the padding): the compiled set_aside equals the numpy sort, bitwise."""
    from atris_node.pipeline.rivals import set_aside

    rng = np.random.default_rng(22)
    for _ in range(300):
        peaks = _random_peaks(rng, int(rng.integers(1, 14)), int(rng.integers(1, 80)))
        drop = rng.random(peaks.shape) < rng.random()
        got, want = set_aside(peaks, drop), _set_aside_numpy(peaks, drop)
        for g, w in zip(got, want, strict=True):
            assert g.dtype == w.dtype and g.shape == w.shape
            np.testing.assert_array_equal(g, w)


def _doubts_numpy(peaks: np.ndarray, first: np.ndarray, rows: np.ndarray,
                  nearest: np.ndarray, unsure: np.ndarray, bands: Any) -> tuple[np.ndarray, ...]:
    """rivals._unique's bookkeeping as it was in numpy: the unsure counts, the removed
    samples with their nearest rival, the unplaced peaks with their lowest band."""
    from atris_node.pipeline.bands import in_image_order

    before = (first >= 0).sum(axis=0)
    k, c = np.nonzero(nearest >= 0)
    rivalled = (first[k, c], c.astype(np.int64), nearest[k, c])
    placed = ((peaks[None, :, :] == rows[:, None, :]) & (rows[:, None, :] >= 0)).any(axis=0)
    unplaced = (peaks >= 0) & ~placed & (unsure > 0)[None, :]
    marked = np.zeros(peaks.shape, dtype=np.bool_)
    m, n = np.nonzero(peaks[:, rivalled[1]] == rivalled[0][None, :])
    marked[m, rivalled[1][n]] = True
    unplaced &= ~marked
    i, j = np.nonzero(unplaced)
    lo, hi, order = in_image_order(bands)
    row = peaks[i, j]
    inside = (row[:, None] >= lo[None, :]) & (row[:, None] < hi[None, :])
    last = inside.shape[1] - 1 - inside[:, ::-1].argmax(axis=1)
    lowest = np.where(inside.any(axis=1), order[last], -1).astype(np.int64)
    known = lowest >= 0
    return (unsure + np.maximum(before - (rows >= 0).sum(axis=0), 0),
            np.concatenate([rivalled[0], row[known]]),
            np.concatenate([rivalled[1], j[known].astype(np.int64)]),
            np.concatenate([rivalled[2], lowest[known]]))


def _random_identity(rng: np.random.Generator, peaks: np.ndarray, k_count: int
                     ) -> np.ndarray:
    """(K, W) rows by line taken from ``peaks`` (some lines without one)."""
    m_count, width = peaks.shape
    pick = peaks[rng.integers(0, m_count, (k_count, width)), np.arange(width)[None, :]]
    return np.where(rng.random((k_count, width)) < 0.7, pick, -1).astype(np.int64)


def test_doubts_of_the_rival_test_are_the_numpy_form() -> None:
    """300 random identities before and after a rival test, with nearest rival lines and
    unsure counts: rivals_kernels.doubts equals the numpy bookkeeping it replaced (values
    and order of the doubts), bitwise."""
    from atris_node.pipeline import rivals_kernels
    from atris_node.pipeline.bands import Band, in_image_order

    rng = np.random.default_rng(23)
    for _ in range(300):
        k_count = int(rng.integers(1, 9))
        peaks = _random_peaks(rng, int(rng.integers(1, 14)), int(rng.integers(1, 80)))
        width = peaks.shape[1]
        edges = np.sort(rng.integers(0, 400, (k_count, 2)), axis=1)
        bands = tuple(Band(int(k), int(a), int(b)) for k, (a, b) in
                      zip(rng.permutation(k_count), edges, strict=True))
        first = _random_identity(rng, peaks, k_count)
        removed = (first >= 0) & (rng.random(first.shape) < 0.2)
        rows = np.where(removed | (rng.random(first.shape) < 0.05), -1, first)
        nearest = np.where(removed, rng.integers(0, k_count, first.shape), -1).astype(np.int64)
        unsure = (rng.integers(0, 3, width) * (rng.random(width) < 0.5)).astype(np.int64)
        lo, hi, order = in_image_order(bands)
        got = rivals_kernels.doubts(peaks, first, rows, nearest, unsure, lo, hi, order)
        want = _doubts_numpy(peaks, first, rows, nearest, unsure, bands)
        for g, w in zip(got, want, strict=True):
            assert g.dtype == w.dtype and g.shape == w.shape
            np.testing.assert_array_equal(g, w)


def _stable_numpy(rows: np.ndarray, alone: np.ndarray, held: np.ndarray,
                  position: np.ndarray) -> tuple[np.ndarray, ...]:
    """rivals.robust_identity's comparison of the two identities as it was in numpy."""
    unstable = ((rows != alone) & ((alone >= 0) | held)).any(axis=0)
    dropped = unstable[None, :] & (rows != alone) & (rows >= 0)
    kept = np.where(dropped, -1, rows)
    lost = (rows >= 0).sum(axis=0) - (kept >= 0).sum(axis=0)
    k, c = np.nonzero(dropped)
    match = alone[:, c] == rows[k, c][None, :]
    other = np.where(match.any(axis=0), match.argmax(axis=0), -1).astype(np.int64)
    nearer = np.where((other >= 0) & (position[np.maximum(other, 0)] > position[k]), other, k)
    return kept, lost, rows[k, c], c.astype(np.int64), nearer.astype(np.int64)


def test_stable_identity_is_the_numpy_form() -> None:
    """300 random pairs of identities (with and without the weak peaks) and weak masks:
    rivals_kernels.stable equals the numpy comparison it replaced, bitwise."""
    from atris_node.pipeline import rivals_kernels

    rng = np.random.default_rng(24)
    for _ in range(300):
        k_count = int(rng.integers(1, 9))
        peaks = _random_peaks(rng, int(rng.integers(1, 14)), int(rng.integers(1, 80)))
        rows = _random_identity(rng, peaks, k_count)
        alone = np.where(rng.random(rows.shape) < 0.1, _random_identity(rng, peaks, k_count),
                         rows)
        held = np.ascontiguousarray((rows >= 0) & (rng.random(rows.shape) < 0.8))
        position = rng.permutation(k_count).astype(np.int64)
        got = rivals_kernels.stable(rows, alone, held, position)
        want = _stable_numpy(rows, alone, held, position)
        for g, w in zip(got, want, strict=True):
            assert g.dtype == w.dtype and g.shape == w.shape
            np.testing.assert_array_equal(g, w)


def test_continuity_reference_of_some_columns_is_that_of_all_columns_there() -> None:
    """The rounds of the rival test take the continuity reference only in the columns they
    test: on 200 random tables and column subsets it equals the whole reference there
    (and is inf elsewhere), bitwise."""
    from atris_node.pipeline import rivals_kernels
    from atris_node.pipeline.identity import CONTINUITY_BLOCK, MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES
    from atris_node.pipeline.rivals import BRIDGE_PX, CONTINUITY_REACH, MEDIAN_PX, _reference

    rng = np.random.default_rng(25)
    for _ in range(200):
        k_count, width = int(rng.integers(1, 9)), int(rng.integers(1, 200))
        rows = _random_rows(rng, k_count, width)
        anchored = rng.random(width) < rng.random()
        columns = np.flatnonzero(rng.random(width) < rng.random()).astype(np.int64)
        got = rivals_kernels.continuity(rows, anchored, columns, CONTINUITY_REACH,
                                        CONTINUITY_BLOCK, MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES,
                                        BRIDGE_PX, MEDIAN_PX)
        want = np.full(rows.shape, np.inf)
        want[:, columns] = _reference(rows, anchored)[:, columns]
        np.testing.assert_array_equal(got, want)
