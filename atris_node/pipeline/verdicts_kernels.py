"""Compiled nearest credible cluster of one sector (numba, ``nopython``).

:func:`atris_node.pipeline.verdicts.nearest_credible` documents the method; this is its
loop over the sector's obstacle points, sorted by range. As numpy steps (unique lines and
columns per window, a straight fit per line) it cost about 0.3 ms per sector; here one
pass. Ranges and σ float64 m, lines and columns int64.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@kernel()
def _independent(line: IntArray, column: IntArray, lo: int, hi: int, min_columns: int,
                 seen: BoolArray) -> bool:
    """More than one line among points lo..hi, or one line over ``min_columns`` columns
    (``seen`` (W,) scratch, left all False)."""
    for i in range(lo + 1, hi):
        if line[i] != line[lo]:
            return True
    count = 0
    for i in range(lo, hi):
        if not seen[column[i]]:
            seen[column[i]] = True
            count += 1
    for i in range(lo, hi):
        seen[column[i]] = False
    return count >= min_columns


@kernel()
def _line_front(cols: FloatArray, ranges: FloatArray) -> float:
    """Least range of a straight fit of ``ranges`` against ``cols`` over their span, or
    their mean when the slope is within 2 standard errors of zero; inf when the columns
    do not spread."""
    n = ranges.size
    c_mean, r_mean = cols.mean(), ranges.mean()
    sxx = sxy = 0.0
    for i in range(n):
        sxx += (cols[i] - c_mean) ** 2
        sxy += (cols[i] - c_mean) * (ranges[i] - r_mean)
    if sxx == 0.0:
        return np.inf
    slope = sxy / sxx
    rss = 0.0
    for i in range(n):
        rss += (ranges[i] - r_mean - slope * (cols[i] - c_mean)) ** 2
    error = np.sqrt(rss / max(n - 2, 1) / sxx)
    if abs(slope) <= 2.0 * error:
        return r_mean
    end = cols.min() if slope > 0 else cols.max()
    return r_mean + slope * (end - c_mean)


@kernel()
def _front(r: FloatArray, line: IntArray, column: IntArray, keep: BoolArray,
           min_points: int, quantile: float) -> float:
    """Least straight-fit front over the lines with ``min_points`` kept points; the kept
    ranges' ``quantile`` when no line has that many."""
    best = np.inf
    for k in np.unique(line[keep]):
        mine = keep & (line == k)
        if mine.sum() >= min_points:
            best = min(best, _line_front(column[mine].astype(np.float64), r[mine]))
    if np.isfinite(best):
        return best
    return np.quantile(r[keep], quantile)


@kernel("UniTuple(float64, 4)(float64[:], float64[:], int64[:], int64[:], int64, int64, "
        "float64[:])")
def credible(r: FloatArray, sigma: FloatArray, line: IntArray, column: IntArray,
             min_points: int, width_px: int, params: FloatArray
             ) -> tuple[float, float, float, float]:
    """(distance m, σ m, support, nearer) of the nearest credible cluster of points sorted
    by range ``r``, or (nan, nan, -1, -1) when there is none. ``params``: (cluster rel,
    cluster abs m, spread σ, sliver columns per min_points, window quantile)."""
    rel, abs_m, spread, sliver, quantile = params[0], params[1], params[2], params[3], params[4]
    n = r.size
    seen = np.zeros(width_px + 1, dtype=np.bool_)
    end = 0
    for i in range(n):
        width = max(rel * r[i], abs_m, spread * sigma[i])
        while end < n and r[end] <= r[i] + width:
            end += 1
        end = max(end, i + 1)
        if end - i < min_points or not _independent(line, column, i, end,
                                                    int(sliver * min_points), seen):
            continue
        keep = np.zeros(n, dtype=np.bool_)
        keep[i:end] = True
        noise = np.median(sigma[i:end])
        if spread * noise >= width:  # the window opened on a noise tail: the surface
            centre = np.median(r[i:end])
            for _ in range(2):
                centre = np.median(r[np.abs(r - centre) <= spread * noise])
            keep = np.abs(r - centre) <= spread * noise
        distance = max(_front(r, line, column, keep, min_points, quantile), r[i])
        support = keep.sum()
        error = max(np.std(r[keep]), noise) / np.sqrt(support)
        return distance, error, float(support), float(i)
    return np.nan, np.nan, -1.0, -1.0


def warm_up() -> None:
    """Type the kernel's arguments once."""
    r = np.array([1.0, 1.0, 1.01, 1.02, 1.02, 1.03])
    credible(r, np.full(6, 0.01), np.array([0, 1, 0, 1, 0, 1], dtype=np.int64),
             np.arange(6, dtype=np.int64), 5, 8, np.array([0.03, 0.05, 2.0, 3.0, 0.25]))
