"""The vectorised helpers of the line search give what their plain definitions give.

Each fast path (one sort instead of per-group medians, a broadcast instead of repeats) is
checked against a straightforward reference on representative data: exactly where the
same arithmetic is done, within float32 rounding where numpy's own routine rounds
differently.
"""

from __future__ import annotations

import numpy as np
import pytest
from prior_reference import hidden_as_defined

from atris_node.pipeline.bands import Band, count_in_bands
from atris_node.pipeline.identity import (
    CONTINUITY_BLOCK,
    MIN_BLOCK_SAMPLES,
    MIN_LINE_SAMPLES,
    VisibilityPrior,
    _continuity_reference,
)
from atris_node.pipeline.noise import (
    NOISE_TILE_PX,
    _counted_quartile_and_median,
    _quartile_and_median,
    noise_floor,
    noise_map,
)
from atris_node.pipeline.peaks import (
    ExtractorSettings,
    LineSamples,
    _median_per_line,
    _samples,
    smooth_along_lines,
    supported_along_lines,
)


def _ambient_map(rng: np.random.Generator, height: int = 400, width: int = 640,
                 dtype: type = np.int16) -> np.ndarray:
    """A map with a background that changes across the image and a sunlit patch."""
    background = np.linspace(-20.0, 40.0, width)[None, :] + np.zeros((height, 1))
    sigma = np.full((height, width), 8.0)
    sigma[100:220, 300:500] = 40.0
    return np.round(rng.normal(background, sigma)).astype(dtype)


@pytest.mark.parametrize("dtype", [np.int16, np.int32, np.float64])
@pytest.mark.parametrize("n", [1, 2, 255, 256, 41280])
def test_quartile_and_median_are_numpys_percentiles(dtype: type, n: int) -> None:
    rng = np.random.default_rng(n)
    a = np.round(rng.normal(5.0, 30.0, (3, n))).astype(dtype)
    q25, median = _quartile_and_median(a)
    reference = np.percentile(a.astype(np.float32), [25, 50], axis=-1)
    assert q25.dtype == median.dtype == np.float32
    np.testing.assert_allclose(q25, reference[0], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(median, reference[1], rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("dtype", [np.int16, np.int32, np.uint16, np.int64])
@pytest.mark.parametrize("n", [1, 2, 5, 256, 41281])
def test_counted_order_statistics_are_the_sorted_ones_exactly(dtype: type, n: int) -> None:
    """The counting path of noise_floor gives the very numbers of the sort."""
    rng = np.random.default_rng(n)
    a = np.abs(np.round(rng.normal(5.0, 300.0, n))).astype(dtype)
    a[: n // 100] += 4000  # a tail of laser pixels
    counted = _counted_quartile_and_median(a)
    assert counted is not None
    assert counted == tuple(_quartile_and_median(a))


def test_counting_is_left_to_the_sort_where_it_does_not_pay() -> None:
    wide = np.array([0, 2**21], dtype=np.int32)
    assert _counted_quartile_and_median(wide) is None
    assert _counted_quartile_and_median(np.zeros(4, np.float32)) is None
    assert noise_floor(wide[None, :], [(0, 1)]) == (0.0, 0.5)


def test_noise_map_is_the_per_tile_percentile_statistics() -> None:
    rng = np.random.default_rng(11)
    values = _ambient_map(rng)
    lo, hi = 46, 304
    local = noise_map(values, [(lo, hi)])
    t = NOISE_TILE_PX
    for r in range(lo, hi, t):
        for c in range(0, values.shape[1], t):
            tile = values[r:min(r + t, hi):2, c:c + t:2].astype(np.float32)
            if tile.shape != (t // 2, t // 2):  # edge tiles are padded by reflection
                continue
            q25, median = np.percentile(tile, [25, 50])
            sigma = max((median - q25) / 0.6745, 0.5)
            np.testing.assert_allclose(local.background[r:r + t, c:c + t], median, atol=1e-4)
            np.testing.assert_allclose(local.sigma[r:r + t, c:c + t], sigma, rtol=1e-5)
    assert (local.background[:lo] == 0).all() and (local.sigma[hi:] == 0.5).all()


def test_noise_floor_is_the_percentile_of_the_subsample() -> None:
    rng = np.random.default_rng(12)
    values = _ambient_map(rng)
    spans = [(46, 150), (180, 304)]
    background, sigma = noise_floor(values, spans)
    sample = np.concatenate([values[lo:hi:2, ::2].ravel() for lo, hi in spans])
    q25, median = np.percentile(sample.astype(np.float32), [25, 50])
    assert background == pytest.approx(median, abs=1e-4)
    assert sigma == pytest.approx((median - q25) / 0.6745, rel=1e-5)


def _unexplained_by_definition(prior: VisibilityPrior, rows: np.ndarray) -> np.ndarray:
    """Per column: the unassigned lines that would be seen, inside the image and above the
    ground, at the range of the assigned line fewest places away in image order (the
    nearer range on a tie), if that range is at most z_max."""
    f, cot = prior.focal_px, prior.cot_alpha
    position = np.argsort(np.argsort(cot))  # place of each line in image order
    out = np.zeros(rows.shape[1], dtype=np.int64)
    for c in range(rows.shape[1]):
        z = [f * prior.baseline_m / (f * cot[k] - (rows[k, c] - prior.cy_px))
             if rows[k, c] >= 0 and f * cot[k] - (rows[k, c] - prior.cy_px) > 0 else np.inf
             for k in range(rows.shape[0])]
        for k in np.flatnonzero(rows[:, c] < 0):
            found = [(abs(position[k] - position[j]), z[j]) for j in range(rows.shape[0])
                     if j != k and np.isfinite(z[j])]
            if not found or hidden_as_defined(prior, rows[:, c], z, position, k):
                continue
            near = min(found)[1]
            row = prior.cy_px + f * cot[k] - f * prior.baseline_m / near
            out[c] += int(near <= prior.z_max_m and near < prior.ground_range_m[k, c]
                          and 0 <= row < prior.height_px)
    return out


def test_unexplained_lines_are_their_definition() -> None:
    rng = np.random.default_rng(13)
    cot = np.array([0.25, -0.05, 0.45, 0.05, 0.15, 0.35])  # lines 38 px apart, unordered
    ground = rng.choice([0.8, 2.0, 5.0, np.inf], (6, 300))
    prior = VisibilityPrior(cot, 380.0, 200.0, 400, 0.075, 6.0, ground)
    z = rng.choice([1.0, 2.0, 4.0, 8.0], (6, 300))  # each line's range, so ties matter
    rows = np.round(200.0 + 380.0 * cot[:, None] - 380.0 * 0.075 / z).astype(np.int64)
    rows[(rng.random(rows.shape) < 0.5) | (rows >= 400)] = -1
    rows[:, :5] = -1  # columns without any line
    expected = _unexplained_by_definition(prior, rows)
    assert expected.any()
    np.testing.assert_array_equal(prior.unexplained(rows), expected)
    cols = np.arange(0, 300, 7)
    np.testing.assert_array_equal(prior.unexplained(rows[:, cols], cols), expected[cols])


def _reference_per_line(rows: np.ndarray, good: np.ndarray) -> np.ndarray:
    """The continuity reference of one line (W,), one block at a time with np.median."""
    w, block = rows.size, CONTINUITY_BLOCK
    overall = float(np.median(rows[good])) if good.sum() >= MIN_LINE_SAMPLES else np.inf
    out = np.empty(w)
    for lo in range(0, w, block):
        kept = np.sort(rows[lo:lo + block][good[lo:lo + block]].astype(np.float64))
        out[lo:lo + block] = kept[kept.size // 2] if kept.size >= MIN_BLOCK_SAMPLES else overall
    return out


def test_continuity_reference_is_the_per_line_block_median() -> None:
    rng = np.random.default_rng(14)
    rows = np.round(100 + 20 * np.sin(np.arange(650) / 40.0) + rng.normal(0, 3, (5, 650)))
    rows = rows.astype(np.int64)
    good = rng.random(rows.shape) < np.array([0.9, 0.5, 0.1, 0.02, 0.0])[:, None]
    good[1, 100:300] = False  # blocks without enough samples take the line's median
    reference = np.stack([_reference_per_line(r, g) for r, g in zip(rows, good, strict=True)])
    np.testing.assert_array_equal(_continuity_reference(rows, good), reference)


def test_threshold_and_snr_are_those_of_the_per_pixel_images() -> None:
    rng = np.random.default_rng(15)
    values = _ambient_map(rng)
    local = noise_map(values, [(30, 130), (150, 310)])
    background, sigma = local.background, local.sigma
    assert background.shape == sigma.shape == values.shape
    np.testing.assert_array_equal(local.threshold(6.0), background + 6.0 * sigma)
    assert (background[130:150] == 0).all() and (sigma[310:] == 0.5).all()


def test_sample_snr_is_that_of_the_per_pixel_images() -> None:
    """The SNR the samples carry (computed per peak in the compiled pass) is the peak
    value against the local background and σ images, rows read or not."""
    rng = np.random.default_rng(15)
    values = _ambient_map(rng)
    peak_rows = np.array([60, 140, 200, 330])  # the second and last outside the rows read
    for r in peak_rows:
        values[r - 1:r + 2] += np.array([300, 600, 300], dtype=np.int16)[:, None]
    local = noise_map(values, [(30, 130), (150, 310)])
    rows = np.repeat(peak_rows[:, None], values.shape[1], axis=1)
    samples, strong, _ = _samples(values, np.zeros(values.shape, bool), rows, local,
                                  ExtractorSettings(snr_min=1.0), noise=8.0)
    assert strong == len(samples) == rows.size  # every peak kept: the SNR of each is read
    cols = samples.col_px.astype(np.int64)
    at = peak_rows[samples.line]
    expected = (values[at, cols] - local.background[at, cols].astype(np.float64)) / (
        local.sigma[at, cols])
    np.testing.assert_array_equal(samples.snr, expected)


@pytest.mark.parametrize("count", [1, 3, 8])
def test_median_per_line_is_numpys_median(count: int) -> None:
    rng = np.random.default_rng(count)
    line = rng.integers(0, max(count - 1, 1), 999)  # of several lines, the last has none
    snr = rng.uniform(6.0, 80.0, line.size)
    expected = tuple(float(np.median(snr[line == k])) if (line == k).any() else 0.0
                     for k in range(count))
    assert _median_per_line(line, snr, count) == expected
    assert _median_per_line(line[:0], snr[:0], count) == (0.0,) * count


def _smoothed_by_definition(samples: LineSamples, lines: int, width: int, taps: int
                            ) -> np.ndarray:
    """Rows after the median of 2·(taps // 2) + 1 columns, with np.median and np.ptp."""
    half = taps // 2
    grid = np.full((lines, width + 2 * half), np.inf)
    cols = samples.col_px.astype(np.int64)
    grid[samples.line, cols + half] = samples.row_px
    stack = np.stack([grid[samples.line, cols + half + d] for d in range(-half, half + 1)])
    ok = np.isfinite(stack).all(axis=0)
    ok[ok] = np.ptp(stack[:, ok], axis=0) <= 2.0
    row = samples.row_px.copy()
    row[ok] = np.median(stack[:, ok], axis=0)
    return row


@pytest.mark.parametrize("taps", [3, 4, 5, 9])
def test_smoothing_is_the_median_of_the_neighbouring_columns(taps: int) -> None:
    rng = np.random.default_rng(taps)
    line, col = np.nonzero(rng.random((4, 640)) < 0.8)  # gaps
    row = 50.0 * line + 20.0 * np.sin(col / 50.0) + rng.normal(0.0, 0.4, col.size)
    row[rng.random(col.size) < 0.02] += 9.0  # steps
    samples = LineSamples(line, row, col.astype(np.float64), np.ones(col.size),
                          np.ones(col.size), np.zeros(col.size, bool))
    smoothed = smooth_along_lines(samples, 4, 640, taps)
    np.testing.assert_array_equal(smoothed.row_px,
                                  _smoothed_by_definition(samples, 4, 640, taps))


@pytest.mark.parametrize("reach", [1, 2, 3])
def test_support_is_a_near_sample_of_the_same_line(reach: int) -> None:
    rng = np.random.default_rng(20 + reach)
    line, col = np.nonzero(rng.random((4, 640)) < 0.3)  # many lone samples
    row = 50.0 * line + rng.normal(0.0, 1.5, col.size)
    samples = LineSamples(line, row, col.astype(np.float64), np.ones(col.size),
                          np.ones(col.size), np.zeros(col.size, bool))
    apart = np.abs(col[:, None] - col[None, :])  # every pair of samples
    near = (line[:, None] == line[None, :]) & (apart > 0) & (apart <= reach)
    expected = (near & (np.abs(row[:, None] - row[None, :]) <= 2.0)).any(axis=1)
    got = supported_along_lines(samples, 4, 640, reach)
    assert 0 < got.sum() < col.size
    np.testing.assert_array_equal(got, expected)


def test_peaks_in_bands_are_counted_per_column() -> None:
    rng = np.random.default_rng(16)
    peaks = np.sort(rng.integers(-1, 400, (12, 640)), axis=0)
    bands = (Band(0, 54, 154), Band(1, 74, 175), Band(2, 300, 300), Band(3, 320, 390))
    inside = np.zeros(peaks.shape, dtype=bool)
    for b in bands:
        inside |= (peaks >= b.row_lo) & (peaks < b.row_hi)
    np.testing.assert_array_equal(count_in_bands(peaks, bands), inside.sum(axis=0))


def _greedy_by_definition(column: list[int], bands: list[tuple[int, int]],
                          top_down: bool) -> list[int]:
    """Each band in turn (top down, or bottom up) takes the nearest free peak past the
    previous band's in its own range, or none."""
    out, last = [-1] * len(bands), -1 if top_down else 10**9
    for k in (range(len(bands)) if top_down else reversed(range(len(bands)))):
        lo, hi = bands[k]
        fits = [p for p in column if lo <= p < hi and (p > last if top_down else p < last)]
        if fits:
            out[k] = last = min(fits) if top_down else max(fits)
    return out


def test_greedy_matchings_are_their_definition() -> None:
    from atris_node.pipeline import identity_kernels

    rng = np.random.default_rng(17)
    for _ in range(300):
        k = int(rng.integers(1, 9))
        edges = [(lo, lo + int(rng.integers(0, 120))) for lo in rng.integers(0, 300, k)]
        edges.sort(key=lambda e: e[0] + e[1])  # image order
        m, width = int(rng.integers(1, 14)), 20
        peaks = np.full((m, width), -1, dtype=np.int64)
        for c in range(width):
            n = int(rng.integers(0, m + 1))
            peaks[:n, c] = np.sort(rng.choice(420, n, replace=False))
        lo, hi = (np.array([e[i] for e in edges], dtype=np.int64) for i in (0, 1))
        line = np.arange(k, dtype=np.int64)
        for kernel, top_down in ((identity_kernels.assign_down, True),
                                 (identity_kernels.assign_up, False)):
            got = kernel(peaks, lo, hi, line)
            for c in range(width):
                column = [int(p) for p in peaks[:, c] if p >= 0]
                assert got[:, c].tolist() == _greedy_by_definition(column, edges, top_down)
