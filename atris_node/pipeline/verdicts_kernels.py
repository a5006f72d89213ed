"""Compiled passes of the sector verdicts (numba, ``nopython``).

:func:`credible` is the nearest credible cluster of one sector
(:func:`atris_node.pipeline.verdicts.nearest_credible` documents the method): its loop
over the sector's obstacle points, sorted by range. As numpy steps (unique lines and
columns per window, a straight fit per line) it cost about 0.3 ms per sector; here one
pass. :func:`runs` finds the runs of True in each row of a mask and
:func:`expected_on_surface` where a surface should show each line (both for
:func:`atris_node.pipeline.verdicts.missing_on_surface`; as numpy steps about 60 µs per
sector). Ranges and σ float64 m, lines and columns int64.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from numba import types

from atris_node.jit import kernel

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: a fitted slope counts when it is this many standard errors from zero
SLOPE_SIGMAS = 2.0
#: one line's front replaces the front of all lines when nearer by this many standard errors
NEARER_SIGMAS = 2.0
#: standard error of a normal sample's lower quartile, in σ/√n
QUANTILE_SE = 1.36
#: fits of a slanted surface's points, each taking the points near the last
FOLLOW_PASSES = 2
#: moves of a noisy surface's centre to the median of the points near it
CENTRE_PASSES = 8
#: a noisy surface is the points within this many triangulation σ of its centre (a band
#: of 2σ would cut its tails unevenly and cost the mean a fifth more scatter)
SURFACE_SIGMAS = 3.0


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
def _fit(cols: FloatArray, ranges: FloatArray) -> tuple[float, float, float, float, float]:
    """(mean column, mean range m, slope m/px, residual scatter m, Σ(c - c̄)²) of a
    straight fit of ``ranges`` against ``cols``; slope and scatter 0 when the columns do
    not spread."""
    n = ranges.size
    c_mean, r_mean = cols.mean(), ranges.mean()
    sxx = sxy = 0.0
    for i in range(n):
        sxx += (cols[i] - c_mean) ** 2
        sxy += (cols[i] - c_mean) * (ranges[i] - r_mean)
    if sxx == 0.0:
        return c_mean, r_mean, 0.0, 0.0, 0.0
    slope = sxy / sxx
    rss = 0.0
    for i in range(n):
        rss += (ranges[i] - r_mean - slope * (cols[i] - c_mean)) ** 2
    return c_mean, r_mean, slope, np.sqrt(rss / max(n - 2, 1)), sxx


@kernel()
def _sloped(slope: float, scatter: float, sxx: float) -> bool:
    return sxx > 0.0 and abs(slope) > SLOPE_SIGMAS * scatter / np.sqrt(sxx)


@kernel()
def _fit_at(cols: FloatArray, ranges: FloatArray, idx: IntArray
            ) -> tuple[float, float, float, float, float]:
    """:func:`_fit` of the points ``idx`` (m,) (``_fit(cols[idx], ranges[idx])``, the
    same sums in the same order) without gathering them."""
    m = idx.size
    if m == 0:
        return np.nan, np.nan, 0.0, 0.0, 0.0
    c_total = r_total = 0.0
    for i in idx:
        c_total += cols[i]
    for i in idx:
        r_total += ranges[i]
    c_mean, r_mean = c_total / m, r_total / m
    sxx = sxy = 0.0
    for i in idx:
        sxx += (cols[i] - c_mean) ** 2
        sxy += (cols[i] - c_mean) * (ranges[i] - r_mean)
    if sxx == 0.0:
        return c_mean, r_mean, 0.0, 0.0, 0.0
    slope = sxy / sxx
    rss = 0.0
    for i in idx:
        rss += (ranges[i] - r_mean - slope * (cols[i] - c_mean)) ** 2
    return c_mean, r_mean, slope, np.sqrt(rss / max(m - 2, 1)), sxx


@kernel()
def _front_of(fit: tuple[float, float, float, float, float], cols: FloatArray, idx: IntArray,
              noise: float) -> tuple[float, float]:
    """(front m, its standard error m) of the points ``idx`` from their straight ``fit``
    (:func:`_fit_at`): the least range of the fit over the columns' span, or the mean
    when the slope is within SLOPE_SIGMAS standard errors of zero; (inf, inf) when the
    columns do not spread. The error's scatter is the residual's or ``noise`` (one
    sample's triangulation σ), whichever is larger: smoothing along the lines makes
    neighbouring samples share their noise, so the residual alone would claim more
    independent samples than there are."""
    c_mean, r_mean, slope, residual, sxx = fit
    n = idx.size
    if sxx == 0.0:
        return np.inf, np.inf
    scatter = max(residual, noise)
    if not _sloped(slope, residual, sxx):
        return r_mean, scatter / np.sqrt(n)
    end = cols[idx[0]]
    for i in idx:
        end = min(end, cols[i]) if slope > 0 else max(end, cols[i])
    return (r_mean + slope * (end - c_mean),
            scatter * np.sqrt(1.0 / n + (end - c_mean) ** 2 / sxx))


@kernel()
def _followed(r: FloatArray, cols: FloatArray, keep: BoolArray, first: int, noise: float,
              spread: float) -> tuple[BoolArray, IntArray,
                                      tuple[float, float, float, float, float], bool]:
    """:func:`_follow`'s points, their indices and, when made on them, their straight
    fit (and True; False: not fitted)."""
    limit = spread * noise
    idx = np.flatnonzero(keep)
    fit = (0.0, 0.0, 0.0, 0.0, 0.0)
    fitted = False
    for _ in range(FOLLOW_PASSES):
        if idx.size < 3:
            break
        fit = _fit_at(cols, r, idx)
        fitted = True
        c_mean, r_mean, slope, scatter, sxx = fit
        if not _sloped(slope, scatter, sxx):
            break
        along = np.zeros(r.size, dtype=np.bool_)
        count, same = 0, True
        for i in range(r.size):
            # |r - r̄ - slope·(c - c̄)| <= limit, as the array expression computes it
            along[i] = i >= first and abs(r[i] - r_mean - slope * (cols[i] - c_mean)) <= limit
            count += along[i]
            same = same and along[i] == keep[i]
        if count < 3 or same:
            break
        keep = along
        idx = np.flatnonzero(keep)
        fitted = False
    return keep, idx, fit, fitted


@kernel()
def _follow(r: FloatArray, cols: FloatArray, keep: BoolArray, first: int, noise: float,
            spread: float) -> BoolArray:
    """The points of a slanted surface: those (from index ``first`` on) within
    ``spread``·``noise`` of the straight fit of the kept ones, fitted again, FOLLOW_PASSES
    times. A window in range cuts a slanted surface short and flattens its fit; the
    surface's own points do not. ``keep`` itself when the fit has no slope
    (:func:`_followed`, without its indices and fit)."""
    return _followed(r, cols, keep, first, noise, spread)[0]


@kernel()
def _by_line(line: IntArray, keep: BoolArray) -> tuple[IntArray, IntArray, IntArray]:
    """The kept points grouped by line: (m,) their indices, line by line in increasing
    line order, each line's in increasing order; (L,) the lines (increasing, as
    ``np.unique`` gives them) and (L + 1,) where each line's indices start."""
    idx = np.flatnonzero(keep)
    low, high = 0, -1
    if idx.size:
        low, high = line[idx[0]], line[idx[0]]
        for i in idx:
            low, high = min(low, line[i]), max(high, line[i])
    start = np.zeros(high - low + 2, dtype=np.int64)
    for i in idx:
        start[line[i] - low + 1] += 1
    lines = 0
    for v in range(1, start.size):
        lines += start[v] > 0
        start[v] += start[v - 1]
    grouped = np.empty(idx.size, dtype=np.int64)
    fill = start[:-1].copy()
    for i in idx:
        grouped[fill[line[i] - low]] = i
        fill[line[i] - low] += 1
    values = np.empty(lines, dtype=np.int64)
    bounds = np.empty(lines + 1, dtype=np.int64)
    j = 0
    for v in range(start.size - 1):
        if start[v + 1] > start[v]:
            values[j], bounds[j] = low + v, start[v]
            j += 1
    bounds[lines] = idx.size
    return grouped, values, bounds


@kernel()
def _front(r: FloatArray, sigma: FloatArray, line: IntArray, column: IntArray,
           keep: BoolArray, first: int, min_points: int, params: FloatArray
           ) -> tuple[float, float, int]:
    """(front m, standard error m, support) of the surface the kept points start: the
    straight-fit front of all its points (followed along its slope, :func:`_follow`), or
    of one line with ``min_points`` of them where that line's front lies nearer by more
    than NEARER_SIGMAS combined standard errors (the lower lines on a ramp); the window
    quantile of the ranges when the points do not spread over columns."""
    cols = column.astype(np.float64)
    noise = np.median(sigma[keep])
    keep, idx, fit, fitted = _followed(r, cols, keep, first, noise, params[2])
    if not fitted:
        fit = _fit_at(cols, r, idx)
    best, error = _front_of(fit, cols, idx, noise)
    count = idx.size
    if not np.isfinite(best):
        return np.quantile(r[keep], params[4]), QUANTILE_SE * noise / np.sqrt(count), count
    grouped, lines, bounds = _by_line(line, keep)
    for j in range(lines.size):  # the lines in increasing order, as np.unique(line[keep])
        mine = grouped[bounds[j]:bounds[j + 1]]
        if mine.size < min_points:
            continue
        front, se = _front_of(_fit_at(cols, r, mine), cols, mine, np.median(sigma[mine]))
        if front < best - NEARER_SIGMAS * np.sqrt(se * se + error * error):
            best, error = front, se
    return best, error, count


@kernel("UniTuple(float64, 4)(float64[:], float64[:], int64[:], int64[:], int64, int64, "
        "float64[:])")
def credible(r: FloatArray, sigma: FloatArray, line: IntArray, column: IntArray,
             min_points: int, width_px: int, params: FloatArray
             ) -> tuple[float, float, float, float]:
    """(distance m, σ m, support, nearer) of the nearest credible cluster of points sorted
    by range ``r``, or (nan, nan, -1, -1) when there is none. ``params``: (cluster rel,
    cluster abs m, spread σ, sliver columns per min_points, window quantile)."""
    rel, abs_m, spread, sliver = params[0], params[1], params[2], params[3]
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
            band = SURFACE_SIGMAS * noise
            for _ in range(CENTRE_PASSES):
                centre = np.median(r[np.abs(r - centre) <= band])
            keep = np.abs(r - centre) <= band
        front, error, support = _front(r, sigma, line, column, keep, i, min_points, params)
        return max(front, r[i]), error, float(support), float(i)
    return np.nan, np.nan, -1.0, -1.0


#: buckets per value of :func:`range_order`'s distribution by range
BUCKETS_PER_VALUE = 4
#: most insertion work per value (Σ bucket size², in values) :func:`range_order` takes on
#: before it leaves the values to a merge sort (a wall's points crowd a few buckets)
BUCKET_WORK = 16


@kernel()
def _merge_order(r: FloatArray) -> tuple[IntArray, FloatArray]:
    """:func:`range_order` by numpy's merge sort (NaN last)."""
    order = np.argsort(r, kind="mergesort")
    return order, r[order]


@kernel("Tuple((int64[:], float64[:]))(float64[:])")
def range_order(r: FloatArray) -> tuple[IntArray, FloatArray]:
    """(n,) the order that sorts ``r`` (n,) stably (``np.argsort(kind="stable")``) and
    (n,) ``r`` in that order. Finite values are dealt into BUCKETS_PER_VALUE·n buckets
    by (r - min)·scale, truncated (each step rounds monotonically, so a smaller value
    never lands in a later bucket and equal values share one), in their given order,
    and each bucket is put in order by an insertion sort that moves a value only past
    greater ones: the stable order, with one pass to deal and about one comparison per
    value where a merge sort mispredicts a branch at each of its log n levels. Values
    with NaN or inf, or buckets crowded past BUCKET_WORK, take numpy's merge sort."""
    n = r.size
    low = high = r[0] if n else 0.0
    finite = True
    for i in range(n):
        finite &= np.isfinite(r[i])
        low, high = min(low, r[i]), max(high, r[i])
    buckets = BUCKETS_PER_VALUE * n
    scale = buckets / (high - low) if high > low else 0.0
    if not (finite and np.isfinite(scale)):
        return _merge_order(r)
    bucket = np.empty(n, dtype=np.int64)
    end = np.zeros(buckets + 1, dtype=np.int64)
    for i in range(n):
        bucket[i] = min(int((r[i] - low) * scale), buckets - 1)
        end[bucket[i] + 1] += 1
    work = 0
    for b in range(buckets):
        work += end[b + 1] * end[b + 1]
        end[b + 1] += end[b]
    if work > BUCKET_WORK * n:
        return _merge_order(r)
    order, ranges = np.empty(n, dtype=np.int64), np.empty(n)
    for i in range(n):  # end[b] ends bucket b - 1 and then, filled, bucket b
        at = end[bucket[i]]
        order[at], ranges[at] = i, r[i]
        end[bucket[i]] = at + 1
    first = 0
    for b in range(buckets):
        for i in range(first + 1, end[b]):
            value, index = ranges[i], order[i]
            j = i
            while j > first and ranges[j - 1] > value:
                ranges[j], order[j] = ranges[j - 1], order[j - 1]
                j -= 1
            ranges[j], order[j] = value, index
        first = end[b]
    return order, ranges


@kernel("UniTuple(float64, 4)(float64[:], float64[:], int64[:], int64[:], int64, int64, "
        "float64[:])")
def credible_of(r: FloatArray, sigma: FloatArray, line: IntArray, column: IntArray,
                min_points: int, width_px: int, params: FloatArray
                ) -> tuple[float, float, float, float]:
    """:func:`credible` of points in any order: sorted by range ``r`` first, ties in their
    given order (``np.argsort(kind="stable")``, NaN last; :func:`range_order`)."""
    order, ranges = range_order(r)
    return credible(ranges, sigma[order], line[order], column[order], min_points,
                    width_px, params)


@kernel("float64[:, :](float64[:], float64[:], int64[:], int64[:], int64[:], int64[:], int64, "
        "int64, float64[:])")
def credible_per_sector(r: FloatArray, sigma: FloatArray, line: IntArray, column: IntArray,
                        start: IntArray, stop: IntArray, min_points: int, width_px: int,
                        params: FloatArray) -> FloatArray:
    """(S, 4) :func:`credible_of` of each sector's points ``start[s]`` .. ``stop[s]``
    (exclusive) of the given (n,) arrays, one call for every sector; (nan, nan, -1, -1)
    where a sector has fewer than ``min_points``."""
    out = np.empty((start.size, 4))
    for s in range(start.size):
        lo, hi = start[s], stop[s]
        if hi - lo < min_points:
            out[s, 0], out[s, 1], out[s, 2], out[s, 3] = np.nan, np.nan, -1.0, -1.0
            continue
        out[s, 0], out[s, 1], out[s, 2], out[s, 3] = credible_of(
            r[lo:hi], sigma[lo:hi], line[lo:hi], column[lo:hi], min_points, width_px, params)
    return out


@kernel("Tuple((int64[:], int64[:]))(int64[:], int64)")
def grouped(key: IntArray, groups: int) -> tuple[IntArray, IntArray]:
    """(n,) the order that sorts ``key`` (n,) stably (``np.argsort(kind="stable")``) and
    (groups + 1,) how many keys lie below 0, 1, ..., ``groups`` (``np.searchsorted`` of
    the sorted keys): one counting pass over the values' range."""
    n = key.size
    below = np.zeros(groups + 1, dtype=np.int64)
    order = np.empty(n, dtype=np.int64)
    if n == 0:
        return order, below
    low, high = key.min(), key.max()
    start = np.zeros(high - low + 2, dtype=np.int64)
    for i in range(n):
        start[key[i] - low + 1] += 1
    for v in range(1, start.size):
        start[v] += start[v - 1]
    for j in range(groups + 1):
        below[j] = start[min(max(j - low, 0), start.size - 1)]
    for i in range(n):
        v = key[i] - low
        order[start[v]] = i
        start[v] += 1
    return order, below


@kernel("boolean[:](boolean[:], int64)")
def widened(columns: BoolArray, margin: int) -> BoolArray:
    """(W,) ``columns`` (W,) dilated by ``margin`` columns each side: True within
    ``margin`` columns of a True one."""
    width = columns.size
    out = np.zeros(width, dtype=np.bool_)
    for c in range(width):
        if columns[c]:
            for d in range(max(c - margin, 0), min(c + margin + 1, width)):
                out[d] = True
    return out


@kernel("int64[:](float64[:], float64, float64, int64)")
def sector_index(bearing: FloatArray, half_fov: float, width: float, count: int) -> IntArray:
    """(n,) the sector of each ``bearing`` (n,) rad: floor((bearing + ``half_fov``) /
    ``width``) where it lies in 0 .. ``count`` - 1, else -1 (NaN too), as the numpy steps
    of :meth:`atris_node.pipeline.sectors.SectorLayout.index_of` compute it."""
    out = np.empty(bearing.size, dtype=np.int64)
    for i in range(bearing.size):
        f = np.floor((bearing[i] + half_fov) / width)
        out[i] = int(f) if 0.0 <= f < count else -1
    return out


@kernel("void(float64[:], int64[:], float64[:])")
def least_per_sector(out: FloatArray, sector: IntArray, values: FloatArray) -> None:
    """``out[s]`` (S,) lowered to the least of the ``values`` (n,) whose ``sector`` (n,) is
    s, as ``np.minimum.at`` does (NaN kept); sectors below 0 (outside) left out."""
    for i in range(sector.size):
        s = sector[i]
        if s < 0:
            continue
        if s >= out.size:
            raise IndexError("a sector beyond the sectors given")
        v = values[i]
        if np.isnan(v) or v < out[s]:
            out[s] = v


def _with_mask(before: tuple[Any, ...], after: tuple[Any, ...]) -> list[Any]:
    """int64 kernel signatures with the arguments ``before``, a (W,) bool mask (writable
    or read-only: the sectors' column masks are read-only), then ``after``."""
    return [types.int64(*before, types.Array(types.boolean, 1, "A", readonly=readonly),
                        *after) for readonly in (False, True)]


_F, _I, _B = (types.Array(dtype, 1, "A") for dtype in (types.float64, types.int64,
                                                       types.boolean))


@kernel(_with_mask((_F, _F, _B, _B, _I, _I, _I, types.int64, types.int64, types.float64,
                    types.float64, types.int64, types.int64), (_I, _I, _F)))
def shadowed(nearer: FloatArray, farther: FloatArray, noisy: BoolArray, bright: BoolArray,
             line: IntArray, start: IntArray, stop: IntArray, first: int, last: int,
             limit: float, margin: float, lines: int, beside: int, inside: BoolArray,
             hit_line: IntArray, hit_column: IntArray, hit_range: FloatArray) -> int:
    """:func:`atris_node.pipeline.verdicts.shadowed_columns`: how many of the sector's
    columns (``inside`` (W,), spanning ``first`` .. ``last``) lie in holes (``nearer``,
    ``farther`` m, ``noisy``, ``bright``, ``line``, ``start``, ``stop``; (h,) each) of
    ``lines`` or more lines whose flanks lie within ``margin`` of each other and not
    beyond ``limit`` (m), quiet and bright, with no obstacle point (``hit_line``,
    ``hit_column``, ``hit_range`` (n,)) at most ``limit`` away in them. A hole whose line
    is the only one with obstacle points within ``margin`` of its near flank within
    ``beside`` columns of it counts as ``lines`` holes: no other line is on that surface
    there to stop with it."""
    width = inside.size
    count = np.zeros(width, dtype=np.int64)
    for h in range(nearer.size):
        if (nearer[h] <= limit and farther[h] <= nearer[h] + margin and not noisy[h]
                and start[h] <= last and stop[h] > first and bright[h]):
            alone = True
            for i in range(hit_column.size):
                if (hit_line[i] != line[h] and hit_column[i] >= start[h] - beside
                        and hit_column[i] < stop[h] + beside
                        and abs(hit_range[i] - nearer[h]) <= margin):
                    alone = False
                    break
            weight = lines if alone else 1
            for c in range(start[h], stop[h]):
                count[c] += weight
    shadow = np.zeros(width, dtype=np.bool_)
    for c in range(width):
        shadow[c] = count[c] >= lines and inside[c]
    for i in range(hit_column.size):
        if hit_range[i] <= limit:
            shadow[hit_column[i]] = False
    return shadow.sum()


@kernel()
def _count_true(row: BoolArray, lo: int, hi: int) -> int:
    """How many of ``row``'s entries lo .. hi - 1 (clipped to the row) are True."""
    count = 0
    for c in range(max(lo, 0), min(hi, row.size)):
        count += row[c]
    return count


@kernel()
def _near_strong_hole(h: int, nearer: FloatArray, noisy: BoolArray, line: IntArray,
                      start: IntArray, stop: IntArray, first: int, last: int,
                      nearer_than: float, hit_line: IntArray, hit_snr: FloatArray,
                      strong_snr: float) -> int:
    """1 when hole ``h`` (of :func:`unseen`'s arguments) touches columns ``first`` ..
    ``last``, is flanked nearer than ``nearer_than`` or noisy, and its line is strong
    (:func:`_strong_line`); 0 when not; -1 when its line's SNR holds NaN."""
    if not ((nearer[h] < nearer_than or noisy[h]) and start[h] <= last and stop[h] > first):
        return 0
    return _strong_line(line[h], hit_line, hit_snr, strong_snr)


@kernel()
def _strong_line(k: int, hit_line: IntArray, hit_snr: FloatArray, strong_snr: float) -> int:
    """1 when the points of line ``k`` among ``hit_line`` (n,) have a median SNR
    (``hit_snr``) of ``strong_snr`` or more, 0 when less or none, -1 when one is NaN."""
    n = 0
    for i in range(hit_line.size):
        n += hit_line[i] == k
    if n == 0:
        return 0
    snr = np.empty(n)
    j = 0
    for i in range(hit_line.size):
        if hit_line[i] == k:
            if np.isnan(hit_snr[i]):
                return -1
            snr[j] = hit_snr[i]
            j += 1
    return int(np.median(snr) >= strong_snr)


@kernel(_with_mask((_F, _B, _I, _I, _I, types.int64, types.int64, types.float64,
                    types.float64, types.float64), (_I, _I, _F, _F, _I, _F, types.int64)))
def unseen(nearer: FloatArray, noisy: BoolArray, line: IntArray, start: IntArray,
           stop: IntArray, first: int, last: int, nearer_than: float, farther_than: float,
           strong_snr: float, inside: BoolArray, hit_line: IntArray, hit_column: IntArray,
           hit_range: FloatArray, hit_snr: FloatArray, all_column: IntArray,
           all_range: FloatArray, gap: int) -> int:
    """:func:`atris_node.pipeline.verdicts.unseen_columns`: how many columns of the sector
    (``inside`` (W,), spanning ``first`` .. ``last``) lie in a hole (``nearer`` m,
    ``noisy``, ``line``, ``start``, ``stop``; (h,) each) flanked nearer than
    ``nearer_than`` (m) or noisy, of a line whose obstacle points in the sector
    (``hit_*`` (n,)) have a median SNR of ``strong_snr`` or more (a noisy hole counts
    beyond the sector's columns too), with no obstacle point of the sector at most
    ``farther_than`` away in the column and no point of the sector (``all_*``) farther
    within ``gap`` columns. -1 when a line's SNR holds NaN (the median is numpy's to
    take then)."""
    width = inside.size
    hole = np.zeros(width, dtype=np.bool_)
    whole = np.zeros(width, dtype=np.bool_)
    found = False
    for h in range(nearer.size):
        use = _near_strong_hole(h, nearer, noisy, line, start, stop, first, last,
                                nearer_than, hit_line, hit_snr, strong_snr)
        if use < 0:
            return -1
        if use:
            found = True
            for c in range(start[h], stop[h]):
                hole[c] = True
                whole[c] |= noisy[h]
    if not found:
        return 0
    for c in range(width):
        hole[c] &= inside[c] or whole[c]
    for i in range(hit_column.size):
        if hit_range[i] <= farther_than:
            hole[hit_column[i]] = False
    for i in range(all_column.size):
        if all_range[i] > farther_than:
            for shift in range(-gap, gap + 1):  # clipped to the image, as np.clip does
                hole[min(max(all_column[i] + shift, 0), width - 1)] = False
    return hole.sum()


@kernel(_with_mask((_F, _B, _I, _I, _I, types.int64, types.int64, types.float64,
                    types.float64, types.float64), (_I, _F, _I, _F, types.int64)))
def unseen_whole(nearer: FloatArray, noisy: BoolArray, line: IntArray, start: IntArray,
                 stop: IntArray, first: int, last: int, nearer_than: float,
                 farther_than: float, strong_snr: float, inside: BoolArray,
                 hit_line: IntArray, hit_snr: FloatArray, all_column: IntArray,
                 all_range: FloatArray, gap: int) -> int:
    """The longest hole, counted whole, of
    :func:`atris_node.pipeline.verdicts.unseen_columns` that enters the sector (``inside``
    (W,), spanning ``first`` .. ``last``): a hole (``nearer`` m, ``noisy``, ``line``,
    ``start``, ``stop``; (h,) each) flanked nearer than ``nearer_than`` (m) or noisy, of a
    line whose obstacle points in the sector (``hit_line``, ``hit_snr``) have a median SNR
    of ``strong_snr`` or more, without its columns that lie within ``gap`` columns of a
    point farther than ``farther_than`` (m) (``all_*`` (n,): the points of the sector and
    its neighbours), with at least one column left in the sector. 0 when none; -1 when a
    line's SNR holds NaN (the median is numpy's to take then)."""
    width = inside.size
    open_ = np.zeros(width, dtype=np.bool_)
    for i in range(all_column.size):
        if all_range[i] > farther_than:
            for shift in range(-gap, gap + 1):  # clipped to the image, as np.clip does
                open_[min(max(all_column[i] + shift, 0), width - 1)] = True
    hole = np.zeros(width, dtype=np.bool_)
    longest = 0
    for h in range(nearer.size):
        use = _near_strong_hole(h, nearer, noisy, line, start, stop, first, last,
                                nearer_than, hit_line, hit_snr, strong_snr)
        if use < 0:
            return -1
        if not use:
            continue
        for c in range(start[h], stop[h]):
            hole[c] = not open_[c]
        count, enters = 0, False
        for c in range(start[h], stop[h]):
            count += hole[c]
            enters |= hole[c] and inside[c]
        if enters and count > longest:
            longest = count
    return longest


@kernel("Tuple((int64[:], int64[:], int64[:]))(boolean[:, :])")
def runs(mask: BoolArray) -> tuple[IntArray, IntArray, IntArray]:
    """The runs of True in each row of a (K, W) ``mask``: (n,) row, start and stop
    (exclusive) of each, row by row, each row's from the left."""
    lines, width = mask.shape
    count = 0
    for k in range(lines):
        for c in range(width):
            if mask[k, c] and (c == 0 or not mask[k, c - 1]):
                count += 1
    row = np.empty(count, dtype=np.int64)
    start = np.empty(count, dtype=np.int64)
    stop = np.empty(count, dtype=np.int64)
    i = -1
    for k in range(lines):
        for c in range(width):
            if mask[k, c]:
                if c == 0 or not mask[k, c - 1]:
                    i += 1
                    row[i], start[i] = k, c
                stop[i] = c + 1
    return row, start, stop


@kernel("Tuple((int64[:], int64[:], int64[:], float64[:], float64[:], boolean[:], "
        "boolean[:]))(boolean[:, :], boolean[:, :], boolean[:, :], int64[:], int64[:], "
        "float64[:], boolean[:], boolean[:], float64[:], float64, int64)")
def line_holes(seen: BoolArray, noisy: BoolArray, dimmed: BoolArray, line: IntArray,
               column: IntArray, range_m: FloatArray, obstacle: BoolArray, low: BoolArray,
               snr: FloatArray, bright_snr: float, gap: int
               ) -> tuple[IntArray, IntArray, IntArray, FloatArray, FloatArray, BoolArray,
                          BoolArray]:
    """:class:`atris_node.pipeline.verdicts.LineHoles` of ``seen`` (K, W) under ``noisy``
    ((K, W), or (0, 0) for nowhere) from the points (``line``, ``column``, ``range_m``,
    ``obstacle``, ``low``, ``snr``; (n,) each): per hole its line, start, stop, nearer and
    farther flank (m), noisy, and bright (its line has an obstacle point of SNR
    ``bright_snr`` or more in ``gap`` of the 2·``gap`` columns on either side: a single
    dropout beside the hole leaves it bright; or ``dimmed`` ((K, W), or (0, 0) for
    nowhere) in a column of the run: a bright line's dim, whose flanks a moving occluder
    dims too). A flank is the last obstacle point of the line in the column, as a numpy
    assignment leaves it; opposite an obstacle flank, the last ``low`` point (a surface
    below the clearance) flanks too."""
    lines, width = seen.shape
    flank = np.full((lines, width), np.nan)
    below = np.full((lines, width), np.nan)  # the last low point
    bright_lines, bright_width = lines, width
    for i in range(line.size):
        if obstacle[i] and not (0 <= line[i] < lines and 0 <= column[i] < width):
            raise IndexError("a point outside the seen lines and columns")
        bright_lines = max(bright_lines, line[i] + 1)
        bright_width = max(bright_width, column[i] + 1)
    bright = np.zeros((bright_lines, bright_width), dtype=np.bool_)
    for i in range(line.size):
        if low[i] and not obstacle[i] and 0 <= line[i] < lines and 0 <= column[i] < width:
            below[line[i], column[i]] = range_m[i]
        if obstacle[i]:
            flank[line[i], column[i]] = range_m[i]
            if snr[i] >= bright_snr:
                bright[line[i], column[i]] = True
    row, start, stop = runs(~seen)
    out = np.zeros(row.size, dtype=np.bool_)
    nearer = np.full(row.size, np.inf)
    farther = np.full(row.size, np.inf)
    hidden = np.zeros(row.size, dtype=np.bool_)
    lit = np.zeros(row.size, dtype=np.bool_)
    for h in range(row.size):
        k, a, b = row[h], start[h], stop[h]
        if a == 0 or b >= width or b - a < gap:
            continue
        left, right = flank[k, a - 1], flank[k, b]
        if np.isfinite(left) and not np.isfinite(right):
            right = below[k, b]
        elif np.isfinite(right) and not np.isfinite(left):
            left = below[k, a - 1]
        flanked = np.isfinite(left) and np.isfinite(right)
        if noisy.shape[0]:
            inside = 0
            for c in range(a, b):
                inside += noisy[k, c]
            hidden[h] = 2 * inside >= b - a
        out[h] = flanked or hidden[h]
        if flanked:
            nearer[h], farther[h] = min(left, right), max(left, right)
        lit[h] = (_count_true(bright[k], a - 2 * gap, a) >= gap
                  and _count_true(bright[k], b, b + 2 * gap) >= gap)
        if not lit[h] and k < dimmed.shape[0]:
            lit[h] = _count_true(dimmed[k], a, b) > 0
    return (row[out], start[out], stop[out], nearer[out], farther[out], hidden[out],
            lit[out])


@kernel()
def _divide(a: float, b: float) -> float:
    """a / b as numpy divides (±inf, or nan for 0 / 0, where b is 0), not raising."""
    if b == 0.0:
        if a == 0.0 or np.isnan(a):
            return np.nan
        return np.inf if (a > 0.0) == (np.copysign(1.0, b) > 0.0) else -np.inf
    return a / b


@kernel("Tuple((int64, boolean[:, :], int64[:]))(int64[:], float64[:], int64[:], int64[:], "
        "float64[:], float64[:, :], boolean[:, :], float64[:])")
def expected_on_surface(column: IntArray, depth: FloatArray, line: IntArray, rank: IntArray,
                        cot: FloatArray, ground_range: FloatArray, noisy: BoolArray,
                        geometry: FloatArray) -> tuple[int, BoolArray, IntArray]:
    """:func:`atris_node.pipeline.verdicts._expected_on_surface` of the surface points
    (``column``, camera ``depth`` m, ``line``; (n,) each, n > 0) under the lines' image
    ``rank`` and ``cot`` (K,) and ``ground_range`` (K, W) m: (first column c0, (K, m + 2)
    where line k is expected on the surface in column c0 + j, (m + 2,) image position of
    the lowest line seen on it per column or -1), m the span of the columns less one.
    ``noisy`` (K, W) or (0, 0) for nowhere; ``geometry``: (focal px, cy px, height px,
    f·b px·m, margin rows, margin rows for a line seen on the surface). A column's mean
    depth adds its points' depths in their order, as np.bincount does."""
    focal, cy, height, fb = geometry[0], geometry[1], geometry[2], geometry[3]
    lines, n = rank.size, column.size
    first, last = column.min(), column.max()
    span = last - first + 2
    total = np.zeros(span)
    count = np.zeros(span, dtype=np.int64)
    held = np.zeros((span, lines), dtype=np.bool_)
    for i in range(n):
        j = column[i] - first
        total[j] += depth[i]
        count[j] += 1
        held[j, rank[line[i]]] = True
    reached = np.zeros(lines, dtype=np.bool_)
    for j in range(span):
        for r in range(lines):
            reached[r] |= held[j, r]
    onto = np.zeros((lines, span), dtype=np.bool_)
    bottom = np.full(span, -1, dtype=np.int64)
    for j in range(span):
        if count[j] == 0:
            continue
        z = total[j] / count[j]
        top = 0
        while not held[j, top]:
            top += 1
        low = lines - 1
        while not held[j, low]:
            low -= 1
        bottom[j] = low
        c = first + j
        for k in range(lines):
            margin = geometry[5] if reached[rank[k]] else geometry[4]
            rows_off = _divide(fb, z) - _divide(fb, ground_range[k, c])
            row = cy + focal * cot[k] - _divide(fb, z)
            onto[k, j] = (rank[k] > top and rows_off >= margin and row >= 0
                          and row < height and not (noisy.shape[0] and noisy[k, c]))
    return first, onto, bottom


@kernel("Tuple((int64, boolean[:, :], int64[:], boolean[:, :], int64[:], int64[:], int64[:]))"
        "(float64[:], float64[:], int64[:], float64[:], int64[:], float64, float64, float64, "
        "int64, int64, int64[:], float64[:], float64[:, :], boolean[:, :], float64[:], "
        "boolean[:, :])")
def lost_on_surface(range_m: FloatArray, snr: FloatArray, column: IntArray, depth: FloatArray,
                    line: IntArray, distance: float, margin: float, strong: float,
                    min_points: int, min_run: int, rank: IntArray, cot: FloatArray,
                    ground_range: FloatArray, noisy: BoolArray, geometry: FloatArray,
                    seen: BoolArray) -> tuple[int, BoolArray, IntArray, BoolArray, IntArray,
                                              IntArray, IntArray]:
    """The first steps of :func:`atris_node.pipeline.verdicts.missing_on_surface` over a
    sector's obstacle points (``range_m``, ``snr``, ``column``, camera ``depth``, ``line``;
    (n,) each): the surface is the points within ``margin`` of ``distance`` (m) with an
    SNR of ``strong`` or more; with ``min_points`` of them, (first column c0, (K, m + 2)
    lines expected on it, (m + 2,) lowest line seen on it, as :func:`expected_on_surface`
    gives them under ``rank``, ``cot``, ``ground_range``, ``noisy`` and ``geometry``;
    (K, m + 2) ``seen`` (K, W) from c0 on, the last column False; and the runs of
    ``min_run`` or more columns where an expected line is not seen: (r,) line, start,
    stop). With fewer points: first -1 and nothing else."""
    bright = 0
    for i in range(range_m.size):
        bright += abs(range_m[i] - distance) <= margin and snr[i] >= strong
    none = np.zeros(0, dtype=np.int64)
    if bright < min_points:
        flat = np.zeros((0, 0), dtype=np.bool_)
        return -1, flat, none, flat, none, none, none
    col = np.empty(bright, dtype=np.int64)
    dep = np.empty(bright)
    lin = np.empty(bright, dtype=np.int64)
    j = 0
    for i in range(range_m.size):
        if abs(range_m[i] - distance) <= margin and snr[i] >= strong:
            col[j], dep[j], lin[j] = column[i], depth[i], line[i]
            j += 1
    first, onto, bottom = expected_on_surface(col, dep, lin, rank, cot, ground_range, noisy,
                                              geometry)
    lines, span = onto.shape
    shown = np.zeros((lines, span), dtype=np.bool_)
    lost = np.zeros((lines, span), dtype=np.bool_)
    for k in range(lines):
        for c in range(span - 1):
            shown[k, c] = seen[k, first + c]
        for c in range(span):
            lost[k, c] = onto[k, c] and not shown[k, c]
    row, start, stop = runs(lost)
    long = stop - start >= min_run
    return first, onto, bottom, shown, row[long], start[long], stop[long]


def _read_only(dtype: Any, ndim: int) -> Any:
    """A read-only C-contiguous array type (writable arrays convert to it)."""
    return types.Array(dtype, ndim, "C", readonly=True)


@kernel(types.UniTuple(types.int64[::1], 2)(
    _read_only(types.int64, 1), _read_only(types.int64, 1), _read_only(types.int64, 1),
    _read_only(types.int64, 1), _read_only(types.boolean, 2), _read_only(types.boolean, 2),
    _read_only(types.boolean, 2), types.int64))
def sector_counts(sector: IntArray, ambiguous: IntArray, doubtful: IntArray,
                  missing: IntArray, seen: BoolArray, noisy: BoolArray, expected: BoolArray,
                  count: int) -> tuple[IntArray, IntArray]:
    """(S,) per sector 0 .. ``count`` - 1 the sums over its columns (``sector`` (W,), -1
    outside) of ``ambiguous`` (W,), and of ``doubtful`` + ``missing`` (W,) + the lines
    not ``seen``, not ``expected`` whose band is ``noisy`` in the column ((K, W) each;
    ``noisy`` (0, 0): none), int64: one pass for what ``ColumnEvidence.per_sector`` of
    each sum adds up (exactly: the float64 sums of ``np.bincount`` hold integers)."""
    width = sector.size
    unclean = np.zeros(width, dtype=np.int64)
    for k in range(noisy.shape[0]):  # row by row: the (K, W) masks are read in order
        for c in range(width):
            unclean[c] += noisy[k, c] > (seen[k, c] | expected[k, c])
    ambiguous_out = np.zeros(count, dtype=np.int64)
    doubtful_out = np.zeros(count, dtype=np.int64)
    for c in range(width):
        s = sector[c]
        if 0 <= s < count:
            ambiguous_out[s] += ambiguous[c]
            doubtful_out[s] += doubtful[c] + missing[c] + unclean[c]
    return ambiguous_out, doubtful_out


@kernel(types.Tuple((types.boolean[:, ::1], types.int64[::1], types.int64[::1]))(
    _read_only(types.int64, 1), _read_only(types.int64, 1), _read_only(types.boolean, 1),
    _read_only(types.boolean, 1), _read_only(types.boolean, 2), _read_only(types.boolean, 1),
    _read_only(types.int64, 1), _read_only(types.boolean, 1), _read_only(types.int64, 1)))
def column_evidence(line: IntArray, column: IntArray, saturated: BoolArray, valid: BoolArray,
                    expected: BoolArray, looks_beyond: BoolArray, doubtful: IntArray,
                    foreign: BoolArray, flagged: IntArray
                    ) -> tuple[BoolArray, IntArray, IntArray]:
    """What the samples (``line``, whole ``column``, ``saturated``, ``valid``; (n,) each)
    say of each column, for :class:`atris_node.pipeline.verdicts.ColumnEvidence`:
    (K, W) ``seen`` (line k has a sample in column c; a negative line counted from the
    last, a line or column beyond the table: IndexError, as numpy's indexing), (W,)
    ``doubtful``: the given ``doubtful`` (W,) counts + the saturated samples + 1 for
    ``foreign`` light + 1 where no line ``looks_beyond`` the operating range and none is
    seen beyond it (no invalid sample) + the ``flagged`` samples' columns (m,) (columns
    at or beyond W not counted, as ``per_column``), and (W,) ``missing``: the lines
    ``expected`` (K, W) on the ground there and not seen; int64 counts."""
    lines, width = expected.shape
    seen = np.zeros((lines, width), dtype=np.bool_)
    out = np.empty(width, dtype=np.int64)
    beyond = np.zeros(width, dtype=np.bool_)
    for c in range(width):
        out[c] = doubtful[c] + foreign[c]
    for i in range(line.size):
        k, c = line[i] + lines if line[i] < 0 else line[i], column[i]
        if k < 0 or k >= lines or c < 0 or c >= width:
            raise IndexError("a sample outside the lines and columns")
        seen[k, c] = True
        out[c] += saturated[i]
        beyond[c] |= not valid[i]
    for i in range(flagged.size):
        if flagged[i] < 0:
            raise ValueError("a negative column")
        if flagged[i] < width:
            out[flagged[i]] += 1
    missing = np.zeros(width, dtype=np.int64)
    for k in range(lines):
        for c in range(width):
            missing[c] += expected[k, c] > seen[k, c]
    for c in range(width):
        out[c] += not (looks_beyond[c] or beyond[c])
    return seen, out, missing


def warm_up() -> None:
    """Type the kernels' arguments once."""
    r = np.array([1.0, 1.0, 1.01, 1.02, 1.02, 1.03])
    credible(r, np.full(6, 0.01), np.array([0, 1, 0, 1, 0, 1], dtype=np.int64),
             np.arange(6, dtype=np.int64), 5, 8, np.array([0.03, 0.05, 2.0, 3.0, 0.25]))
    range_order(r)
    credible_of(r, np.full(6, 0.01), np.array([0, 1, 0, 1, 0, 1], dtype=np.int64),
                np.arange(6, dtype=np.int64), 5, 8, np.array([0.03, 0.05, 2.0, 3.0, 0.25]))
    credible_per_sector(r, np.full(6, 0.01), np.array([0, 1, 0, 1, 0, 1], dtype=np.int64),
                        np.arange(6, dtype=np.int64), np.array([0, 6], dtype=np.int64),
                        np.array([6, 6], dtype=np.int64), 5, 8,
                        np.array([0.03, 0.05, 2.0, 3.0, 0.25]))
    grouped(np.array([1, 0, 1], dtype=np.int64), 2)
    least_per_sector(np.full(2, np.inf), np.array([1, -1], dtype=np.int64), np.ones(2))
    sector_index(np.zeros(1), 0.6, 0.15, 8)
    widened(np.ones(3, dtype=np.bool_), 1)
    column = np.zeros(1, dtype=np.int64)
    sector_counts(column, column, column, column, *(np.zeros((1, 1), dtype=np.bool_),) * 3, 1)
    flag = np.zeros(1, dtype=np.bool_)
    column_evidence(column, column, flag, flag, np.zeros((1, 1), dtype=np.bool_), flag, column,
                    flag, column)
    two, flag = np.ones(2), np.zeros(2, dtype=np.bool_)
    pair = np.array([0, 1], dtype=np.int64)
    shadowed(two, two, flag, flag, pair, pair, pair + 1, 0, 1, 1.0, 0.2, 2, 6, flag, pair,
             pair, two)
    unseen(two, flag, pair, pair, pair + 1, 0, 1, 1.0, 1.0, 1.0, flag, pair, pair, two, two,
           pair, two, 3)
    unseen_whole(two, flag, pair, pair, pair + 1, 0, 1, 1.0, 1.0, 1.0, flag, pair, two, pair,
                 two, 3)
    runs(np.ones((1, 2), dtype=np.bool_))
    line_holes(np.zeros((1, 8), dtype=np.bool_), np.zeros((0, 0), dtype=np.bool_),
               np.zeros((0, 0), dtype=np.bool_), np.zeros(1, dtype=np.int64),
               np.zeros(1, dtype=np.int64), np.ones(1), np.ones(1, dtype=np.bool_),
               np.zeros(1, dtype=np.bool_),
               np.ones(1), 1.0, 3)
    one = np.zeros(1, dtype=np.int64)
    expected_on_surface(one, np.ones(1), one, one, np.ones(1), np.ones((1, 1)),
                        np.zeros((0, 0), dtype=np.bool_), np.ones(6))
    lost_on_surface(np.ones(1), np.ones(1), one, np.ones(1), one, 1.0, 0.2, 1.0, 1, 2, one,
                    np.ones(1), np.ones((1, 1)), np.zeros((0, 0), dtype=np.bool_), np.ones(6),
                    np.ones((1, 1), dtype=np.bool_))
