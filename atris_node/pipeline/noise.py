"""Background and noise floor of the distortion map rows read, globally and per tile.

Laser pixels only add positive values, so the lower half of the distribution of a map's
values is background noise alone: σ comes from the lower quartile. Shot noise grows with
the ambient light, so :class:`NoiseMap` keeps one median and σ per square tile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node.pipeline import peaks_kernels

IntArray = npt.NDArray[np.int64]

#: distance from the median to the lower quartile of a normal distribution, in σ
QUARTILE_TO_SIGMA = 0.6745
#: the smallest noise floor used, DN (quantisation of an integer map is 0.29 DN)
MIN_NOISE_DN = 0.5
#: side of the square tiles of the local noise estimate, pixels
NOISE_TILE_PX = 32


def noise_floor(values: npt.NDArray[np.generic], spans: list[tuple[int, int]]) -> tuple[
        float, float]:
    """(median, robust σ) in DN of the map rows in ``spans`` (a 2×2 subsample).

    σ comes from the lower quartile, ``(median - q25) / 0.6745``: laser pixels only add
    positive values, so the lower half of the distribution is background noise alone.
    An int16 or int32 map's subsample is counted where it lies, in one compiled pass
    (:func:`_subsample_quartile_and_median`); other maps' is gathered first.
    """
    height, width = values.shape
    rows = [range(*slice(lo, hi, 2).indices(height)) for lo, hi in spans]
    if sum(len(r) for r in rows) * len(range(0, width, 2)) == 0:
        return 0.0, MIN_NOISE_DN
    counted = _subsample_quartile_and_median(values, rows)
    if counted is None:
        sample = np.concatenate([values[lo:hi:2, ::2].ravel() for lo, hi in spans])
        counted = _counted_quartile_and_median(sample)
        q25, median = counted if counted is not None else _quartile_and_median(sample)
    else:
        q25, median = counted
    return float(median), max(float(median - q25) / QUARTILE_TO_SIGMA, MIN_NOISE_DN)


#: value range (max - min + 1) up to which order statistics are counted, not sorted
COUNTED_RANGE_MAX = 1 << 20


def _subsample_quartile_and_median(values: npt.NDArray[Any], rows: list[range]
                                   ) -> tuple[np.float32, np.float32] | None:
    """:func:`_counted_quartile_and_median` of the 2×2 subsample of an int16 or int32
    ``values`` (H, W) on the ``rows`` (steps of 2), counted in place
    (:func:`atris_node.pipeline.peaks_kernels.subsample_counts`) with no copy of the
    subsample; None for other dtypes or a value range above COUNTED_RANGE_MAX.

    The counts start at the least value of the whole rows, at or below the subsample's
    least: the empty counts below it move no order statistic, so the numbers are those
    of the subsample's own counts (and of its sort)."""
    if values.dtype not in (np.int16, np.int32):
        return None
    values = np.ascontiguousarray(values)
    starts = np.array([r.start for r in rows], dtype=np.int64)
    stops = np.array([r.stop for r in rows], dtype=np.int64)
    low, high = peaks_kernels.rows_range(values, starts, stops)
    if high - low + 1 > COUNTED_RANGE_MAX:
        return None
    counts = peaks_kernels.subsample_counts(values, starts, stops, low, high - low + 1)
    n = sum(len(r) for r in rows) * len(range(0, values.shape[1], 2))
    return _quartile_and_median_of_counts(low, counts, n)


def _counted_quartile_and_median(a: npt.NDArray[Any]) -> tuple[np.float32, np.float32] | None:
    """:func:`_quartile_and_median` of a 1-D integer ``a`` by counting (``np.bincount``,
    O(n + range)) instead of sorting (several times faster on a 2 MP map's 0.5 M
    samples); None for other dtypes or a value range above COUNTED_RANGE_MAX.

    The k-th smallest value is the first value whose cumulative count exceeds k, the
    same element a sort puts at index k, so the numbers are identical.
    """
    if a.ndim != 1 or a.size == 0 or a.dtype.kind not in "iu":
        return None
    low, high = int(a.min()), int(a.max())
    if high - low + 1 > COUNTED_RANGE_MAX:
        return None
    counts = np.bincount((a - low).astype(np.intp, copy=False))
    return _quartile_and_median_of_counts(low, counts, a.size)


def _quartile_and_median_of_counts(low: int, counts: npt.NDArray[Any], n: int
                                   ) -> tuple[np.float32, np.float32]:
    """(25th percentile, median), float32 as :func:`_quartile_and_median`, of the ``n``
    values whose counts of ``low``, ``low + 1``, ... are ``counts``: the k-th smallest
    value is the first whose cumulative count exceeds k."""
    cumulative = np.cumsum(counts)

    def kth(k: int) -> np.float32:
        return np.float32(low + int(np.searchsorted(cumulative, k, side="right")))

    def at(position: float) -> np.float32:
        i, frac = divmod(position, 1.0)
        value = kth(int(i))
        if not frac:
            return value
        return np.float32(value + np.float32(frac) * (kth(min(int(i) + 1, n - 1)) - value))

    return at((n - 1) * 0.25), at((n - 1) * 0.5)


def _quartile_and_median(a: npt.NDArray[Any]) -> tuple[Any, Any]:
    """(25th percentile, median) along the last axis of ``a`` (any real dtype), float32,
    as ``np.percentile`` computes them on ``a.astype(np.float32)`` (linear interpolation).

    One sort in the input's own dtype: numpy's vectorised sort is several times faster
    than a partition at four indices, and converting only the picked values to float32
    gives the same numbers (the conversion keeps the order).
    """
    picks, (f25, f50) = _percentile_picks(a.shape[-1])
    ordered = np.sort(a, axis=-1)[..., picks]

    def at(i: int, frac: float) -> Any:
        low = ordered[..., i].astype(np.float32)
        if not frac:
            return low
        return low + frac * (ordered[..., i + 1].astype(np.float32) - low)

    return at(0, f25), at(2, f50)


def _percentile_picks(n: int) -> tuple[list[int], tuple[float, float]]:
    """The positions in n sorted values between which the 25th percentile and the median
    are interpolated (the lower and upper of each), and the two fractions."""
    lo25, f25 = divmod((n - 1) * 0.25, 1.0)
    lo50, f50 = divmod((n - 1) * 0.5, 1.0)
    return ([int(lo25), min(int(lo25) + 1, n - 1), int(lo50), min(int(lo50) + 1, n - 1)],
            (f25, f50))


def median_of(values: npt.NDArray[Any]) -> float:
    """``float(np.median(values))`` of a non-empty float array of any shape, as np.median
    computes it (the mean of the middle value, or of the middle two, in the array's dtype),
    by one partition at the upper middle (the lower is the greatest value before it)
    without np.median's overhead (12 against 3 µs at 640 tiles). NaN is left to
    np.median."""
    flat = values.reshape(-1)
    n = flat.size
    if n == 0 or np.isnan(flat).any():
        return float(np.median(values))
    half = n // 2
    part = np.partition(flat, half)
    zero = flat.dtype.type(0.0)  # np.mean adds to +0 (a median of -0 values is +0)
    if n % 2:
        return float(zero + part[half])
    return float((zero + part[:half].max() + part[half]) / 2)


@dataclass(frozen=True)
class NoiseMap:
    """Local background and noise σ (DN) per NOISE_TILE_PX square tile of the rows read.

    Shot noise grows with the ambient light, so a sunlit patch is noisier than the rest:
    one global threshold would take its noise for peaks. Each NOISE_TILE_PX square tile
    of the rows read gets its own median and ``(median - q25) / 0.6745`` (2×2 subsample).

    ``background_tiles`` and ``sigma_tiles`` (R + 1, C) float32 hold the tiles of every
    span stacked, and in their last row the values outside the rows read (0 and
    MIN_NOISE_DN); ``tile_row`` (H,) int64 gives each image row its row of tiles (-1, the
    last, outside the rows read). Column c lies in tile column ``c // NOISE_TILE_PX``.
    Per-pixel (H, W) float32 images are made only where asked for.
    """

    tile_row: IntArray
    background_tiles: npt.NDArray[np.float32]
    sigma_tiles: npt.NDArray[np.float32]
    width: int

    @property
    def background(self) -> npt.NDArray[np.float32]:
        """(H, W) float32 local background, DN."""
        return self._image(self.background_tiles)

    @property
    def sigma(self) -> npt.NDArray[np.float32]:
        """(H, W) float32 local noise σ, DN."""
        return self._image(self.sigma_tiles)

    def threshold(self, snr_min: float) -> npt.NDArray[np.float32]:
        """(H, W) float32 ``background + snr_min · σ``, DN, computed per tile."""
        return self._image(self.threshold_tiles(snr_min))

    def threshold_tiles(self, snr_min: float) -> npt.NDArray[np.float32]:
        """(R + 1, C) float32 ``background + snr_min · σ`` per tile, DN."""
        return self.background_tiles + np.float32(snr_min) * self.sigma_tiles

    def background_at(self, row_px: npt.NDArray[np.float64], col_px: npt.NDArray[np.float64]
                      ) -> npt.NDArray[np.float64]:
        """(n,) float64 local background (DN) of the pixels at (``row_px``, ``col_px``)
        (n,), rows floored and columns rounded as the samples are read, both clipped to
        the image (0 outside the rows read)."""
        row = np.clip(np.floor(row_px).astype(np.int64), 0, self.tile_row.size - 1)
        col = np.clip(np.rint(col_px).astype(np.int64), 0, self.width - 1)
        return self.background_tiles[self.tile_row[row], col // NOISE_TILE_PX].astype(
            np.float64)

    def _image(self, tiles: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """(H, W) float32 image of per-tile values (one broadcast copy)."""
        t = NOISE_TILE_PX
        rows = tiles[self.tile_row]  # (H, C)
        full = np.broadcast_to(rows[:, :, None], (*rows.shape, t)).reshape(rows.shape[0], -1)
        return np.ascontiguousarray(full[:, :self.width])



def _tile_statistics(block: npt.NDArray[Any]) -> tuple[npt.NDArray[np.float32],
                                                        npt.NDArray[np.float32]]:
    """Per NOISE_TILE_PX tile of ``block`` (h, w): (median, σ), each (nr, nc) float32,
    tiles from the top left corner. The tiles of the 2×2 subsample are cut in one
    compiled pass (:func:`atris_node.pipeline.peaks_kernels.subsample_tiles`) for the map
    dtypes the kernels take; int16 and int32 tiles' statistics come from one more
    (:func:`atris_node.pipeline.peaks_kernels.tile_noise`, the numbers of
    :func:`_quartile_and_median` and the float32 steps below)."""
    t = NOISE_TILE_PX // 2
    if (block.size and t == peaks_kernels.SUBSAMPLE_TILE_PX
            and block.dtype in (np.int16, np.int32, np.float32, np.float64)):
        tiles = peaks_kernels.subsample_tiles(np.ascontiguousarray(block))
    else:
        sub = block[::2, ::2]
        nr, nc = -(-sub.shape[0] // t), -(-sub.shape[1] // t)
        padded = np.pad(sub, ((0, nr * t - sub.shape[0]), (0, nc * t - sub.shape[1])),
                        "symmetric")
        tiles = padded.reshape(nr, t, nc, t).transpose(0, 2, 1, 3).reshape(nr, nc, t * t)
    if tiles.shape[-1] and tiles.dtype in (np.int16, np.int32):
        picks, fractions = _percentile_picks(tiles.shape[-1])
        return peaks_kernels.tile_noise(np.ascontiguousarray(tiles),
                                        np.array(picks, dtype=np.int64),
                                        np.array(fractions, dtype=np.float32),
                                        np.float32(QUARTILE_TO_SIGMA),
                                        np.float32(MIN_NOISE_DN))
    q25, median = _quartile_and_median(tiles)
    return median, np.maximum((median - q25) / QUARTILE_TO_SIGMA, np.float32(MIN_NOISE_DN))


def noise_map(values: npt.NDArray[np.generic], spans: list[tuple[int, int]]) -> NoiseMap:
    """The :class:`NoiseMap` of the rows in ``spans``."""
    height, width = values.shape
    tile_row = np.full(height, -1, dtype=np.int64)
    nc = -(-width // NOISE_TILE_PX)
    background = [np.zeros((0, nc), dtype=np.float32)]
    sigma = [np.zeros((0, nc), dtype=np.float32)]
    for lo, hi in spans:
        if hi > lo:
            tile_row[lo:hi] = sum(b.shape[0] for b in background) + (
                np.arange(hi - lo) // NOISE_TILE_PX)
            median, noise = _tile_statistics(values[lo:hi])
            background.append(median)
            sigma.append(noise)
    background.append(np.zeros((1, nc), dtype=np.float32))
    sigma.append(np.full((1, nc), MIN_NOISE_DN, dtype=np.float32))
    return NoiseMap(tile_row, np.concatenate(background), np.concatenate(sigma), width)
