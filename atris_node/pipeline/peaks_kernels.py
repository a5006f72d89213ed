"""Compiled per-pixel and per-sample loops of the line search (numba, ``nopython``).

The maxima search compares each pixel of the rows read with its tile's threshold and its
neighbours above and below; the peak methods read a few pixels around each peak; the
support and median along lines and the per-line median SNR look at a few samples each; the
noise floor's subsample is counted where it lies (:mod:`atris_node.pipeline.noise`). As
numpy vector steps these were many passes and temporaries per map; here one pass each
(about 0.45 ms in all at 640x400). Each function is the kernel of one of
:mod:`atris_node.pipeline.peaks`, which checks the arguments, documents the methods and is
what the rest of the node calls. Line identity's kernels are in
:mod:`atris_node.pipeline.identity_kernels`.

Types: rows and lines int64, rows and offsets in px float64, maps int16, int32, float32 or
float64 (:func:`map_values`), writable or read-only. Every kernel has explicit signatures:
it is compiled at import, or loaded from numba's cache next to this file
(``__pycache__``, or ``NUMBA_CACHE_DIR``); :func:`warm_up` also does the first-call
argument typing. With ``NUMBA_DISABLE_JIT=1`` they run as plain Python (slow).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from numba import types

from atris_node.jit import kernel, uncounted
from atris_node.pipeline.selection import insert_sorted, median

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]

_I1 = "int64[:]"
_F1 = "float64[:]"


@kernel()
def _is_maximum(values: npt.NDArray[np.generic], r: int, c: int, lo: int, hi: int,
                sep: int) -> bool:
    """True when values[r, c] is above the ``sep`` rows over it and not below the ``sep``
    rows under it (rows of ``[lo, hi)`` only)."""
    v = values[r, c]
    for d in range(1, sep + 1):
        if r - d >= lo and not v > values[r - d, c]:
            return False
        if r + d < hi and not v >= values[r + d, c]:
            return False
    return True


def map_values(values: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """A map (H, W) as the kernels take it: C-contiguous int16, int32, float32 or float64;
    other integers widen to int32 (or float64 when they do not fit), other floats to
    float64."""
    if values.dtype not in (np.int16, np.int32, np.float32, np.float64):
        fits = np.issubdtype(values.dtype, np.integer) and np.can_cast(values.dtype, np.int32)
        values = values.astype(np.int32 if fits else np.float64)
    return np.ascontiguousarray(values)


def _maxima_signatures() -> list[Any]:
    """One signature per map dtype, writable or read-only (demodulators hand out
    read-only maps)."""
    i64, f32 = types.int64, types.float32
    rest = (types.Array(i64, 2, "A"), types.Array(f32, 2, "C"), types.Array(i64, 1, "A"),
            i64, i64, types.Array(types.boolean, 1, "A"), types.boolean,
            types.Array(i64, 2, "C"), types.Array(i64, 1, "C"))
    return [types.void(types.Array(dtype, 2, "C", readonly=readonly), *rest)
            for dtype in (types.int16, types.int32, f32, types.float64)
            for readonly in (False, True)]


@kernel()
def _reaches(values: npt.NDArray[np.generic], r: int, lo: int, hi: int,
             threshold: np.float32) -> bool:
    """True when a pixel of row r, columns [lo, hi), may reach ``threshold`` (DN): its
    value rounded to float32 reaches it. Rounding keeps the order and a float32
    threshold is its own rounding, so every pixel whose exact value reaches it is found
    (an int32 or float64 value just below it may be found too). A loop without branches
    over a row slice, which the compiler vectorises."""
    row = values[r, lo:hi]
    found = False
    for c in range(row.size):
        found |= bool(np.float32(row[c]) >= threshold)
    return found


@kernel()
def _row_reaches(values: npt.NDArray[np.generic], r: int,
                 threshold_px: npt.NDArray[np.float32]) -> bool:
    """:func:`_reaches` for the whole row r against a threshold per column
    ``threshold_px`` (W,) float32."""
    row = values[r]
    found = False
    for c in range(row.size):
        found |= bool(np.float32(row[c]) >= threshold_px[c])
    return found


@kernel()
def _spread(tiles: npt.NDArray[np.float32], tile_px: int,
            out: npt.NDArray[np.float32]) -> None:
    """``out`` (W,) the value of each column's tile in ``tiles`` (C,)."""
    for c in range(out.size):
        out[c] = tiles[c // tile_px]


@kernel(_maxima_signatures())
def strong_maxima(values: npt.NDArray[np.generic], spans: IntArray,
                  threshold_tiles: npt.NDArray[np.float32], tile_row: IntArray, tile_px: int,
                  sep: int, inside: npt.NDArray[np.bool_], use_inside: bool, out: IntArray,
                  count: IntArray) -> None:
    """Rows of the local maxima of ``values`` (H, W) in the row ``spans`` (S, 2) into
    ``out`` (P, W) (-1 filled), top to bottom, the first P per column; ``count`` (W,)
    zeros in, the maxima found per column out (may exceed P). A maximum reaches its
    tile's threshold (``threshold_tiles[tile_row[r], c // tile_px]``, DN), is strictly
    above the ``sep`` rows over it and not below the ``sep`` rows under it, within its
    span; with ``use_inside`` only rows where ``inside`` (H,) is True count.

    Few pixels reach the threshold: a row, then each tile's columns of it, are first
    tested for one (:func:`_row_reaches`, :func:`_reaches`, vectorised), and only the
    pixels of a tile that holds one are compared with the threshold and their
    neighbours, as a plain scan would."""
    per_column, width = out.shape
    threshold_px = np.empty(width, dtype=np.float32)
    spread, filled = 0, False  # the tile row threshold_px holds, once it holds one
    for s in range(spans.shape[0]):
        lo, hi = spans[s, 0], spans[s, 1]
        for r in range(lo, hi):
            if use_inside and not inside[r]:
                continue
            tiles = threshold_tiles[tile_row[r]]
            if not filled or tile_row[r] != spread:
                _spread(tiles, tile_px, threshold_px)
                spread, filled = tile_row[r], True
            if not _row_reaches(values, r, threshold_px):
                continue
            for tile in range(tiles.size):
                first, last = tile * tile_px, min((tile + 1) * tile_px, width)
                if not _reaches(values, r, first, last, tiles[tile]):
                    continue
                threshold = np.float64(tiles[tile])
                for c in range(first, last):
                    if np.float64(values[r, c]) >= threshold and _is_maximum(
                            values, r, c, lo, hi, sep):
                        if count[c] < per_column:
                            out[count[c], c] = r
                        count[c] += 1


def _reach_signatures() -> list[Any]:
    """Signatures of :func:`any_reaches`, per map dtype, writable or read-only."""
    i64 = types.int64
    return [types.boolean(types.Array(dtype, 2, "C", readonly=readonly),
                          types.Array(i64, 2, "A"), types.Array(types.float32, 2, "C"),
                          types.Array(i64, 1, "A"), i64)
            for dtype in (types.int16, types.int32, types.float32, types.float64)
            for readonly in (False, True)]


@kernel(_reach_signatures())
def any_reaches(values: npt.NDArray[np.generic], spans: IntArray,
                threshold_tiles: npt.NDArray[np.float32], tile_row: IntArray,
                tile_px: int) -> bool:
    """True when a pixel of ``values`` (H, W) in the row ``spans`` (S, 2) [lo, hi) reaches
    its tile's threshold (``threshold_tiles[tile_row[r], c // tile_px]``, DN, compared in
    float64 as numpy compares the map with a float32 image). Tiles are tested first
    (:func:`_reaches`); no (H, W) threshold image is made."""
    width = values.shape[1]
    for s in range(spans.shape[0]):
        for r in range(spans[s, 0], spans[s, 1]):
            tiles = threshold_tiles[tile_row[r]]
            for tile in range(tiles.size):
                first, last = tile * tile_px, min((tile + 1) * tile_px, width)
                if not _reaches(values, r, first, last, tiles[tile]):
                    continue
                threshold = np.float64(tiles[tile])
                for c in range(first, last):
                    if np.float64(values[r, c]) >= threshold:
                        return True
    return False


@kernel()
def _line_grid(line: IntArray, col: IntArray, row: FloatArray, lines: int, width: int,
               pad: int) -> FloatArray:
    """(lines, width + 2·pad) rows of the samples at column + pad, inf elsewhere."""
    grid = np.full((lines, width + 2 * pad), np.inf)
    for i in range(line.size):
        grid[line[i], col[i] + pad] = row[i]
    return grid


@kernel(f"boolean[:]({_I1}, {_I1}, {_F1}, int64, int64, int64, float64)")
def supported(line: IntArray, col: IntArray, row: FloatArray, lines: int, width: int,
              reach: int, max_step_px: float) -> npt.NDArray[np.bool_]:
    """(n,) True for samples with a sample of the same line within ``reach`` columns and
    ``max_step_px`` rows. ``line``, ``col`` (n,) int64 (0 <= col < width), ``row`` px."""
    grid = _line_grid(line, col, row, lines, width, reach)
    out = np.zeros(line.size, dtype=np.bool_)
    for i in range(line.size):
        for d in range(-reach, reach + 1):
            if d != 0 and abs(grid[line[i], col[i] + reach + d] - row[i]) <= max_step_px:
                out[i] = True
                break
    return out


@uncounted
def _ordered(a: float, b: float) -> tuple[float, float]:
    """(min, max) of a and b."""
    return min(a, b), max(a, b)


@uncounted
def _spread_of_five(p0: float, p1: float, p2: float, p3: float, p4: float
                    ) -> tuple[float, float, float]:
    """(least, median, greatest) of five values (no NaN) by a sorting network of nine
    exchanges (Knuth's), in registers: no branch per value as an insertion sort takes."""
    p0, p1 = _ordered(p0, p1)
    p3, p4 = _ordered(p3, p4)
    p2, p4 = _ordered(p2, p4)
    p2, p3 = _ordered(p2, p3)
    p1, p4 = _ordered(p1, p4)
    p0, p3 = _ordered(p0, p3)
    p0, p2 = _ordered(p0, p2)
    p1, p3 = _ordered(p1, p3)
    p1, p2 = _ordered(p1, p2)
    return p0, p2, p4


@kernel(f"float64[:]({_I1}, {_I1}, {_F1}, int64, int64, int64, float64)")
def smooth(line: IntArray, col: IntArray, row: FloatArray, lines: int, width: int,
           taps: int, max_step_px: float) -> FloatArray:
    """(n,) the median of the ``taps`` columns around each sample on its line where all
    exist and span at most ``max_step_px`` rows; elsewhere the sample's own row. Five
    taps of positive rows (or none, inf) go through a sorting network in registers
    (:func:`_spread_of_five`); others (a zero or NaN row, whose order an insertion sort
    keeps) and other tap counts through an insertion sort of the window."""
    half = taps // 2
    grid = _line_grid(line, col, row, lines, width, half)
    out = row.copy()
    window = np.empty(taps)
    for i in range(line.size):
        if taps == 5:
            at, c = grid[line[i]], col[i]
            p0, p1, p2, p3, p4 = at[c], at[c + 1], at[c + 2], at[c + 3], at[c + 4]
            if p0 > 0.0 and p1 > 0.0 and p2 > 0.0 and p3 > 0.0 and p4 > 0.0:
                low, middle, high = _spread_of_five(p0, p1, p2, p3, p4)
                if np.isfinite(high) and high - low <= max_step_px:
                    out[i] = middle
                continue
        for j in range(taps):  # insertion sort of the window
            v = grid[line[i], col[i] + j]
            k = j
            while k > 0 and window[k - 1] > v:
                window[k] = window[k - 1]
                k -= 1
            window[k] = v
        if np.isfinite(window[-1]) and window[-1] - window[0] <= max_step_px:
            out[i] = window[half]
    return out


@kernel(f"float64[:]({_I1}, {_F1}, int64)")
def line_medians(line: IntArray, values: FloatArray, count: int) -> FloatArray:
    """(count,) the median (as ``np.median``) of the ``values`` of each line 0..count-1,
    0.0 for a line without any; lines outside 0..count-1 are left out."""
    size = np.zeros(count + 1, dtype=np.int64)
    for k in line:
        if 0 <= k < count:
            size[k + 1] += 1
    start = np.cumsum(size)
    grouped = np.empty(start[-1])
    fill = start[:-1].copy()
    for i in range(line.size):
        k = line[i]
        if 0 <= k < count:
            grouped[fill[k]] = values[i]
            fill[k] += 1
    out = np.zeros(count)
    for k in range(count):
        if start[k + 1] > start[k]:
            out[k] = median(grouped[start[k]:start[k + 1]])
    return out


#: peak methods as :func:`refine` takes them
METHOD_CODES = {"cog": 0, "parabolic": 1, "gaussian": 2, "blais_rioux": 3, "steger": 4}


@kernel()
def _parabola(a: float, b: float, c: float) -> tuple[float, bool]:
    """Vertex offset of the parabola through (-1, a), (0, b), (1, c); ok when it opens
    downwards."""
    den = a - 2.0 * b + c
    return (0.5 * (a - c) / den, True) if den < 0 else (0.0, False)


@kernel()
def _offset(window: FloatArray, method: int, r: int, cog_threshold: float,
            sigma: float) -> tuple[float, bool]:
    """Sub-pixel offset of the peak at the centre of ``window`` (2r + 1,), and ok (the
    methods are described in :mod:`atris_node.pipeline.peaks`): cog above ``cog_threshold`` DN,
    parabolic, gaussian (a parabola through the logarithms), Blais-Rioux, Steger with
    stripe σ ``sigma`` px."""
    if method == 1:
        return _parabola(window[r - 1], window[r], window[r + 1])
    if method == 2:
        if min(window[r - 1], window[r], window[r + 1]) <= 0:
            return _parabola(np.log(max(window[r - 1], 1e-9)), np.log(max(window[r], 1e-9)),
                             np.log(max(window[r + 1], 1e-9)))[0], False
        return _parabola(np.log(window[r - 1]), np.log(window[r]), np.log(window[r + 1]))
    if method == 0:
        total = moment = 0.0
        for j in range(2 * r + 1):
            w = max(window[j] - cog_threshold, 0.0)
            total += w
            moment += w * (j - r)
        return (moment / total, True) if total > 0 else (0.0, False)
    if method == 3:
        return _blais_rioux(window, r)
    return _steger(window, r, sigma)


@kernel()
def _blais_rioux(window: FloatArray, r: int) -> tuple[float, bool]:
    """Zero crossing of the 4-tap derivative g(j) = w[j-2] + w[j-1] - w[j+1] - w[j+2]."""
    def g(j: int) -> float:
        return window[j - 2] + window[j - 1] - window[j + 1] - window[j + 2]

    gm, g0, g1 = g(r - 1), g(r), g(r + 1)
    right = g0 < 0  # still rising at the maximum: the crossing is between r and r + 1
    den = g0 - g1 if right else gm - g0
    if den == 0:
        return (0.0 if right else -1.0), False
    t = (g0 if right else gm) / den
    return (t if right else t - 1.0), 0.0 <= t <= 1.0


@kernel()
def _steger(window: FloatArray, r: int, sigma: float) -> tuple[float, bool]:
    """Three Newton steps on the Gaussian-smoothed first derivative (Steger)."""
    t, second = 0.0, -1.0
    for _ in range(3):
        first = second = 0.0
        for j in range(2 * r + 1):
            x = t - (j - r)
            gauss = np.exp(-0.5 * (x / sigma) ** 2)
            first += window[j] * (-x / sigma**2) * gauss
            second += window[j] * ((x * x / sigma**2 - 1.0) / sigma**2) * gauss
        step = first / second if second < 0 else 0.0
        t = min(max(t - step, -1.0), 1.0)
    return t, second < 0 and abs(t) < 1.0


def _sample_signatures() -> list[Any]:
    """Signatures of :func:`line_samples`, per map dtype, writable or read-only."""
    i64, f64, f32, b1 = types.int64, types.float64, types.float32, types.boolean
    f1, i1 = types.Array(f64, 1, "C"), types.Array(i64, 1, "C")
    out = types.Tuple((i1, f1, f1, f1, f1, types.Array(b1, 1, "C"), i64, i64))
    return [out(types.Array(dtype, 2, "C", readonly=readonly), types.Array(b1, 2, "A"), b1,
                types.Array(i64, 2, "A"), types.Array(i64, 1, "A"),
                types.Array(f32, 2, "A"), types.Array(f32, 2, "A"), i64, f64,
                i64, i64, f64, f64, f64, f64, i64, f64)
            for dtype in (types.int16, types.int32, f32, f64)
            for readonly in (False, True)]


@kernel()
def _saturated_run(saturated: npt.NDArray[np.bool_], row: int, c: int, r: int
                   ) -> tuple[int, int]:
    """First and last row of the run of saturated pixels in column c that holds (row, c),
    or the pixel above or below it (the run of a flat-topped peak, :func:`_flat_top`),
    followed at most ``r`` rows from ``row`` each way. Only the contiguous run: a second
    clipped stripe a few rows away (a near-parallel line pair on a bright surface) is
    another run and does not pull this one's centre. (row, row) when none is saturated."""
    height = saturated.shape[0]
    seed = -1
    for d in (0, -1, 1):
        i = row + d
        if 0 <= i < height and saturated[i, c]:
            seed = i
            break
    if seed < 0:
        return row, row
    lo = hi = seed
    while lo - 1 >= max(row - r, 0) and saturated[lo - 1, c]:
        lo -= 1
    while hi + 1 <= min(row + r, height - 1) and saturated[hi + 1, c]:
        hi += 1
    return lo, hi


@kernel()
def _open_run(saturated: npt.NDArray[np.bool_], lo: int, hi: int, c: int) -> bool:
    """True when the saturated run lo..hi of column c (:func:`_saturated_run`) was cut
    where it was followed: the pixel past one of its ends is saturated too."""
    height = saturated.shape[0]
    return bool((lo > 0 and saturated[lo - 1, c])
                or (hi < height - 1 and saturated[hi + 1, c]))


@kernel()
def _lit_run(values: npt.NDArray[np.generic], lo: int, hi: int, row: int, c: int) -> bool:
    """True when the saturated run lo..hi of column c holds, on average, at least half
    the value at (row, c): a stripe clipped at full scale. Pixels full in the OFF
    sub-frames as well (sunlit, blinded) demodulate to about 0: the run holds no laser
    light, and a peak at its edge is no stripe."""
    total = 0.0
    for i in range(lo, hi + 1):
        total += np.float64(values[i, c])
    return bool(total >= 0.5 * (hi - lo + 1) * np.float64(values[row, c]))


@kernel()
def _half_crossing(values: npt.NDArray[np.generic], edge: int, c: int, step: int,
                   level: float, reach: int) -> float:
    """Row (px, sub-pixel) where column c's profile, walked from the run's ``edge`` row
    by ``step`` (-1 up, +1 down) at most ``reach`` rows, first falls below ``level``,
    linearly interpolated between the last row at or above it and the first below it.
    Where the profile rises again first (another stripe's flank) or the image or the
    reach ends, the half-pixel boundary of the last row walked."""
    height = values.shape[0]
    prev = np.float64(values[edge, c])
    i = edge
    for _ in range(reach):
        j = i + step
        if j < 0 or j >= height:
            break
        v = np.float64(values[j, c])
        if v < level:
            return i + step * min(max((prev - level) / max(prev - v, 1e-9), 0.0), 1.0)
        if v > prev:
            break
        i, prev = j, v
    return i + 0.5 * step


#: rows of each unclipped flank a clipped stripe's Gaussian is fitted to
FLANK_ROWS = 3
#: least value of a flank row in the fit, as a fraction of the clipped run's value
FLANK_LEVEL = 0.03
#: largest distance (px) between the fit and the half-level crossings' centre
FLANK_AGREE_PX = 0.5


@kernel()
def _flank_fit(values: npt.NDArray[np.generic], lo: int, hi: int, c: int, floor: float,
               reach: int) -> tuple[float, bool]:
    """Centre (px) of the Gaussian through the unclipped flanks of a stripe clipped over
    rows lo..hi of column c: a parabola fitted to ln(value) of up to ``reach`` rows each
    side (weights value², the log's inverse variance), walked outward while a row stays
    above ``floor`` and does not rise (another stripe's flank). False where a side has no
    such row, there are fewer than three, or the fit is not a maximum near the run."""
    height = values.shape[0]
    m = 0.5 * (lo + hi)
    s0 = s1 = s2 = s3 = s4 = t0 = t1 = t2 = 0.0
    count = 0
    for step in (-1, 1):
        i = lo if step < 0 else hi
        prev = np.inf
        taken = 0
        for _ in range(reach):
            i += step
            if i < 0 or i >= height:
                break
            v = np.float64(values[i, c])
            if v <= floor or v > prev:
                break
            x, w, y = i - m, v * v, np.log(v)
            s0 += w
            s1 += w * x
            s2 += w * x * x
            s3 += w * x * x * x
            s4 += w * x * x * x * x
            t0 += w * y
            t1 += w * x * y
            t2 += w * x * x * y
            prev = v
            taken += 1
        if taken == 0:
            return m, False
        count += taken
    if count < 3:
        return m, False
    # normal equations of y = a + b x + q x² (3x3, Cramer's rule)
    det = s0 * (s2 * s4 - s3 * s3) - s1 * (s1 * s4 - s3 * s2) + s2 * (s1 * s3 - s2 * s2)
    if not abs(det) > 1e-12 * max(s0 * s2 * s4, 1e-300):
        return m, False
    b = (s0 * (t1 * s4 - s3 * t2) - t0 * (s1 * s4 - s3 * s2) + s2 * (s1 * t2 - t1 * s2)) / det
    q = (s0 * (s2 * t2 - t1 * s3) - s1 * (s1 * t2 - t1 * s2) + t0 * (s1 * s3 - s2 * s2)) / det
    if not q < 0.0:
        return m, False
    centre = m - b / (2.0 * q)
    if not abs(centre - m) <= 0.5 * (hi - lo) + 1.0:
        return m, False
    return centre, True


@kernel()
def _clipped_centre(values: npt.NDArray[np.generic], lo: int, hi: int, c: int,
                    reach: int, floor: float) -> float:
    """Sub-pixel centre (px) of a stripe clipped over the rows lo..hi of column c.

    First half-way between the rows where its profile crosses half the run's mean value
    above and below (:func:`_half_crossing`; a clipped symmetric profile stays symmetric,
    where the run's middle moves in half-pixel steps). Then, where each flank has a row
    above ``floor`` DN and FLANK_LEVEL of the run's value, and three such rows in all,
    the Gaussian through them (:func:`_flank_fit`), kept when it lies within
    FLANK_AGREE_PX of the crossings: a neighbour's tail (a near-parallel line pair) that
    bends the fit is not followed."""
    total = 0.0
    for i in range(lo, hi + 1):
        total += np.float64(values[i, c])
    level = total / (hi - lo + 1)
    top = _half_crossing(values, lo, c, -1, 0.5 * level, reach)
    bottom = _half_crossing(values, hi, c, 1, 0.5 * level, reach)
    half = 0.5 * (top + bottom)
    fit, fitted = _flank_fit(values, lo, hi, c, max(floor, FLANK_LEVEL * level), FLANK_ROWS)
    return fit if fitted and abs(fit - half) <= FLANK_AGREE_PX else half


@kernel()
def _flat_top(saturated: npt.NDArray[np.bool_], row: int, c: int) -> bool:
    """True when (row, c) or a pixel above or below it is saturated."""
    height = saturated.shape[0]
    for d in (-1, 0, 1):  # noqa: SIM110 (a generator does not compile)
        if saturated[min(max(row + d, 0), height - 1), c]:
            return True
    return False


#: σ of the noise by which a profile must fall short of the narrowest stripe to be cut
CUT_SIGMAS = 3.0


@kernel()
def _cut(window: FloatArray, r: int, background: float, noise: float, product: float
         ) -> bool:
    """True when the peak at the centre of ``window`` (2r + 1,) is narrower than a stripe
    of σ px, ``product`` = exp(-1/σ²) (taken once per map). Three samples of a Gaussian
    of σ, A at the maximum and a, c beside it, hold a·c = A²·exp(-1/σ²) wherever its
    centre lies between them: the smaller neighbour of a stripe that wide is at least
    A²·exp(-1/σ²) over the larger (all over the ``background``; the larger raised by
    CUT_SIGMAS times the ``noise``, so that a weak stripe's noisy flank cuts nothing).
    Cut when the smaller neighbour falls short of that by more than CUT_SIGMAS times the
    noise. A stripe cut by an edge (a corner, an object's outline, the end of a
    retro-reflector) keeps one flank: its maximum is the last lit row, off the sheet's
    centre by up to the stripe's width (the tail of a sheet whose centre fell on the
    ground before a retro-reflective wall, 1.9 px off, read 5.2 m for 6.5 m)."""
    peak = window[r] - background
    high = max(window[r - 1], window[r + 1]) - background + CUT_SIGMAS * noise
    low = min(window[r - 1], window[r + 1]) - background
    if high <= 0.0:  # no light beside the peak at all (a noiseless map): one row lit
        return peak > CUT_SIGMAS * noise
    need = peak * peak * product / high
    return need - low > CUT_SIGMAS * noise


@kernel(_sample_signatures())
def line_samples(values: npt.NDArray[np.generic], saturated: npt.NDArray[np.bool_],
                 any_saturated: bool, rows: IntArray, tile_row: IntArray,
                 background_tiles: npt.NDArray[np.float32],
                 sigma_tiles: npt.NDArray[np.float32], tile_px: int, snr_min: float,
                 method: int, r: int, cog_threshold: float, sigma: float, crlb: float,
                 saturated_sigma: float, saturation_window: int, narrowest: float
                 ) -> tuple[IntArray, FloatArray, FloatArray, FloatArray, FloatArray,
                            npt.NDArray[np.bool_], int, int]:
    """The line samples of the identified peaks ``rows`` (K, W) (-1 = none), line by
    line, column by column: (line, sub-pixel row px, column, SNR, σ_u px, flat top) of
    those kept, the number of peaks with SNR >= ``snr_min`` and the number of those
    dropped. SNR is against the peak's noise tile; the ``method``
    (:data:`METHOD_CODES`) reads the column profile of half width ``r``; a peak next to a
    saturated pixel (looked for only with ``any_saturated``) is flat-topped and takes the
    centre of its contiguous saturated run (:func:`_saturated_run`;
    :func:`_clipped_centre`) and σ_u ``saturated_sigma`` when that run holds laser light
    (:func:`_lit_run`; a peak at the edge of pixels blinded in every sub-frame is
    dropped) and is at most 2·``saturation_window`` + 1 rows long (a stripe of σ 2 px
    clipped at 1,000 times its threshold is 15 rows wide; a longer run is a patch clipped
    in the sub-frames, a lamp-lit floor whose flicker the code does not cancel, and no
    point of it is a stripe's centre: the middle of a window cut out of one read a line
    1.3 m ahead of a wall at 14 m; dropped); other peaks σ_u
    ``crlb / max(SNR, 1)``. A sample is kept when its profile lies inside the image and
    it is flat-topped or a local maximum with an offset within ±1 px, and not cut
    (:func:`_cut`, narrower than a stripe of σ ``narrowest`` px; 0: no test)."""
    k_count, width = rows.shape
    height = values.shape[0]
    size = k_count * width
    out_line, out_col = np.empty(size, dtype=np.int64), np.empty(size)
    out_row, out_snr, out_sigma = np.empty(size), np.empty(size), np.empty(size)
    out_flat = np.empty(size, dtype=np.bool_)
    window = np.empty(2 * r + 1)  # one column profile, float64
    product = np.exp(-1.0 / (narrowest * narrowest)) if narrowest > 0.0 else 0.0  # _cut
    n = strong = 0
    for k in range(k_count):
        for c in range(width):
            centre = rows[k, c]
            if centre < 0:
                continue
            tile = (tile_row[centre], c // tile_px)
            snr = (np.float64(values[centre, c]) - np.float64(background_tiles[tile])) / (
                np.float64(sigma_tiles[tile]))
            if not snr >= snr_min:
                continue
            strong += 1
            background = np.float64(background_tiles[tile])
            for j in range(2 * r + 1):  # the stripe over its tile's background
                window[j] = np.float64(values[min(max(centre - r + j, 0), height - 1), c]
                                       ) - background
            flat = any_saturated and _flat_top(saturated, centre, c)
            if not (centre - r >= 0 and centre + r < height):
                continue
            if flat:
                lo, hi = _saturated_run(saturated, centre, c, 2 * saturation_window)
                if (hi - lo > 2 * saturation_window or _open_run(saturated, lo, hi, c)
                        or not _lit_run(values, lo, hi, centre, c)):
                    continue  # no clipped stripe (blinded, or longer than the window)
                row = _clipped_centre(values, lo, hi, c, r, cog_threshold)
                sigma_u = saturated_sigma
            else:
                offset, good = _offset(window, method, r, cog_threshold, sigma)
                if not (good and abs(offset) <= 1.0 and window[r] >= window[r - 1]
                        and window[r] >= window[r + 1]):
                    continue
                if narrowest > 0.0 and _cut(window, r, 0.0, np.float64(sigma_tiles[tile]),
                                            product):
                    continue
                row, sigma_u = centre + offset, crlb / max(snr, 1.0)
            out_line[n], out_row[n], out_col[n] = k, row, c
            out_snr[n], out_sigma[n], out_flat[n] = snr, sigma_u, flat
            n += 1
    return (out_line[:n].copy(), out_row[:n].copy(), out_col[:n].copy(), out_snr[:n].copy(),
            out_sigma[:n].copy(), out_flat[:n].copy(), strong, strong - n)


def _snr_signatures() -> list[Any]:
    """Signatures of :func:`peak_snr`, per map dtype, writable or read-only."""
    i64, f32 = types.int64, types.float32
    out = types.Array(types.float64, 2, "C")
    return [out(types.Array(dtype, 2, "C", readonly=readonly), types.Array(i64, 2, "A"),
                types.Array(i64, 1, "A"), types.Array(f32, 2, "A"), types.Array(f32, 2, "A"),
                i64)
            for dtype in (types.int16, types.int32, f32, types.float64)
            for readonly in (False, True)]


@kernel(_snr_signatures())
def peak_snr(values: npt.NDArray[np.generic], rows: IntArray, tile_row: IntArray,
             background_tiles: npt.NDArray[np.float32], sigma_tiles: npt.NDArray[np.float32],
             tile_px: int) -> FloatArray:
    """(., W) SNR of ``values`` (H, W) at the ``rows`` (., W) of each column (0.0 where a
    row is -1): the value over its tile's background, in its tile's σ (the tiles as
    :func:`line_samples` reads them)."""
    out = np.zeros(rows.shape)
    for i in range(rows.shape[0]):
        for c in range(rows.shape[1]):
            r = rows[i, c]
            if r >= 0:
                tile = (tile_row[r], c // tile_px)
                out[i, c] = (np.float64(values[r, c]) - np.float64(background_tiles[tile])) / (
                    np.float64(sigma_tiles[tile]))
    return out


@uncounted
def _sorted_median(kept: FloatArray, n: int) -> float:
    """The median of the ascending ``kept[:n]`` (n >= 1), as np.median takes it."""
    if n % 2:
        return kept[n // 2]
    return (kept[n // 2 - 1] + kept[n // 2]) / 2.0


@uncounted
def _others_near(peaks: IntArray, c: int, r: int, reach: int, out: IntArray) -> int:
    """Column c's ``peaks`` (-1 padded) other than row ``r`` within ``reach`` rows of it
    into ``out``; their count."""
    n = 0
    for k in range(peaks.shape[0]):
        p = peaks[k, c]
        if p >= 0 and p != r and abs(p - r) <= reach:
            out[n] = p
            n += 1
    return n


@uncounted
def _by_a_peak(others: IntArray, n: int, q: int, reach: int) -> bool:
    """True when row ``q`` lies within ``reach`` rows of one of ``others[:n]``."""
    for k in range(n):  # noqa: SIM110 (a generator does not compile)
        if abs(q - others[k]) < reach:
            return True
    return False


def _flank_signatures() -> list[Any]:
    """Signatures of :func:`flank_snr`, per map dtype, writable or read-only."""
    i64, f64 = types.int64, types.float64
    out = types.Array(f64, 2, "C")
    return [out(types.Array(dtype, 2, "C", readonly=readonly), types.Array(i64, 2, "A"),
                types.Array(i64, 2, "A"), types.Array(f64, 2, "A"), f64, f64, i64, i64, f64)
            for dtype in (types.int16, types.int32, types.float32, f64)
            for readonly in (False, True)]


@kernel(_flank_signatures())
def flank_snr(values: npt.NDArray[np.generic], rows: IntArray, peaks: IntArray,
              tile: FloatArray, lo: float, hi: float, near: int, far: int,
              floor_dn: float) -> FloatArray:
    """(., W) SNR of ``values`` (H, W) at the ``rows`` (., W) of each column against its
    own flanks, where their SNR against their tiles ``tile`` (., W) lies in ``[lo, hi)``
    (``tile`` itself elsewhere, 0.0 where a row is -1): the value over the higher of the
    medians of the rows ``near`` to ``far`` above it and below it (those inside the
    image; a side with none does not count), in the larger of their σ (1.4826 times the
    median absolute deviation), at least ``floor_dn``. A row with no flank row inside
    the image gets the value over 0 in ``floor_dn``."""
    height = values.shape[0]
    out = np.zeros(rows.shape)
    kept = np.empty(far - near + 1)
    others = np.empty(peaks.shape[0], dtype=np.int64)
    for i in range(rows.shape[0]):
        for c in range(rows.shape[1]):
            r = rows[i, c]
            if r < 0:
                continue
            if not lo <= tile[i, c] < hi:
                out[i, c] = tile[i, c]
                continue
            base = -np.inf
            sigma = floor_dn
            n_others = _others_near(peaks, c, r, far + near, others)
            for step in (-1, 1):
                n = 0
                for d in range(near, far + 1):
                    q = r + step * d
                    if 0 <= q < height and not _by_a_peak(others, n_others, q, near):
                        insert_sorted(kept, n, np.float64(values[q, c]))
                        n += 1
                if n == 0:
                    continue
                level = _sorted_median(kept, n)
                for a in range(n):
                    kept[a] = abs(kept[a] - level)
                for a in range(1, n):
                    insert_sorted(kept, a, kept[a])
                base = max(base, level)
                sigma = max(sigma, 1.4826 * _sorted_median(kept, n))
            out[i, c] = (np.float64(values[r, c]) - (base if base > -np.inf else 0.0)) / sigma
    return out


def _edge_signatures() -> list[Any]:
    """Signatures of :func:`one_sided`, per map dtype, writable or read-only."""
    i64, f32, f64, b1 = types.int64, types.float32, types.float64, types.boolean
    out = types.Array(b1, 2, "C")
    return [out(types.Array(dtype, 2, "C", readonly=readonly), types.Array(i64, 2, "A"),
                types.Array(b1, 2, "A"), b1, types.Array(i64, 1, "A"),
                types.Array(f32, 2, "A"), i64, i64, i64, f64, f64)
            for dtype in (types.int16, types.int32, f32, f64)
            for readonly in (False, True)]


@uncounted
def _flank_floor(values: npt.NDArray[np.generic], row: int, c: int, step: int, near: int,
                 far: int, stop: int, kept: FloatArray) -> float:
    """The median value (DN) of column ``c`` from ``near`` to ``far`` rows away from
    ``row`` in direction ``step`` (+1 down, -1 up), rows inside the image only, and ending
    ``near`` rows before the next maximum ``stop`` rows away (the valley half-way to it
    when they are closer than that); inf when no row is. The median, not the lowest: the
    lowest of a few noisy values lies over a σ under its side's level, and a step's bright
    side then looks like a drop; the next maximum is another stripe's, not a flank.
    ``kept`` (at least far - near + 1,) work space; the median as np.median takes it.
    Seven rows inside the image (the default flank, far - near = 6) are read into
    registers and go through :func:`_median_of_seven` without the work space."""
    height = values.shape[0]
    last = min(far, stop - near)
    first = near
    if last - first == 6 and first > 0 and 0 <= row + step * first < height and (
            0 <= row + step * last < height):  # the whole flank of a stripe of σ 1.5 px
        i = row + step * first
        return _median_of_seven(
            np.float64(values[i, c]), np.float64(values[i + step, c]),
            np.float64(values[i + 2 * step, c]), np.float64(values[i + 3 * step, c]),
            np.float64(values[i + 4 * step, c]), np.float64(values[i + 5 * step, c]),
            np.float64(values[i + 6 * step, c]))
    if last < first:
        first = last = stop // 2
    n = 0
    for d in range(first, last + 1):
        i = row + step * d
        if d > 0 and 0 <= i < height:
            kept[n] = np.float64(values[i, c])
            n += 1
    if n == 0:
        return np.inf
    if n == 7:  # the whole flank of a stripe of σ 1.5 px (the default)
        return _median_of_7(kept)
    for a in range(1, n):  # a flank is a few rows
        insert_sorted(kept, a, kept[a])
    return _sorted_median(kept, n)


@uncounted
def _median_of_7(p: FloatArray) -> float:
    """The median of ``p[:7]`` (finite values), :func:`_median_of_seven` of them."""
    return _median_of_seven(p[0], p[1], p[2], p[3], p[4], p[5], p[6])


@uncounted
def _median_of_seven(p0: float, p1: float, p2: float, p3: float, p4: float, p5: float,
                     p6: float) -> float:
    """The median of seven finite values by a selection network of 13 exchanges (no
    branch to mispredict), in registers: an array in memory stalls each exchange on the
    store of the one before."""
    p0, p5 = _ordered(p0, p5)
    p0, p3 = _ordered(p0, p3)
    p1, p6 = _ordered(p1, p6)
    p2, p4 = _ordered(p2, p4)
    p0, p1 = _ordered(p0, p1)
    p3, p5 = _ordered(p3, p5)
    p2, p6 = _ordered(p2, p6)
    p2, p3 = _ordered(p2, p3)
    p3, p6 = _ordered(p3, p6)
    p4, p5 = _ordered(p4, p5)
    p1, p4 = _ordered(p1, p4)
    p1, p3 = _ordered(p1, p3)
    p3, p4 = _ordered(p3, p4)
    return p3


@uncounted
def _next_maxima(peaks: IntArray, m: int, c: int) -> tuple[int, int]:
    """Rows from peak ``m`` of column ``c`` to the nearest other peak above it and to the
    nearest below it, in one pass over the column; a large number where there is none.
    ``peaks`` holds its -1 padding after the rows."""
    row = peaks[m, c]
    above = below = 1 << 30
    for q in range(peaks.shape[0]):
        other = peaks[q, c]
        if other < 0:
            break
        if other < row:
            above = min(above, row - other)
        elif other > row:
            below = min(below, other - row)
    return above, below


@kernel(_edge_signatures())
def one_sided(values: npt.NDArray[np.generic], peaks: IntArray,
              saturated: npt.NDArray[np.bool_], any_saturated: bool, tile_row: IntArray,
              sigma_tiles: npt.NDArray[np.float32], tile_px: int, near: int, far: int,
              ratio: float, sigmas: float) -> npt.NDArray[np.bool_]:
    """(P, W) True for the maxima ``peaks`` (rows, -1 padding) that stand above one side
    of their column only: the edge of a step, not a stripe. A stripe falls on both sides
    within a few stripe widths: the median value ``near``..``far`` rows above it and the
    median below it (each flank ending before the next maximum, another stripe's) both
    lie well under it. A maximum is one-sided when the smaller of its
    two drops is under ``ratio`` times the larger or under ``sigmas`` of its noise tile's
    σ (DN). A step of the background does that: flicker that beats with the code leaves a
    residual image of the lit scene, bright ground under a dark wall, and the first rows
    of the bright side are maxima over the threshold of a tile that reaches into the dark
    side. Flat-topped maxima (a saturated pixel within one row, looked for only with
    ``any_saturated``) are left to the saturated-run test; a side outside the image does
    not count."""
    out = np.zeros(peaks.shape, dtype=np.bool_)
    kept = np.empty(max(far - near + 1, 1))  # one flank's values
    for m in range(peaks.shape[0]):
        for c in range(peaks.shape[1]):
            row = peaks[m, c]
            if row < 0 or (any_saturated and _flat_top(saturated, row, c)):
                continue
            up, down = _next_maxima(peaks, m, c)
            v = np.float64(values[row, c])
            above = v - _flank_floor(values, row, c, -1, near, far, up, kept)
            below = v - _flank_floor(values, row, c, 1, near, far, down, kept)
            low, high = min(above, below), max(above, below)
            if np.isinf(low):
                low = high  # one side outside the image: the other side decides
            if np.isinf(high):
                continue
            noise = np.float64(sigma_tiles[tile_row[row], c // tile_px])
            out[m, c] = low < ratio * high or low < sigmas * noise
    return out


def _blinded_signatures() -> list[Any]:
    """Signatures of :func:`blinded`, per map dtype, writable or read-only."""
    i64, f32, b1 = types.int64, types.float32, types.boolean
    return [types.boolean(types.Array(dtype, 2, "C", readonly=readonly),
                          types.Array(b1, 2, "C", readonly=readonly),
                          types.Array(i64, 2, "A"), types.Array(f32, 2, "A"),
                          types.Array(i64, 1, "A"), i64, types.Array(b1, 2, "C"))
            for dtype in (types.int16, types.int32, f32, types.float64)
            for readonly in (False, True)]


@kernel()
def _any_set(mask: npt.NDArray[np.bool_], r: int, lo: int, hi: int) -> bool:
    """True when ``mask`` holds a True in row r, columns [lo, hi). A loop without branches
    over a row slice, which the compiler vectorises."""
    row = mask[r, lo:hi]
    found = False
    for c in range(row.size):
        found |= row[c]
    return found


#: columns of a row :func:`blinded` tests for a saturated pixel in one vectorised step
SATURATED_CHUNK_PX = 64


@kernel(_blinded_signatures())
def blinded(values: npt.NDArray[np.generic], saturated: npt.NDArray[np.bool_],
            bands: IntArray, threshold_tiles: npt.NDArray[np.float32], tile_row: IntArray,
            tile_px: int, out: npt.NDArray[np.bool_]) -> bool:
    """``out`` (K, W) zeros in; True out where band k (``bands`` (K, 2) rows [lo, hi))
    holds in column c a saturated pixel below its tile's threshold (DN): full scale in
    the OFF sub-frames too, no laser light. Only the band rows are read, and of them only
    the rows, then the SATURATED_CHUNK_PX chunks, that hold a saturated pixel
    (:func:`_any_set`) pixel by pixel. Returns whether any was found."""
    found = False
    width = values.shape[1]
    for k in range(bands.shape[0]):
        for r in range(max(bands[k, 0], 0), min(bands[k, 1], values.shape[0])):
            if not _any_set(saturated, r, 0, width):
                continue
            tiles = threshold_tiles[tile_row[r]]
            for lo in range(0, width, SATURATED_CHUNK_PX):
                hi = min(lo + SATURATED_CHUNK_PX, width)
                if not _any_set(saturated, r, lo, hi):
                    continue
                for c in range(lo, hi):
                    if saturated[r, c] and not out[k, c] and (
                            np.float64(values[r, c]) < np.float64(tiles[c // tile_px])):
                        out[k, c] = True
                        found = True
    return found


def _energy_signatures() -> list[Any]:
    """Signatures of :func:`signed_energy`, per map dtype, writable or read-only."""
    i64, f32, f64, b1 = types.int64, types.float32, types.float64, types.boolean
    out = types.Tuple((f64, f64))
    return [out(types.Array(dtype, 2, "C", readonly=readonly),
                types.Array(b1, 2, "C", readonly=readonly), types.Array(i64, 2, "A"), f32,
                f32, types.Array(b1, 1, "C"))
            for dtype in (types.int16, types.int32, f32, types.float64)
            for readonly in (False, True)]


@kernel()
def _signed(values: npt.NDArray[np.generic], saturated: npt.NDArray[np.bool_], r: int,
            c: int, background: np.float32) -> np.float32:
    """values[r, c] - background in float32 (DN), 0 where saturated."""
    if saturated[r, c]:
        return np.float32(0.0)
    return np.float32(values[r, c]) - background


#: columns of a row :func:`signed_energy` tests in one vectorised step before it looks
#: at single pixels (most chunks hold no pixel beyond the threshold)
ENERGY_CHUNK_PX = 64


@kernel()
def _beyond(values: npt.NDArray[np.generic], r: int, lo: int, hi: int,
            background: np.float32, threshold: np.float32) -> bool:
    """True when a pixel of row r, columns [lo, hi), lies more than ``threshold`` from
    ``background`` (float32, DN; saturation not looked at). A loop without branches over
    a row slice, which the compiler vectorises."""
    row = values[r, lo:hi]
    found = False
    for c in range(row.size):
        found |= bool(abs(np.float32(row[c]) - background) > threshold)
    return found


@kernel(_energy_signatures())
def signed_energy(values: npt.NDArray[np.generic], saturated: npt.NDArray[np.bool_],
                  spans: IntArray, background: np.float32, threshold: np.float32,
                  columns: npt.NDArray[np.bool_]) -> tuple[float, float]:
    """(negative, positive) energy of the map rows ``spans`` (S, 2) [lo, hi), DN: the sum of
    -v over the line-like negative pixels (v below ``-threshold`` with both row neighbours
    below ``-threshold / 2``; not in the first or last column) and of v over the pixels
    above ``threshold``, v = value - ``background`` in float32, 0 where saturated. The
    columns of line-like negative pixels are set in ``columns`` (W,).

    One pass: each row, then each ENERGY_CHUNK_PX chunk of it, is first tested for a pixel
    beyond ``threshold`` (:func:`_beyond`; a saturated pixel's v = 0 is beyond only when
    ``threshold`` < 0, and then every chunk is looked at); only chunks that hold one are
    summed pixel by pixel, in the same order as a plain scan, so the float64 sums are
    those of the scan, bit for bit."""
    negative = positive = 0.0
    weak = -threshold / np.float32(2.0)
    width = values.shape[1]
    everywhere = not threshold >= 0
    for s in range(spans.shape[0]):
        for r in range(spans[s, 0], spans[s, 1]):
            if not (everywhere or _beyond(values, r, 0, width, background, threshold)):
                continue
            for lo in range(0, width, ENERGY_CHUNK_PX):
                hi = min(lo + ENERGY_CHUNK_PX, width)
                if not (everywhere or _beyond(values, r, lo, hi, background, threshold)):
                    continue
                for c in range(lo, hi):
                    v = _signed(values, saturated, r, c, background)
                    if v > threshold:
                        positive += v
                    elif v < -threshold and 0 < c < width - 1 and (
                            _signed(values, saturated, r, c - 1, background) < weak
                            and _signed(values, saturated, r, c + 1, background) < weak):
                        negative -= v
                        columns[c] = True
    return negative, positive


def _subsample_signatures(out: Any, *rest: Any) -> list[Any]:
    """Signatures of the noise kernels, per integer map dtype (int16, int32), writable or
    read-only, as (map, ``rest``...) -> ``out``."""
    return [out(types.Array(dtype, 2, "C", readonly=readonly), *rest)
            for dtype in (types.int16, types.int32) for readonly in (False, True)]


_ROWS = (types.Array(types.int64, 1, "C"), types.Array(types.int64, 1, "C"))


@kernel(_subsample_signatures(types.UniTuple(types.int64, 2), *_ROWS))
def rows_range(values: npt.NDArray[np.integer[Any]], starts: IntArray, stops: IntArray
               ) -> tuple[int, int]:
    """(least, greatest) value (DN) of the whole map rows ``starts[s]``,
    ``starts[s] + 2``, ... below ``stops[s]``: bounds of :func:`subsample_counts`'s
    values (those rows' even columns); (0, -1) when there is no such row. A loop without
    branches per row, which the compiler vectorises."""
    low, high = np.int64(0), np.int64(-1)
    for s in range(starts.size):
        for r in range(starts[s], stops[s], 2):
            row = values[r]
            lo = hi = row[0]
            for c in range(row.size):
                v = row[c]
                lo = v if v < lo else lo
                hi = v if v > hi else hi
            if high < low:
                low, high = np.int64(lo), np.int64(hi)
            else:
                low, high = min(low, np.int64(lo)), max(high, np.int64(hi))
    return int(low), int(high)


#: partial counts :func:`subsample_counts` keeps (interleaved columns)
PARTIAL_COUNTS = 8


@kernel(_subsample_signatures(types.Array(types.int64, 1, "C"), *_ROWS, types.int64,
                              types.int64))
def subsample_counts(values: npt.NDArray[np.integer[Any]], starts: IntArray, stops: IntArray,
                     low: int, size: int) -> IntArray:
    """(size,) how many pixels of the 2x2 subsample (rows ``starts[s]``, ``starts[s] + 2``,
    ... below ``stops[s]``, even columns) hold each value ``low``, ``low + 1``, ... (DN);
    every value must lie in that range (:func:`rows_range`). PARTIAL_COUNTS partial
    counts, added at the end, keep runs of equal values from waiting on each other."""
    part = np.zeros((PARTIAL_COUNTS, size), dtype=np.int64)
    width = values.shape[1]
    step = 2 * PARTIAL_COUNTS
    for s in range(starts.size):
        for r in range(starts[s], stops[s], 2):
            row = values[r]
            c = 0
            while c + step - 2 < width:
                for j in range(PARTIAL_COUNTS):
                    part[j, np.int64(row[c + 2 * j]) - low] += 1
                c += step
            while c < width:
                part[0, np.int64(row[c]) - low] += 1
                c += 2
    out = np.zeros(size, dtype=np.int64)
    for j in range(PARTIAL_COUNTS):
        out += part[j]
    return out


@kernel("float32[:, :](int64[:], float32[:, :], int64[:, :], int64, int64)")
def band_noise(tile_row: IntArray, sigma_tiles: npt.NDArray[np.float32], bands: IntArray,
               tile_px: int, width: int) -> npt.NDArray[np.float32]:
    """(K, W) float32, DN: per band k (``bands`` (K, 2) rows [lo, hi)) and column c the
    highest σ in ``sigma_tiles`` (R + 1, C) of the tiles ``tile_row`` (H,) gives the
    band's rows, in c's tile column (NaN where one is NaN, as ``np.max``); 0 for a band
    without rows."""
    out = np.zeros((bands.shape[0], width), dtype=np.float32)
    seen = np.zeros(sigma_tiles.shape[0], dtype=np.bool_)
    high = np.empty(sigma_tiles.shape[1], dtype=np.float32)
    for k in range(bands.shape[0]):
        seen[:] = False
        first = True
        for r in range(bands[k, 0], bands[k, 1]):
            t = tile_row[r]
            if seen[t]:
                continue
            seen[t] = True
            for j in range(high.size):
                v = sigma_tiles[t, j]
                if first or (not np.isnan(high[j]) and (np.isnan(v) or v > high[j])):
                    high[j] = v
            first = False
        if not first:
            for c in range(width):
                out[k, c] = high[c // tile_px]
    return out


@kernel("Tuple((int64[:], int64[:], int64[:], float32[:]))"
        "(int64[:, :], int64[:], float32[:, :], int64)")
def peak_pixels(peaks: IntArray, tile_row: IntArray, sigma_tiles: npt.NDArray[np.float32],
                tile_px: int) -> tuple[IntArray, IntArray, IntArray, npt.NDArray[np.float32]]:
    """The maxima ``peaks`` (M, W) (rows, -1 padding), slot by slot in row-major order
    (as ``np.nonzero(peaks >= 0)``): (n,) each their slot m, column c, flat pixel index
    ``row · W + c`` and their noise tile's σ (DN, float32) in ``sigma_tiles`` (R + 1, C)."""
    width = peaks.shape[1]
    n = 0
    for m in range(peaks.shape[0]):
        for c in range(width):
            n += peaks[m, c] >= 0
    slot, col = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    flat, sigma = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.float32)
    i = 0
    for m in range(peaks.shape[0]):
        for c in range(width):
            r = peaks[m, c]
            if r >= 0:
                slot[i], col[i], flat[i] = m, c, r * width + c
                sigma[i] = sigma_tiles[tile_row[r], c // tile_px]
                i += 1
    return slot, col, flat, sigma


@kernel("int64[:](int64[:, :], boolean[:])")
def covered_per_column(peaks: IntArray, covered: npt.NDArray[np.bool_]) -> IntArray:
    """(W,) how many entries of (M, W) ``peaks`` (rows, -1 = none) fall on a row that
    ``covered`` (T + 1,) marks, rows beyond T (and -1) looked up at T, as
    ``covered[np.minimum(peaks, T)].sum(axis=0)`` counts them."""
    top = covered.size - 1
    out = np.zeros(peaks.shape[1], dtype=np.int64)
    for m in range(peaks.shape[0]):
        for c in range(peaks.shape[1]):
            r = peaks[m, c]
            out[c] += covered[top if r > top else r]
    return out


@kernel("Tuple((float64[:], float64[:]))(float64[:, :], int64[:])")
def ambient_level(series: FloatArray, rows: IntArray) -> tuple[FloatArray, FloatArray]:
    """Per column p of ``series`` (n, P) float64 (DN) over its ``rows`` (k,) (the OFF
    sub-frames, k >= 1): the level ``max(mean, 1)`` and the ratio of the variance (ddof
    1; 0 for k = 1) to it, (P,) each, computed as numpy's ``mean``, ``var`` (the rows
    added one after another) and ``maximum`` do. The sums run along the rows (contiguous)
    and add each column's values in row order, as a loop per column would."""
    k, size = rows.size, series.shape[1]
    total, squares = np.zeros(size), np.zeros(size)
    for i in range(k):  # row by row: contiguous passes, each column's sum in row order
        row = series[rows[i]]
        for p in range(size):
            total[p] += row[p]
    mean = np.empty(size)
    level, ratio = np.empty(size), np.empty(size)
    for p in range(size):
        mean[p] = total[p] / k
        level[p] = mean[p] if (mean[p] >= 1.0 or np.isnan(mean[p])) else 1.0
    if k > 1:
        for i in range(k):
            row = series[rows[i]]
            for p in range(size):
                d = row[p] - mean[p]
                squares[p] += d * d
    for p in range(size):
        ratio[p] = (squares[p] / (k - 1) if k > 1 else 0.0) / level[p]
    return level, ratio


#: side (px) of a noise tile in the 2×2 subsample: NOISE_TILE_PX / 2
#: (:mod:`atris_node.pipeline.noise`)
SUBSAMPLE_TILE_PX = 16


def _tiles_signatures() -> list[Any]:
    """Signatures of :func:`subsample_tiles`, per map dtype, writable or read-only."""
    return [types.Array(dtype, 3, "C")(types.Array(dtype, 2, "C", readonly=readonly))
            for dtype in (types.int16, types.int32, types.float32, types.float64)
            for readonly in (False, True)]


@kernel()
def _mirrored(i: int, n: int) -> int:
    """Index into n values of position i of their symmetric extension (as ``np.pad``
    "symmetric": the edge value repeated, then the values backwards, and so on)."""
    m = i % (2 * n)
    return m if m < n else 2 * n - 1 - m


@kernel(_tiles_signatures())
def subsample_tiles(block: npt.NDArray[np.generic]) -> npt.NDArray[np.generic]:
    """(nr, nc, T²) the 2×2 subsample of ``block`` (h, w) (h, w >= 1) cut into T × T
    tiles (T = SUBSAMPLE_TILE_PX) from the top left corner, each tile's values row by
    row, the subsample extended symmetrically to whole tiles: the values of ``np.pad``
    "symmetric", reshape and transpose, in one pass (tiles inside the subsample's width
    copied 16 values at a time)."""
    side = SUBSAMPLE_TILE_PX
    rows, cols = (block.shape[0] + 1) // 2, (block.shape[1] + 1) // 2
    nr, nc = -(-rows // side), -(-cols // side)
    out = np.empty((nr, nc, side * side), dtype=block.dtype)
    flat = out.reshape(-1)
    inside = cols // side  # tiles that need no mirrored column
    for i in range(nr * side):
        row = block[2 * _mirrored(i, rows)]
        base = (i // side) * nc * side * side + (i % side) * side
        for tc in range(inside):
            start = base + tc * side * side
            into, source = flat[start:start + side], row[2 * side * tc:2 * side * (tc + 1)]
            for b in range(side):
                into[b] = source[2 * b]
        for tc in range(inside, nc):
            start = base + tc * side * side
            for b in range(side):
                flat[start + b] = row[2 * _mirrored(tc * side + b, cols)]
    return out


#: counts per tile in :func:`_picked`: values this far above the tile's
#: least share the last count (a pick there is read from a sort of the tile instead)
ORDER_COUNTS = 1024


@kernel()
def _picked(tile: npt.NDArray[np.integer[Any]], picks: IntArray,
            counts: npt.NDArray[np.int32], out: npt.NDArray[np.integer[Any]]) -> None:
    """``out[j]`` = ``np.sort(tile)[picks[j]]``, by counting the values of ``tile`` from
    its least in ``counts`` (ORDER_COUNTS zeros, left zero); sorted where a pick lies in
    the last, shared count."""
    n, last = tile.size, ORDER_COUNTS - 1
    low = high = tile[0]
    for i in range(n):
        low = tile[i] if tile[i] < low else low
        high = tile[i] if tile[i] > high else high
    for i in range(n):
        d = np.int64(tile[i]) - np.int64(low)
        counts[d if d < last else last] += 1
    below, b, wide = 0, 0, False
    for j in range(picks.size):
        if picks[j] < below:  # a pick before the one above: count again
            below, b = 0, 0
        while below + counts[b] <= picks[j]:
            below += counts[b]
            b += 1
        wide = wide or b == last
        out[j] = low + b
    top = np.int64(high) - np.int64(low)
    counts[:(top if top < last else last) + 1] = 0
    if wide:
        ordered = np.sort(tile)
        for j in range(picks.size):
            out[j] = ordered[picks[j]]


def _noise_signatures() -> list[Any]:
    """Signatures of :func:`tile_noise`, per integer map dtype."""
    f32 = types.Array(types.float32, 2, "C")
    return [types.Tuple((f32, f32))(types.Array(dtype, 3, "C", readonly=readonly),
                                    types.Array(types.int64, 1, "C"),
                                    types.Array(types.float32, 1, "C"), types.float32,
                                    types.float32)
            for dtype in (types.int16, types.int32) for readonly in (False, True)]


@kernel()
def _between(low: np.float32, high: np.float32, fraction: np.float32) -> np.float32:
    """``low + fraction · (high - low)`` in float32 (numpy's float32 array arithmetic
    with a Python float fraction), ``low`` for a fraction of 0."""
    if fraction == 0:
        return low
    return low + fraction * (high - low)


@kernel(_noise_signatures())
def tile_noise(tiles: npt.NDArray[np.integer[Any]], picks: IntArray,
               fractions: npt.NDArray[np.float32], to_sigma: np.float32,
               least: np.float32) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """(median, σ) (nr, nc) float32 of each tile of ``tiles`` (nr, nc, n): from the
    values at ``picks`` (the lower and upper neighbours of the 25th percentile, then of
    the median) of the sorted tile (:func:`_picked`), each percentile interpolated by
    its ``fractions`` as numpy's float32 arithmetic does, σ = max((median - q25) /
    ``to_sigma``, ``least``) in float32. Counting is several times faster than numpy's
    sort of the (tiles, n) 16-bit values on a CPU without numpy's AVX-512 sort (about
    7 against 0.5 ms at 1280x800)."""
    nr, nc, _ = tiles.shape
    median = np.empty((nr, nc), dtype=np.float32)
    sigma = np.empty((nr, nc), dtype=np.float32)
    counts = np.zeros(ORDER_COUNTS, dtype=np.int32)
    at = np.empty(picks.size, dtype=tiles.dtype)
    for r in range(nr):
        for c in range(nc):
            _picked(tiles[r, c], picks, counts, at)
            q25 = _between(np.float32(at[0]), np.float32(at[1]), fractions[0])
            middle = _between(np.float32(at[2]), np.float32(at[3]), fractions[1])
            median[r, c] = middle
            spread = (middle - q25) / to_sigma
            sigma[r, c] = spread if spread > least else least
    return median, sigma


@kernel("Tuple((int64[:, :], int64[:]))(int64[:, :], int64[:, :], int64, int64, float64)")
def off_steps(rows: IntArray, step_rows: IntArray, reach: int, row_px: int, share: float
              ) -> tuple[IntArray, IntArray]:
    """The rule of :func:`atris_node.pipeline.peaks.off_step_runs`: ``rows`` (K, W) without
    each peak that has step maxima (``step_rows`` (M, W), -1 = none) within ``row_px`` of
    its row in at least two, and ``share`` or more, of the columns within ``reach`` that
    hold either them or its own line within ``row_px`` of that row; and (W,) the peaks
    taken out per column."""
    k_count, width = rows.shape
    out = rows.copy()
    removed = np.zeros(width, dtype=np.int64)
    has_step = np.zeros(width, dtype=np.bool_)
    for m in range(step_rows.shape[0]):  # along the rows of ``step_rows``
        for c in range(width):
            has_step[c] |= step_rows[m, c] >= 0
    total = np.zeros(width + 1, dtype=np.int64)  # columns holding a step maximum, cumulated
    for c in range(width):
        total[c + 1] = total[c] + has_step[c]
    if total[width] == 0:
        return out, removed
    for c in range(width):
        lo, hi = max(c - reach, 0), min(c + reach + 1, width)
        if total[hi] == total[lo]:
            continue  # no step maximum within reach
        for k in range(k_count):
            row = rows[k, c]
            if row < 0:
                continue
            count = either = 0
            for q in range(lo, hi):
                stepped = False
                if has_step[q]:
                    for m in range(step_rows.shape[0]):
                        step = step_rows[m, q]
                        stepped |= step >= 0 and abs(step - row) <= row_px
                own = rows[k, q] >= 0 and abs(rows[k, q] - row) <= row_px
                count += stepped
                either += stepped or own
            if count >= 2 and count >= share * either:
                out[k, c] = -1
                removed[c] += 1
    return out, removed


def warm_up() -> None:
    """Call every kernel once on a tiny input (see
    :func:`atris_node.pipeline.identity_kernels.warm_up`)."""
    i64 = np.int64
    line = np.array([0], dtype=i64)
    strong_maxima(np.zeros((4, 1), dtype=np.int16), np.array([[0, 4]], dtype=i64),
                  np.ones((1, 1), dtype=np.float32), np.zeros(4, dtype=i64), 32, 2,
                  np.zeros(4, dtype=np.bool_), False, np.full((2, 1), -1, dtype=i64),
                  np.zeros(1, dtype=i64))
    any_reaches(np.zeros((4, 1), dtype=np.int16), np.array([[0, 4]], dtype=i64),
                np.ones((1, 1), dtype=np.float32), np.zeros(4, dtype=i64), 32)
    supported(line, line, np.zeros(1), 1, 1, 2, 2.0)
    smooth(line, line, np.zeros(1), 1, 1, 5, 2.0)
    line_samples(np.zeros((4, 1), dtype=np.int16), np.zeros((1, 1), dtype=np.bool_), False,
                 np.array([[2]], dtype=i64), np.zeros(4, dtype=i64),
                 np.zeros((1, 1), dtype=np.float32), np.ones((1, 1), dtype=np.float32), 32,
                 6.0, 2, 1, 0.0, 1.5, 1.0, 0.5, 8, 0.0)
    line_medians(line, np.zeros(1), 1)
    signed_energy(np.zeros((4, 3), dtype=np.int16), np.zeros((4, 3), dtype=np.bool_),
                  np.array([[0, 4]], dtype=i64), np.float32(0.0), np.float32(1.0),
                  np.zeros(3, dtype=np.bool_))
    blinded(np.zeros((4, 1), dtype=np.int16), np.zeros((4, 1), dtype=np.bool_),
            np.array([[0, 4]], dtype=i64), np.ones((1, 1), dtype=np.float32),
            np.zeros(4, dtype=i64), 32, np.zeros((1, 1), dtype=np.bool_))
    one_sided(np.zeros((4, 1), dtype=np.int16), np.array([[2]], dtype=i64),
              np.zeros((1, 1), dtype=np.bool_), False, np.zeros(4, dtype=i64),
              np.ones((1, 1), dtype=np.float32), 32, 2, 8, 0.5, 3.0)
    peak_snr(np.zeros((4, 1), dtype=np.int16), np.array([[2]], dtype=i64),
             np.zeros(4, dtype=i64), np.zeros((1, 1), dtype=np.float32),
             np.ones((1, 1), dtype=np.float32), 32)
    flank_snr(np.zeros((4, 1), dtype=np.int16), np.array([[2]], dtype=i64),
              np.array([[2]], dtype=i64), np.zeros((1, 1)), 0.0, 1.0, 1, 2, 0.5)
    rows = np.array([0], dtype=i64), np.array([4], dtype=i64)
    rows_range(np.zeros((4, 3), dtype=np.int16), *rows)
    subsample_counts(np.zeros((4, 3), dtype=np.int16), *rows, 0, 1)
    band_noise(np.zeros(4, dtype=i64), np.ones((1, 1), dtype=np.float32),
               np.array([[0, 4]], dtype=i64), 32, 1)
    peak_pixels(np.array([[2]], dtype=i64), np.zeros(4, dtype=i64),
                np.ones((1, 1), dtype=np.float32), 32)
    ambient_level(np.zeros((2, 1)), np.array([0, 1], dtype=i64))
    covered_per_column(np.array([[2, -1]], dtype=i64), np.ones(3, dtype=np.bool_))
    subsample_tiles(np.zeros((4, 3), dtype=np.int16))
    tile_noise(np.zeros((1, 1, 2), dtype=np.int16), np.zeros(4, dtype=i64),
               np.zeros(2, dtype=np.float32), np.float32(1.0), np.float32(0.5))
    off_steps(np.array([[1]], dtype=i64), np.array([[1]], dtype=i64), 6, 1, 0.25)
