"""Compiled per-column loops of line identity (numba, ``nopython``).

Line identity works column by column on a few lines (K <= 16) and a few peaks (M <= K + 4):
both greedy matchings, the visibility prior's count of lines missing without a reason and
the continuity reference (the cheapest alignment is in
:mod:`atris_node.pipeline.alignment_kernels`). As numpy vector steps these were hundreds
of small array operations per map (about 3 ms at 640x400); here one pass per column (about
0.5 ms in all). Each function is the kernel of one of :mod:`atris_node.pipeline.peaks` or
:mod:`atris_node.pipeline.identity`, which check the arguments, document the method and are
what the rest of the node calls.

Types: rows, lines and indices int64 (-1 = none), costs and ranges float64. Costs are sums
of whole and half pixels, exact in float64, so the order of the sums does not change a
comparison. Every kernel has explicit signatures: it is compiled at import, or loaded from
numba's cache next to this file (``__pycache__``, or ``NUMBA_CACHE_DIR``), so no map waits
for the compiler; :func:`warm_up` also does the first-call argument typing. With
``NUMBA_DISABLE_JIT=1`` they run as plain Python (slow, for debugging). A helper called
once per column or path that neither allocates nor keeps an array is compiled without
reference counting (:data:`uncounted`, also used by the rival test and the alignment):
a counted call increments and decrements each array argument's count, and so does taking
a column as a view (``a[:, c]``), which the per-column loops avoid by copying.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel, uncounted
from atris_node.pipeline.selection import insert_sorted, kth, median

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]

_I1 = "int64[:]"
_I2 = "int64[:, :]"
_F1 = "float64[:]"
_F2 = "float64[:, :]"


@kernel(f"{_I2}({_I2}, {_I1}, {_I1}, {_I1})")
def assign_down(peaks: IntArray, lo: IntArray, hi: IntArray, line: IntArray) -> IntArray:
    """(K, W) by line: each line in image order takes the first peak below the previous
    line's inside its band ``[lo, hi)``; ``peaks`` (M, W) sorted down (distinct rows),
    -1 at the end."""
    k_count, (m_count, width) = lo.size, peaks.shape
    out = np.full((k_count, width), -1, dtype=np.int64)
    for c in range(width):
        if peaks[0, c] < 0:
            continue  # no peak (the padding is last): no line takes one
        last, start = -1, 0
        for k in range(k_count):
            for m in range(start, m_count):
                p = peaks[m, c]
                if p < 0 or p >= hi[k]:
                    break  # the padding, or past the band: no later peak fits
                if p > last and p >= lo[k]:
                    out[line[k], c] = p
                    last, start = p, m + 1
                    break
    return out


@kernel(f"{_I2}({_I2}, {_I1}, {_I1}, {_I1})")
def assign_up(peaks: IntArray, lo: IntArray, hi: IntArray, line: IntArray) -> IntArray:
    """(K, W) by line: as :func:`assign_down` from the bottom line up, each line taking
    the lowest peak above the next line's. The last peak is the one before the padding
    (found from the top: a column holds a few peaks, the padding most of ``M``)."""
    k_count, (m_count, width) = lo.size, peaks.shape
    out = np.full((k_count, width), -1, dtype=np.int64)
    for c in range(width):
        below, end = np.iinfo(np.int64).max, 0
        while end < m_count and peaks[end, c] >= 0:
            end += 1
        end -= 1  # the last peak before the padding
        if end < 0:
            continue  # no peak: no line takes one
        for k in range(k_count - 1, -1, -1):
            for m in range(end, -1, -1):
                p = peaks[m, c]
                if p < lo[k]:
                    break  # above the band: no earlier peak fits
                if p < below and p < hi[k]:
                    out[line[k], c] = p
                    below, end = p, m - 1
                    break
    return out


@kernel()
def _line_terms(cot_alpha: FloatArray, geometry: FloatArray, order: IntArray) -> FloatArray:
    """(2, K) per line in image ``order``: f·cot α and the row at infinite range,
    cy + f·cot α (px), the terms of :func:`_unexplained_column` that do not depend on the
    column (taken once per call of a kernel, the same sums to the bit)."""
    out = np.empty((2, order.size))
    for k in range(order.size):
        out[0, k] = geometry[0] * cot_alpha[order[k]]
        out[1, k] = geometry[1] + out[0, k]
    return out


@uncounted
def _unexplained_column(rows: IntArray, c: int, terms: FloatArray, geometry: FloatArray,
                        ground_range_m: FloatArray, order: IntArray, z: FloatArray) -> int:
    """:func:`unexplained` of one column: ``rows`` (K,) by line, ``c`` its column of
    ``ground_range_m``; ``terms`` of :func:`_line_terms`; ``z`` (K,) scratch. One pass down
    the lines: at each line with a finite range, the missing lines since the one before
    (``up``) take the range of the nearer of the two in lines (the nearer range on a tie),
    unless they are hidden (:func:`_hidden`); the missing lines after the last one take
    its range."""
    k_count = order.size
    cy_px, height_px, z_max_m = geometry[1], geometry[2], geometry[4]
    range_px = geometry[0] * geometry[3]  # f·b: z = f·b / disparity
    count, up, pending = 0, -1, False
    for k in range(k_count):
        row = rows[order[k]]
        if row < 0:
            pending = True
            continue
        den = terms[0, k] - (row - cy_px)
        z[k] = range_px / den if den > 0 else np.inf
        if not np.isfinite(z[k]):
            continue
        if pending:
            for q in range(up + 1, k):
                line = order[q]
                if rows[line] >= 0:
                    continue
                if (up >= 0 and k - up == 2 and _hidden(z[up], z[k], row, q, terms, range_px)
                        and _nearest_below(rows, k, z[k], terms, cy_px, range_px, order)):
                    continue
                gap_up = q - up if up >= 0 else 3 * k_count
                near = z[up] if gap_up < k - q or (gap_up == k - q and z[up] <= z[k]) else z[k]
                count += (_seen_at(near, q, line, c, terms, range_px, height_px, z_max_m,
                                   ground_range_m)
                          and not _masked(rows, near, q, terms, range_px, geometry[5], order))
            pending = False
        up = k
    if pending and up >= 0:
        for q in range(up + 1, k_count):
            line = order[q]
            if rows[line] < 0:
                count += (_seen_at(z[up], q, line, c, terms, range_px, height_px, z_max_m,
                                   ground_range_m)
                          and not _masked(rows, z[up], q, terms, range_px, geometry[5], order))
    return count


@uncounted
def _masked(rows: IntArray, near: float, q: int, terms: FloatArray, range_px: float,
            masked_px: float, order: IntArray) -> bool:
    """True when the missing line at image position q, at range ``near``, would lie
    within ``masked_px`` rows of a stripe seen of a line whose sheet is as near parallel
    to its own (their stripes within ``masked_px`` on every surface, but MERGED_PX or
    more apart): one maximum is kept within the peak search's separation, so its stripe
    may be in that peak. Two sheets
    0.48 deg apart, 3.3 px: the stripe on a dark wall at 2.96 m kept one peak of the
    pair, and the identity that read it as the upper line at 16 m (the lower line's
    absence explained by the range) won over the truth (the upper line's absence
    unexplained), a false free."""
    if masked_px <= 0.0:
        return False
    row = terms[1, q] - range_px / near
    for j in range(order.size):
        seen = rows[order[j]]
        apart = abs(terms[0, j] - terms[0, q])
        if (j != q and seen >= 0 and MERGED_PX <= apart < masked_px
                and abs(seen - row) < masked_px):
            return True
    return False


#: px; the stripes of two sheets nearer than this on every surface merge into one maximum
#: whose row lies between theirs (one row with a lower one on each side is needed for
#: two): that peak is no one line's, and the line missing beside it is not masked (its
#: absence stays unexplained, the merged peak ambiguous). Masked too, two sheets 0.24 deg
#: apart (1.6 px) were read at the merged peak's row, 5 % short in every sector-frame.
MERGED_PX = 2.0


#: px; a missing line is hidden by a nearer surface below it only where its row on the
#: farther surface lies this far below the nearer one's row: a comb whose lower part is
#: taken one line low leaves the line it skips on exactly the row of the stripe the next
#: line took (the stripe may be that line itself: no explanation), a row off by rounding
HIDDEN_PX = 2.0


@uncounted
def _hidden(z_up: float, z_low: float, row_low: int, q: int, terms: FloatArray,
            range_px: float) -> bool:
    """True when a missing line (image position q) between a line seen at range ``z_up``
    above it and one seen nearer, at ``z_low`` on row ``row_low``, below it is hidden by
    the nearer surface: it passes over that surface's top, and its row on the farther one
    lies HIDDEN_PX or more below ``row_low``, where the nearer surface stands before it (a low box
    before a wall: the line over the box's top meets the wall behind the box; identities
    that put the box's one lit line at the wall's range instead leave the line below it
    unexplained, and gave 2.30 m for a box at 1.54 m). The caller asks it only for one
    line missing between two seen ones: where several are, the column is sparse, and
    explaining each line that a nearer hypothesis skips would let its comb be put
    nearer at no cost (a column holding two of eight lines, the others under another
    unit's light, then had a rival in every wall column of two_units_nonorthogonal:
    27 of 32 sector-frames INVALID instead of 14)."""
    return z_low < z_up and terms[1, q] - range_px / z_up >= row_low + HIDDEN_PX


@uncounted
def _nearest_below(rows: IntArray, k: int, z_k: float, terms: FloatArray, cy_px: float,
                   range_px: float, order: IntArray) -> bool:
    """True when no line below image position k is seen farther than ``z_k``: a surface
    that hides a line from the camera stands in front of everything below it (two
    near-parallel sheets merged into one stripe on a box, the box's lines 1.46 m away
    below it: the line above the merged stripe taken for the next one, at 0.83 m, with
    the line over it called hidden, was a near phantom)."""
    for j in range(k + 1, order.size):
        row = rows[order[j]]
        if row < 0:
            continue
        den = terms[0, j] - (row - cy_px)
        if den > 0 and range_px / den > z_k:
            return False
    return True


@uncounted
def _seen_at(near: float, q: int, line: int, c: int, terms: FloatArray, range_px: float,
             height_px: float, z_max_m: float, ground_range_m: FloatArray) -> bool:
    """True when ``line`` (image position q) would be seen at range ``near`` (m) in
    column c: within z_max, above the ground and inside the image."""
    if near <= z_max_m and near < ground_range_m[line, c]:
        row = terms[1, q] - range_px / near
        return 0 <= row < height_px
    return False


@kernel(f"int64[:]({_I2}, {_F1}, {_F1}, {_F2}, {_I1})")
def unexplained(rows: IntArray, cot_alpha: FloatArray, geometry: FloatArray,
                ground_range_m: FloatArray, order: IntArray) -> IntArray:
    """(n,) unassigned lines per column that should be seen at the range of the nearest
    assigned line in image order (``order``: lines top first; the nearer range on a tie):
    above the ground range, inside the image and within z_max. ``rows`` (K, n) by line,
    ``ground_range_m`` (K, n) m; ``geometry`` (focal px, cy px, height px, baseline m,
    z_max m)."""
    out = np.zeros(rows.shape[1], dtype=np.int64)
    z = np.empty(order.size)
    terms = _line_terms(cot_alpha, geometry, order)
    for c in range(rows.shape[1]):
        out[c] = _unexplained_column(rows[:, c], c, terms, geometry, ground_range_m, order, z)
    return out


@uncounted
def _sorted_column(peaks: IntArray, c: int, out: IntArray) -> int:
    """:func:`_sorted_peaks` of column c of ``peaks`` (M, W)."""
    m = 0
    for j in range(peaks.shape[0]):
        p = peaks[j, c]
        if p >= 0:
            insert_sorted(out, m, p)
            m += 1
    return m


@kernel()
def _sorted_peaks(peaks: IntArray, out: IntArray) -> int:
    """The peaks >= 0 into ``out``, ascending (insertion sort; M is small); their count."""
    m = 0
    for p in peaks:
        if p >= 0:
            insert_sorted(out, m, p)
            m += 1
    return m


#: a span of whole values at most this many times their count (plus a few) is counted
#: over; a wider one is selected from (:func:`_median_of_whole`)
_SPAN_PER_VALUE = 4


@kernel()
def _short_span(values: FloatArray) -> tuple[float, int]:
    """The least of (n,) whole-number values (n > 0) and their span in whole numbers, 0
    when it is too wide to count over."""
    low, high = values[0], values[0]
    for v in values:
        low, high = min(low, v), max(high, v)
    span = int(high - low) + 1
    return low, (span if span <= _SPAN_PER_VALUE * values.size + 64 else 0)


@kernel()
def _counted_middle(values: FloatArray, low: float, span: int) -> tuple[float, float]:
    """The values of rank n // 2 - 1 (NaN for n = 1) and n // 2 (0-based) of (n,)
    whole-number values from ``low`` over ``span`` whole numbers, by counting them."""
    counts = np.zeros(span, dtype=np.int64)
    for v in values:
        counts[int(v - low)] += 1
    upper_rank = values.size // 2
    lower, upper = np.nan, np.nan
    seen = 0
    for i in range(span):
        seen += counts[i]
        if np.isnan(lower) and upper_rank > 0 and seen >= upper_rank:
            lower = low + i
        if seen > upper_rank:
            upper = low + i
            break
    return lower, upper


@kernel()
def _median_of_whole(values: FloatArray) -> float:
    """``np.median`` of (n,) whole-number values (rows; n > 0), to the bit: by counting
    them over their span where it is short (a line's rows across the image lie within a
    few hundred rows: O(n + span), without a selection's data-dependent branches), else
    by :func:`atris_node.pipeline.selection.median`. The mean of the middle two (even n)
    is numpy's (a + b) / 2."""
    low, span = _short_span(values)
    if span == 0:
        return median(values)
    lower, upper = _counted_middle(values, low, span)
    return upper if values.size % 2 else (lower + upper) / 2


@kernel()
def _upper_middle_of_whole(values: FloatArray) -> float:
    """The upper median (rank n // 2) of (n,) whole-number values (n > 0), as
    :func:`_median_of_whole` takes it (else :func:`atris_node.pipeline.selection.kth`)."""
    low, span = _short_span(values)
    if span == 0:
        return kth(values, values.size // 2)
    return _counted_middle(values, low, span)[1]


@kernel(f"float64[:, :]({_I2}, boolean[:, :], int64, int64, int64)")
def continuity_reference(rows: IntArray, good: npt.NDArray[np.bool_], block: int,
                         min_block: int, min_line: int) -> FloatArray:
    """(K, W) per line: the upper median of the ``good`` rows in each block of ``block``
    columns with at least ``min_block`` of them; elsewhere the median of all the line's
    good rows when there are at least ``min_line``; inf where neither."""
    k_count, width = rows.shape
    out = np.empty((k_count, width))
    values = np.empty(width)
    kept = np.empty(block)
    starts = np.empty((width + block - 1) // block + 1, dtype=np.int64)
    for k in range(k_count):
        # the good rows in column order, once (without a branch: written always, kept
        # when good); block b's are values[starts[b]:starts[b + 1]]
        n = 0
        for b, lo in enumerate(range(0, width, block)):
            starts[b] = n
            for c in range(lo, min(lo + block, width)):
                values[n] = rows[k, c]
                n += good[k, c]
        starts[-1] = n
        line = np.nan  # taken when a block needs it
        for b, lo in enumerate(range(0, width, block)):
            hi = min(lo + block, width)
            m = 0
            for s in range(starts[b], starts[b + 1]):
                p = values[s]
                i = m
                while i > 0 and kept[i - 1] > p:
                    kept[i] = kept[i - 1]
                    i -= 1
                kept[i] = p
                m += 1
            if m < min_block and np.isnan(line):
                line = _median_of_whole(values[:n]) if n >= min_line else np.inf
            out[k, lo:hi] = kept[m // 2] if m >= min_block else line
    return out


@kernel()
def _continuity_cost(rows: IntArray, differ: npt.NDArray[np.bool_], ref: FloatArray,
                     c: int) -> float:
    """Summed distance (px) of column c's differing assigned rows to their line's
    reference; inf when one of them has no reference (continuity cannot judge)."""
    total = 0.0
    for k in range(rows.shape[0]):
        if differ[k, c] and rows[k, c] >= 0:
            if not np.isfinite(ref[k, c]):
                return np.inf
            total += abs(rows[k, c] - ref[k, c])
    return total


@kernel(f"Tuple((int64[:, :], int64[:], boolean[:], float64[:, :], int64[:]))({_I2}, {_I1}, "
      f"{_I1}, {_I1}, int64, boolean, boolean, {_F1}, {_F1}, {_F2}, {_I1}, int64, int64, int64)")
def greedy_identity(peaks: IntArray, lo: IntArray, hi: IntArray, line: IntArray, sep: int,
                    aligned: bool, has_prior: bool, cot_alpha: FloatArray,
                    geometry: FloatArray, ground_range_m: FloatArray, image_order: IntArray,
                    block: int, min_block: int, min_line: int
                    ) -> tuple[IntArray, IntArray, npt.NDArray[np.bool_], FloatArray, IntArray]:
    """The greedy identity of :func:`atris_node.pipeline.identity.identify_lines`: (K, W)
    rows by line (-1 = none), (W,) ambiguous samples, (W,) columns where the two greedy matchings
    differ and, with ``aligned``, the (K, W) continuity reference of the columns where
    they agree ((0, 0) without), and (W,) the prior's count of the rows' lines missing
    without a reason where it was taken (-1 elsewhere). Bands ``[lo, hi)`` and their
    ``line`` in image order; the prior as :func:`unexplained` takes it, used only with
    ``has_prior``."""
    down = assign_down(peaks, lo, hi, line)
    up = assign_up(peaks, lo, hi, line)
    k_count, width = down.shape
    # the (K, W) passes go along the rows of the tables (contiguous), the per-column
    # work only where the matchings differ
    differ = np.empty((k_count, width), dtype=np.bool_)
    unsettled = np.zeros(width, dtype=np.bool_)
    for k in range(k_count):
        for c in range(width):
            differ[k, c] = down[k, c] != up[k, c]
            unsettled[c] |= differ[k, c]
    pick_up = np.zeros(width, dtype=np.bool_)
    pick_down = np.zeros(width, dtype=np.bool_)
    miss_down = np.full(width, -1, dtype=np.int64)
    miss_up = np.full(width, -1, dtype=np.int64)
    z = np.empty(k_count)
    terms = _line_terms(cot_alpha, geometry, image_order)
    down_c = np.empty(k_count, dtype=np.int64)  # columns copied, not viewed (no count)
    up_c = np.empty(k_count, dtype=np.int64)
    for c in range(width):
        if unsettled[c] and has_prior:
            for k in range(k_count):
                down_c[k], up_c[k] = down[k, c], up[k, c]
            miss_down[c] = _unexplained_column(down_c, c, terms, geometry, ground_range_m,
                                               image_order, z)
            miss_up[c] = _unexplained_column(up_c, c, terms, geometry, ground_range_m,
                                             image_order, z)
            pick_up[c], pick_down[c] = miss_up[c] < miss_down[c], miss_down[c] < miss_up[c]
    settled = ~unsettled | pick_up | pick_down
    chosen = np.empty((k_count, width), dtype=np.int64)
    good = np.empty((k_count, width), dtype=np.bool_)
    for k in range(k_count):
        for c in range(width):
            chosen[k, c] = up[k, c] if pick_up[c] else down[k, c]
            good[k, c] = (not differ[k, c] or settled[c]) and chosen[k, c] >= 0
    ref = continuity_reference(chosen, good, block, min_block, min_line)
    rows = down.copy()
    unsure = np.zeros(width, dtype=np.int64)
    missing = np.full(width, -1, dtype=np.int64)
    for c in range(width):
        if not unsettled[c]:
            continue
        use_up, use_down = pick_up[c], pick_down[c]
        if not settled[c]:
            cost_down = _continuity_cost(down, differ, ref, c)
            cost_up = _continuity_cost(up, differ, ref, c)
            use_up = np.isfinite(cost_up) and cost_up + sep <= cost_down
            use_down = np.isfinite(cost_down) and cost_down + sep <= cost_up
        for k in range(k_count):
            if use_up:
                rows[k, c] = up[k, c]
            elif not use_down and differ[k, c]:
                unsure[c] += down[k, c] >= 0
                rows[k, c] = -1
        if use_up:
            missing[c] = miss_up[c]
        elif use_down or unsure[c] == 0:  # the rows are those of the downward matching
            missing[c] = miss_down[c]
    certain = np.empty((0, 0))
    if aligned:
        for k in range(k_count):  # (good: the rows where both matchings agree)
            for c in range(width):
                good[k, c] = not differ[k, c] and down[k, c] >= 0
        certain = continuity_reference(down, good, block, min_block, min_line)
    return rows, unsure, unsettled, certain, missing


def warm_up() -> None:
    """Call every kernel once on a tiny input. The first call of a compiled function
    types its arguments (and imports what that needs), ~15 ms for the first kernel: done
    here, at configure time, the first map does not pay it. ~0.1 ms after the first time."""
    i64 = np.int64
    peaks = np.array([[1], [-1]], dtype=i64)
    lo, hi, line = np.array([0], dtype=i64), np.array([4], dtype=i64), np.array([0], dtype=i64)
    rows, ref = np.array([[-1]], dtype=i64), np.zeros((1, 1))
    cot, geometry, ground = np.array([0.1]), np.array([100.0, 2.0, 4.0, 0.1, 5.0, 0.0]), ref.copy()
    greedy_identity(peaks, lo, hi, line, 2, True, True, cot, geometry, ground, line, 32, 4, 16)
    unexplained(rows, cot, geometry, ground, line)
    continuity_reference(rows, np.ones((1, 1), dtype=np.bool_), 32, 4, 16)
    assign_down(peaks, lo, hi, line)
    assign_up(peaks, lo, hi, line)
