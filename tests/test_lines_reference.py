"""The vectorised helpers of the line search give what their plain definitions give.

Each fast path (one sort instead of per-group medians, a broadcast instead of repeats) is
checked against a straightforward reference on representative data: exactly where the
same arithmetic is done, within float32 rounding where numpy's own routine rounds
differently.
"""

from __future__ import annotations

import numpy as np
import pytest

from atris_node.lines import NOISE_TILE_PX, _quartile_and_median, noise_map, noise_floor


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
