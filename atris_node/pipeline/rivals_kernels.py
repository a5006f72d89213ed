"""Compiled per-column rival test of line identity (numba, ``nopython``).

For one column, the lines (bands ``[lo, hi)`` in image order) and the sorted peaks are
aligned as in :mod:`atris_node.pipeline.identity` (match: distance to the continuity
reference plus BEYOND past z_max; skip; spare), by a forward table ``F[j, i]`` (the first
j lines against the first i peaks) and a backward table ``G[j, i]`` (lines j.. against
peaks i..). The cheapest assignment in which peak i is taken by line j then costs
``F[j, i] + match(j, i) + G[j + 1, i + 1]`` (a max-marginal), and the assignment itself
is read back from both tables. :func:`rivals` adds the visibility prior's cost of lines
missing without a reason to each, and reports every assigned peak for which an assignment
giving it another line costs less than the chosen one plus a margin. :func:`unique` runs
its rounds (without continuity, then with the :func:`continuity` reference of the anchored
columns), :func:`doubts` and :func:`stable` do the bookkeeping of
:mod:`atris_node.pipeline.rivals` around them, :func:`set_aside` drops peaks from the
columns. A column's test depends only on that column's peaks, rows, prior and reference:
a test already made with the same ones is not made again.

Types: rows and lines int64 (-1 = none), costs float64 px. Costs are sums of whole and
half pixels, exact in float64, so equal sums compare equal when the tables are read back.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel
from atris_node.pipeline.alignment_kernels import _in_bands, _inside, _missing
from atris_node.pipeline.identity_kernels import (
    _line_terms,
    _sorted_column,
    _unexplained_column,
    _upper_middle_of_whole,
    uncounted,
)
from atris_node.pipeline.selection import insert_sorted

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: rival paths per column whose prior count is kept (different candidates often read back
#: the same path: a comb shifted by one line is the rival of each of its peaks)
SEEN_PATHS = 16
#: the steps of a path through the tables: line takes peak, line skipped, peak spare
TAKE, SKIP, SPARE = 1, 2, 0


@uncounted
def _match(j: int, p: int, lo: IntArray, hi: IntArray, ref: FloatArray, beyond: FloatArray,
           beyond_px: float) -> float:
    """Cost (px) of line j (image order) taking the peak on row p; inf outside its band."""
    if not lo[j] <= p < hi[j]:
        return np.inf
    cost = abs(p - ref[j]) if np.isfinite(ref[j]) else 0.0
    return cost + (beyond_px if p >= beyond[j] else 0.0)


#: lines whose bands a row's bits can hold (:func:`_band_bits`)
_MAX_BITS = 63


@kernel()
def _band_bits(lo: IntArray, hi: IntArray) -> IntArray:
    """(max hi,) int64 per row >= 0 the bands ``[lo, hi)`` (image order) that hold it, as
    bits (bit j: band j; at most :data:`_MAX_BITS` bands)."""
    bits = np.zeros(max(hi.max(), 0) if hi.size else 0, dtype=np.int64)
    for j in range(lo.size):
        for p in range(max(lo[j], 0), max(hi[j], 0)):
            bits[p] |= np.int64(1) << j
    return bits


@uncounted
def _bits_of(p: int, band_bits: IntArray) -> int:
    """The bands that hold row ``p`` >= 0 as bits (:func:`_band_bits`)."""
    return band_bits[p] if p < band_bits.size else 0


@uncounted
def _unbounded(beyond: FloatArray) -> bool:
    """True when no line has a z_max row (``beyond`` all +inf): no match pays BEYOND."""
    for b in beyond:  # noqa: SIM110 (a generator does not compile)
        if b != np.inf:
            return False
    return True


@uncounted
def _unreferenced(ref: FloatArray) -> bool:
    """True when no line has a finite continuity reference in ``ref`` (K,)."""
    for r in ref:  # noqa: SIM110 (a generator does not compile)
        if np.isfinite(r):
            return False
    return True


@uncounted
def _plain_match(m: int, k_count: int, bits: IntArray, match: FloatArray) -> None:
    """The match costs (K, M) of :func:`_match` of the first ``m`` peaks, whose bands are
    ``bits`` (M,), where no line has a reference or a z_max row: 0 in the line's band,
    inf outside it."""
    for j in range(k_count):
        for i in range(m):
            match[j, i] = 0.0 if (bits[i] >> j) & 1 else np.inf


@uncounted
def _tables(m: int, k_count: int, match: FloatArray, costs: FloatArray, spare: FloatArray,
            f: FloatArray, g: FloatArray) -> None:
    """Fill the forward ``f`` and backward ``g`` tables (K + 1, M + 1) of one column from
    the ``match`` costs (K, M) of :func:`_match` (the step a cheapest path takes from a
    cell is read back from the values: :func:`_forward_step`, :func:`_backward_step`)."""
    skip_px = costs[0]
    f[0, 0] = 0.0
    for i in range(1, m + 1):
        f[0, i] = f[0, i - 1] + spare[i - 1]
    for j in range(1, k_count + 1):
        last = f[j - 1, 0] + skip_px  # the cell to the left, kept (not read back)
        f[j, 0] = last
        for i in range(1, m + 1):
            last = _least(f[j - 1, i - 1] + match[j - 1, i - 1], f[j - 1, i] + skip_px,
                          last + spare[i - 1])
            f[j, i] = last
    g[k_count, m] = 0.0
    for i in range(m - 1, -1, -1):
        g[k_count, i] = g[k_count, i + 1] + spare[i]
    for j in range(k_count - 1, -1, -1):
        last = g[j + 1, m] + skip_px
        g[j, m] = last
        for i in range(m - 1, -1, -1):
            last = _least(match[j, i] + g[j + 1, i + 1], g[j + 1, i] + skip_px,
                          last + spare[i])
            g[j, i] = last


@uncounted
def _least(a: float, b: float, c: float) -> float:
    """``min(a, b, c)`` of costs (never NaN): the first of the least, by two comparisons
    (about 10 % off the tables against the builtin)."""
    least = a
    if b < least:  # noqa: PLR1730 (min() compiles slower)
        least = b
    if c < least:  # noqa: PLR1730
        least = c
    return least


@uncounted
def _forward_step(j: int, i: int, f: FloatArray, match: FloatArray, skip_px: float) -> int:
    """The step (TAKE, SKIP, SPARE) of a cheapest path to F[j, i], j > 0: the first of
    them whose sum is the cell's value (a match before a skip before a spare on a tie;
    the sums are those :func:`_tables` took the minimum of, the same to the bit)."""
    if i == 0:
        return SKIP
    here = f[j, i]
    if here == f[j - 1, i - 1] + match[j - 1, i - 1]:
        return TAKE
    return SKIP if here == f[j - 1, i] + skip_px else SPARE


@uncounted
def _backward_step(j: int, i: int, m: int, g: FloatArray, match: FloatArray,
                   skip_px: float) -> int:
    """The step of a cheapest path from G[j, i], j < K (as :func:`_forward_step`)."""
    if i == m:
        return SKIP
    here = g[j, i]
    if here == match[j, i] + g[j + 1, i + 1]:
        return TAKE
    return SKIP if here == g[j + 1, i] + skip_px else SPARE


@uncounted
def _read_forward(j: int, i: int, column: IntArray, f: FloatArray, match: FloatArray,
                  skip_px: float, out: IntArray) -> None:
    """Rows (``out``, image order) the first j lines take on a cheapest path to F[j, i]."""
    while j > 0:
        step = _forward_step(j, i, f, match, skip_px)
        if step == TAKE:
            out[j - 1] = column[i - 1]
            j -= 1
            i -= 1
        elif step == SKIP:
            out[j - 1] = -1
            j -= 1
        else:
            i -= 1


@uncounted
def _read_backward(j: int, i: int, m: int, column: IntArray, g: FloatArray,
                   match: FloatArray, skip_px: float, out: IntArray) -> None:
    """Rows (``out``, image order) lines j.. take on a cheapest path from G[j, i]."""
    k_count = out.size
    while j < k_count:
        step = _backward_step(j, i, m, g, match, skip_px)
        if step == TAKE:
            out[j] = column[i]
            j += 1
            i += 1
        elif step == SKIP:
            out[j] = -1
            j += 1
        else:
            i += 1


@uncounted
def _chosen_cost(rows: IntArray, column: IntArray, m: int, lo: IntArray, hi: IntArray,
                 ref: FloatArray, beyond: FloatArray, costs: FloatArray,
                 spare: FloatArray, inside: BoolArray) -> float:
    """Cost (px) of the assignment ``rows`` (K, image order) in the alignment's terms;
    ``inside`` the rows in a band (:func:`_in_bands`)."""
    skip_px, beyond_px = costs[0], costs[2]
    total = 0.0
    taken = 0.0
    for j in range(lo.size):
        if rows[j] < 0:
            total += skip_px
        else:
            total += _match(j, rows[j], lo, hi, ref, beyond, beyond_px)
            taken += costs[1] if _inside(rows[j], inside) else 0.0
    for i in range(m):
        total += spare[i]
    return total - taken


@uncounted
def _known_count(seen: IntArray, seen_count: IntArray, n_seen: int, path: IntArray) -> int:
    """The count stored with ``path`` (K,) among the first ``n_seen`` rows of ``seen``, -1
    when it is not there."""
    for s in range(n_seen):
        same = True
        for k in range(path.size):
            if seen[s, k] != path[k]:
                same = False
                break
        if same:
            return seen_count[s]
    return -1


@uncounted
def _by_line(rows_image: IntArray, order: IntArray, out: IntArray) -> None:
    """Rows in image order -> rows by line (``out``)."""
    for k in range(order.size):
        out[order[k]] = rows_image[k]


@uncounted
def _peak_index(column: IntArray, m: int, row: int) -> int:
    """Index of ``row`` among the sorted peaks (-1 when absent)."""
    for i in range(m):
        if column[i] == row:
            return i
    return -1


@kernel("void(int64[:, :], int64[:], int64[:], int64[:], int64[:, :], int64[:, :], "
        "int64[:], float64[:, :], float64[:], float64, float64[:], boolean, "
        "float64[:], float64[:], float64[:, :], int64[:], int64[:], boolean[:])")
def rivals(peaks: IntArray, lo: IntArray, hi: IntArray, order: IntArray, rows: IntArray,
           ambiguous: IntArray, columns: IntArray, ref: FloatArray, beyond: FloatArray,
           margin: float, costs: FloatArray, has_prior: bool, cot_alpha: FloatArray,
           geometry: FloatArray, ground_range_m: FloatArray, image_order: IntArray,
           counted: IntArray, outranked: BoolArray) -> None:
    """:func:`atris_node.pipeline.rivals.unique_identity` on the given ``columns``.

    ``rows`` (K, W) by line is the chosen identity (never changed: a cheaper assignment is a
    rival like any other); ``ambiguous`` (K, W) by line (-1 where not) is set where the
    line's peak has a rival assignment (another line for it) within ``margin`` of the chosen
    total, to the line among the chosen and the rivals that is lowest in the image: the
    nearest range the peak may stand for. ``peaks`` (M, W) -1 padded; ``lo``, ``hi``,
    ``beyond`` (K,) and ``ref`` (K, W) in image order, ``order`` the line of each; ``costs``
    (skip, spare, beyond, unexplained) px; the prior as
    :func:`atris_node.pipeline.identity_kernels.unexplained` takes it, and ``counted`` (W,)
    its count of the chosen rows' missing lines per column where taken (-1 where not yet;
    filled in where this call takes it)."""
    k_count, m_count = lo.size, peaks.shape[0]
    column = np.empty(m_count, dtype=np.int64)
    spare = np.zeros(m_count)
    f = np.zeros((k_count + 1, m_count + 1))
    g = np.zeros((k_count + 1, m_count + 1))
    match = np.empty((k_count, m_count))
    image = np.empty(k_count, dtype=np.int64)
    other = np.empty(k_count, dtype=np.int64)
    line_rows = np.empty(k_count, dtype=np.int64)
    ref_c = np.empty(k_count)  # column c of ``ref`` (no view: a view is counted)
    z = np.empty(k_count)
    owner = np.empty(m_count, dtype=np.int64)
    seen = np.empty((SEEN_PATHS, k_count), dtype=np.int64)
    seen_count = np.empty(SEEN_PATHS, dtype=np.int64)
    spare_tables = np.zeros(m_count)  # the costs of the tables last filled
    m_tables = -1
    inside = _in_bands(lo, hi)
    terms = _line_terms(cot_alpha, geometry, image_order)
    # without a reference or a z_max row a match costs 0 in the line's band, inf outside
    # it: a column's match costs are its peaks' bands (as bits, for up to 63 lines)
    bitwise = k_count <= _MAX_BITS and _unbounded(beyond)
    band_bits = _band_bits(lo, hi) if bitwise else np.zeros(0, dtype=np.int64)
    bits_tables = np.zeros(m_count, dtype=np.int64)  # the peaks' bands of the last tables
    plain_tables = False  # whether the last tables' match costs were bands only
    for c in columns:
        n_seen = 0
        m = _sorted_column(peaks, c, column)
        for i in range(m):
            spare[i] = costs[1] if _inside(column[i], inside) else 0.0
        for k in range(k_count):
            image[k] = rows[order[k], c]
            ref_c[k] = ref[k, c]
        best = _chosen_cost(image, column, m, lo, hi, ref_c, beyond, costs, spare, inside)
        if best == 0.0 and costs[0] + costs[1] >= margin:
            # every line holds a peak in its band, no peak in a band is left over, nothing
            # past z_max, no continuity cost: another order-preserving assignment must skip
            # a line and leave a peak over, which costs more than the margin
            continue
        # the prior's count of the chosen lines missing without a reason is at most the
        # count of lines missing: taken only when a rival comes within that bound
        priced = not has_prior
        bound = best if priced else best + costs[3] * _missing(image)
        # the tables are those of the last column tested when its costs are these (the
        # neighbouring columns of a stripe mostly have the same bands for their peaks)
        same = m == m_tables
        for i in range(m):
            same &= spare[i] == spare_tables[i]
            spare_tables[i] = spare[i]
        plain = bitwise and _unreferenced(ref_c)
        if plain:  # the match costs are the peaks' bands: compared as bits
            same &= plain_tables
            for i in range(m):
                bits = _bits_of(column[i], band_bits)
                same &= bits == bits_tables[i]
                bits_tables[i] = bits
            if not same:
                _plain_match(m, k_count, bits_tables, match)
        else:
            for j in range(k_count):
                for i in range(m):
                    cost = _match(j, column[i], lo, hi, ref_c, beyond, costs[2])
                    same &= cost == match[j, i]
                    match[j, i] = cost
        plain_tables = plain
        if not same:
            _tables(m, k_count, match, costs, spare, f, g)
            m_tables = m
        owner[:] = -1
        for k in range(k_count):
            if image[k] >= 0:
                owner[_peak_index(column, m, image[k])] = k
        for i in range(m):
            if owner[i] < 0:
                continue
            for j in range(k_count - 1, -1, -1):  # the lowest line first: the nearest
                if j == owner[i] or not lo[j] <= column[i] < hi[j]:
                    continue
                through = f[j, i] + match[j, i] + g[j + 1, i + 1]
                if through >= bound + margin:
                    continue  # no assignment giving peak i to line j comes close
                if not priced:
                    if counted[c] < 0:
                        _by_line(image, order, line_rows)
                        counted[c] = _unexplained_column(line_rows, c, terms, geometry,
                                                         ground_range_m, image_order, z)
                    best += costs[3] * counted[c]
                    bound, priced = best, True
                    if through >= best + margin:
                        continue
                # outranking is judged on the exact price (pass 1, until the column is)
                ranking = outranked.size > 0 and not outranked[c]
                if has_prior:  # (the reads write every line's row)
                    _read_forward(j, i, column, f, match, costs[0], other)
                    other[j] = column[i]
                    _read_backward(j + 1, i + 1, m, column, g, match, costs[0], other)
                    if ranking or through + costs[3] * _missing(other) >= best + margin:
                        # the path's own count of lines missing without a reason decides
                        missing = _known_count(seen, seen_count, n_seen, other)
                        if missing < 0:  # a path not yet priced in this column
                            _by_line(other, order, line_rows)
                            missing = _unexplained_column(line_rows, c, terms, geometry,
                                                          ground_range_m, image_order, z)
                            if n_seen < SEEN_PATHS:
                                for k in range(k_count):  # (a row of ``seen`` is counted)
                                    seen[n_seen, k] = other[k]
                                seen_count[n_seen] = missing
                                n_seen += 1
                        through += costs[3] * missing
                if through < best + margin:
                    if ambiguous[order[owner[i]], c] < 0:
                        ambiguous[order[owner[i]], c] = order[max(j, owner[i])]
                    if not ranking:
                        break
                    if through < best - margin:
                        outranked[c] = True
                        break


@kernel("boolean[:, :](int64[:, :], int64, int64)")
def isolated(peaks: IntArray, reach: int, max_step: int) -> BoolArray:
    """(M, W) True for peaks with no peak within ``max_step`` rows in any of the ``reach``
    columns on either side: a stripe continues across columns, a noise maximum does not."""
    m_count, width = peaks.shape
    out = np.zeros((m_count, width), dtype=np.bool_)
    for c in range(width):
        for i in range(m_count):
            p = peaks[i, c]
            if p < 0:
                continue
            alone = True
            for d in range(-reach, reach + 1):
                n = c + d
                if d == 0 or n < 0 or n >= width:
                    continue
                for q in peaks[:, n]:
                    if q >= 0 and abs(q - p) <= max_step:
                        alone = False
                        break
                if not alone:
                    break
            out[i, c] = alone
    return out


@uncounted
def _block_median(row: IntArray, goods: IntArray, start: int, end: int, min_block: int,
                  kept: FloatArray) -> float:
    """The upper median of ``row`` in the good columns ``goods[start:end]`` (ascending),
    inf with fewer than ``min_block``; ``kept`` (end - start,) work space."""
    m = 0
    for s in range(start, end):
        insert_sorted(kept, m, np.float64(row[goods[s]]))
        m += 1
    return kept[m // 2] if m >= min_block else np.inf


@kernel()
def _line_median(row: IntArray, goods: IntArray, n_good: int, min_line: int,
                 values: FloatArray) -> float:
    """The upper median of ``row`` in all the good columns ``goods[:n_good]``, inf with
    fewer than ``min_line``; ``values`` (W,) work space."""
    for s in range(n_good):
        values[s] = row[goods[s]]
    return _upper_middle_of_whole(values[:n_good]) if n_good >= min_line else np.inf


@uncounted
def _bisect(goods: IntArray, n_good: int, c: int) -> int:
    """The first index of ``goods[:n_good]`` (ascending) whose column is >= c."""
    start, end = 0, n_good
    while start < end:
        mid = (start + end) // 2
        if goods[mid] < c:
            start = mid + 1
        else:
            end = mid
    return start


@uncounted
def _first_from(goods: IntArray, n_good: int, c: int, start: int) -> int:
    """The first index of ``goods[:n_good]`` (ascending) whose column is >= c: from
    ``start`` on when ``goods[start - 1]`` < c (columns taken in ascending order),
    else by bisection."""
    if start > 0 and goods[start - 1] >= c:
        return _bisect(goods, n_good, c)
    while start < n_good and goods[start] < c:
        start += 1
    return start


@kernel()
def _far_or_bridged(row: IntArray, c: int, left: int, right: int, bridge_px: float) -> float:
    """Column c's bridge between its nearest good columns ``left`` <= c <= ``right`` (-1 /
    W: none): the nearer one's row (the left one on a tie) when both exist and agree
    within ``bridge_px``, else inf; NaN when a side has none (the line's median decides)."""
    if left < 0 or right >= row.size:
        return np.nan
    row_l, row_r = np.float64(row[left]), np.float64(row[right])
    if abs(row_l - row_r) <= bridge_px:
        return row_l if c - left <= right - c else row_r
    return np.inf


@kernel()
def _held_columns(rows: IntArray) -> tuple[IntArray, IntArray]:
    """Per line of ``rows`` (K, W), the columns where it holds a row (>= 0), ascending:
    (K, W) with line k's in ``[k, :count[k]]``, and the (K,) ``count``."""
    k_count, width = rows.shape
    held = np.empty((k_count, width), dtype=np.int64)
    count = np.zeros(k_count, dtype=np.int64)
    for k in range(k_count):
        n = 0
        for c in range(width):  # without a branch: written always, kept when held
            held[k, n] = c
            n += rows[k, c] >= 0
        count[k] = n
    return held, count


@kernel()
def _medians_memo(k_count: int, width: int, block: int) -> tuple[FloatArray, IntArray]:
    """An empty memo of :func:`_continuity_columns`' medians for (K, W) rows: (K, B + 1)
    values and (K, B + 1) counts of the good rows each was taken from (-1: none yet), B
    the blocks of ``block`` columns."""
    n_blocks = (width + block - 1) // block
    return (np.full((k_count, n_blocks + 1), np.nan),
            np.full((k_count, n_blocks + 1), -1, dtype=np.int64))


@uncounted
def _lone_stripe(rows: IntArray, c: int) -> bool:
    """True when column c of ``rows`` (K, W) holds one line's row at most: a stripe
    alone in its column, which every line explains at its own range."""
    held = 0
    for k in range(rows.shape[0]):
        held += rows[k, c] >= 0
    return held <= 1


@kernel()
def _continuity_columns(rows: IntArray, anchored: BoolArray, held: IntArray,
                        n_held: IntArray, medians: FloatArray, taken: IntArray,
                        columns: IntArray, reach: int, block: int, min_block: int,
                        min_line: int, bridge_px: float, median_px: float) -> FloatArray:
    """:func:`continuity` as (K, n): the reference of each line in each of the (n,)
    ``columns``; ``held``, ``n_held`` the columns where each line holds a row
    (:func:`_held_columns`). Each line's good columns (anchored, a row >= 0) are listed
    once, from those it holds; a column's nearest good ones on both sides are found in
    that list.

    ``medians``, ``taken``: the memo of :func:`_medians_memo`, in place: per line each
    block's median (B blocks) and the line's median (last), and the count of good rows
    each was taken from. Between calls on one memo the rows are the same and the
    anchored columns only grow, so a line or a block with as many good rows as when
    its median was taken has the same ones: the median is not taken again."""
    k_count, width = rows.shape
    n = columns.size
    n_blocks = medians.shape[1] - 1
    out = np.full((k_count, n), np.inf)
    far = np.zeros((k_count, n), dtype=np.bool_)
    off = np.zeros(n, dtype=np.bool_)
    goods = np.empty(width, dtype=np.int64)
    checked = np.empty(n_blocks, dtype=np.bool_)  # the blocks counted in this call
    values = np.empty(width)
    kept = np.empty(block)
    for k in range(k_count):
        row = rows[k]
        n_good = 0
        for s in range(n_held[k]):  # without a branch: written always, kept when good
            c = held[k, s]
            goods[n_good] = c
            n_good += anchored[c]
        if n_good == 0 and min_block > 0 and min_line > 0:  # no anchored row: no reference
            for i in range(n):
                far[k, i] = True
                off[i] |= row[columns[i]] >= 0
            continue
        checked[:] = False
        s = 0
        for i in range(n):
            c = columns[i]
            s = _first_from(goods, n_good, c, s)
            good = s < n_good and goods[s] == c
            before = goods[s - 1] if s > 0 else -1
            after = goods[s + good] if s + good < n_good else width
            left_gap = c - before if before >= 0 else reach + 1
            right_gap = after - c if after < width else reach + 1
            if left_gap <= reach and left_gap <= right_gap:
                out[k, i] = row[before]
            elif right_gap <= reach:
                out[k, i] = row[after]
            else:
                b = c // block
                if not checked[b]:
                    start = _bisect(goods, n_good, b * block)
                    end = _bisect(goods, n_good, min(b * block + block, width))
                    if taken[k, b] != end - start:
                        medians[k, b] = _block_median(row, goods, start, end, min_block, kept)
                        taken[k, b] = end - start
                    checked[b] = True
                ref = medians[k, b]
                if not np.isfinite(ref):
                    ref = _far_or_bridged(row, c, c if good else before, c if good else after,
                                          bridge_px)
                if np.isnan(ref) and _lone_stripe(rows, c):
                    ref = np.inf  # a line's rows elsewhere cannot tell a lone stripe's line
                elif np.isnan(ref):
                    if taken[k, n_blocks] != n_good:
                        medians[k, n_blocks] = _line_median(row, goods, n_good, min_line,
                                                            values)
                        taken[k, n_blocks] = n_good
                    line = medians[k, n_blocks]
                    ref = line
                    far[k, i] = True
                    off[i] |= row[c] >= 0 and abs(row[c] - line) > median_px
                out[k, i] = ref
    for i in range(n):
        c = columns[i]
        tied = False  # some line the column holds has a reference ...
        loose = False  # ... and none has none
        for k in range(k_count):
            if far[k, i] and off[i]:
                out[k, i] = np.inf
            tied |= rows[k, c] >= 0 and np.isfinite(out[k, i])
            loose |= rows[k, c] >= 0 and not np.isfinite(out[k, i])
        tied &= not loose
        for k in range(k_count):
            if far[k, i] and rows[k, c] < 0 and not tied:
                out[k, i] = np.inf
    return out


@kernel("float64[:, :](int64[:, :], boolean[:], int64[:], int64, int64, int64, int64, "
        "float64, float64)")
def continuity(rows: IntArray, anchored: BoolArray, columns: IntArray, reach: int, block: int,
               min_block: int, min_line: int, bridge_px: float, median_px: float
               ) -> FloatArray:
    """The continuity reference of :func:`atris_node.pipeline.rivals._reference` in the
    given ``columns``: (K, W) per line, from its anchored rows (``anchored`` (W,) and a
    row >= 0), the first of

    - the row in the nearest anchored column within ``reach`` columns (not the column
      itself; the left one on a tie);
    - the upper median of the anchored rows in the column's block of ``block`` columns
      (at least ``min_block`` of them);
    - where there are anchored rows on both sides (the column's own counts for both): the
      nearer one's row (the left one on a tie) when the two agree within ``bridge_px``,
      else inf;
    - the upper median of all the line's anchored rows (at least ``min_line``; inf
      otherwise), and inf for every line of a column where some line of this case has a
      row more than ``median_px`` off (or no) median, or that holds one line's row at
      most (:func:`_lone_stripe`: a stripe alone in its column lies on every line's
      median row at some range, and the medians are other surfaces' rows); and inf for
      a line the column does not hold unless every line it holds has a reference (the
      median of a left-out line only prices a rival that gives it a peak; with no held
      line tied to a surface it would decide alone: a far comb with its lowest line
      lost was settled one line low, 2.6 m for 3.66 m, by line 0's median from nearer
      surfaces; and with a held stripe untied, between anchors that disagree, it prices
      only the rival that gives that stripe the left-out line, while the chosen line
      pays nothing: a hanging sphere's one stripe at 4.10 m, the ground lines below it
      tied to their neighbours, was settled one line down at 1.45 m by line 0's median
      from a pole and boxes 1.3-1.4 m away).

    inf in the other columns. The block and line medians are taken only where they are
    needed."""
    out = np.full(rows.shape, np.inf)
    held, n_held = _held_columns(rows)
    medians, taken = _medians_memo(rows.shape[0], rows.shape[1], block)
    at = _continuity_columns(rows, anchored, held, n_held, medians, taken, columns, reach,
                             block, min_block, min_line, bridge_px, median_px)
    for i in range(columns.size):
        for k in range(rows.shape[0]):
            out[k, columns[i]] = at[k, i]
    return out


@kernel()
def _anchored(ambiguous: IntArray, anchored: BoolArray, again: IntArray) -> int:
    """Columns without an ambiguous line into ``anchored`` (W,), the others' indices into
    ``again`` (W,); their count."""
    k_count, width = ambiguous.shape
    anchored[:] = True
    for k in range(k_count):  # along the rows of ``ambiguous``
        for c in range(width):
            anchored[c] &= ambiguous[k, c] < 0
    n = 0
    for c in range(width):  # without a branch: written always, kept when not anchored
        again[n] = c
        n += not anchored[c]
    return n


@uncounted
def _still_open(ambiguous: IntArray, anchored: BoolArray, tested: IntArray, n_tested: int,
                columns: IntArray, n: int) -> int:
    """After a round: the ``tested`` columns (``[:n_tested]``) without an ambiguous line
    anchored (``anchored`` (W,)), and the first ``n`` of ``columns`` (ascending, not
    anchored before the round) kept in place where still not anchored; their count."""
    for i in range(n_tested):
        c = tested[i]
        for k in range(ambiguous.shape[0]):
            if ambiguous[k, c] >= 0:
                break
        else:
            anchored[c] = True
    kept = 0
    for i in range(n):  # without a branch: written always, kept when not anchored
        c = columns[i]
        columns[kept] = c
        kept += not anchored[c]
    return kept


@uncounted
def _off_reference(rows: IntArray, by_line: FloatArray, c: int, i: int, near_px: float
                   ) -> bool:
    """True when none of the chosen rows of column c (``rows`` (K, W) by line) lies
    within ``near_px`` of its reference, column i of ``by_line`` (K, n): no stripe of the
    column continues an anchored one, the reference is other surfaces' rows, and a rival
    farther from it is the lesser of two misfits, not a worse fit."""
    for k in range(rows.shape[0]):
        if rows[k, c] >= 0 and abs(rows[k, c] - by_line[k, i]) <= near_px:
            return False
    return True


@uncounted
def _same_reference(ref: FloatArray, by_line: FloatArray, order: IntArray, c: int,
                    i: int) -> bool:
    """True when column c of ``ref`` (K, W, image ``order``) is column i of ``by_line``
    (K, n)."""
    for k in range(order.size):  # noqa: SIM110 (a generator does not compile)
        if ref[k, c] != by_line[order[k], i]:
            return False
    return True


@kernel("void(int64[:, :], int64[:], int64[:], int64[:], int64[:, :], int64[:, :], "
        "int64[:, :], boolean[:], boolean[:], float64[:], int64[:], float64[:], boolean, "
        "float64[:], float64[:], float64[:, :], int64[:], int64[:])")
def unique(peaks: IntArray, lo: IntArray, hi: IntArray, order: IntArray, rows: IntArray,
           ambiguous: IntArray, passed: IntArray, outranked: BoolArray, reuse: BoolArray,
           margins: FloatArray,
           spans: IntArray, costs: FloatArray, has_prior: bool, cot_alpha: FloatArray,
           geometry: FloatArray, ground_range_m: FloatArray, image_order: IntArray,
           counted: IntArray) -> None:
    """The rounds of :func:`atris_node.pipeline.rivals.unique_identity`, in place on
    ``rows`` (K, W) by line (every sample with a rival set to -1) and ``ambiguous`` (K, W)
    (-1 on entry; the nearest rival line of each removed sample).

    Pass 1 (no continuity) tests every column where a line holds a peak, except the
    ``reuse`` (W,) ones, which take their pass-1 result from ``passed`` (K, W): the rival
    test of a column without continuity depends only on its own peaks, rows and prior, so
    a column whose peaks and rows are those of an earlier identity has that identity's
    result. ``passed`` receives this pass-1 result of every column. Then at most
    ``spans[4]`` rounds of :func:`rivals` on the columns not anchored yet, with the
    :func:`continuity` reference of the anchored ones (``spans[:4]``: reach, block,
    min_block, min_line; ``margins``: rival margin, bridge px, median px), until a round
    anchors nothing new. A column whose reference is the one of its last test is not
    tested again (the test is a function of the column's peaks, rows, prior and
    reference), nor is a column pass 1 found ``outranked`` (W,; filled in by pass 1 except
    in the ``reuse`` columns, which keep theirs): a rival cheaper than its chosen identity
    by the margin, which continuity may not overrule. Bands ``lo``, ``hi`` and ``order``
    and the prior as :func:`rivals` takes them; ``counted`` (W,) the prior's count of the
    lines of ``rows`` missing without a reason where known (-1 elsewhere; filled in where
    taken)."""
    k_count, width = rows.shape
    margin, bridge_px, median_px = margins[0], margins[1], margins[2]
    reach, block, min_block, min_line, rounds = spans[0], spans[1], spans[2], spans[3], spans[4]
    beyond = np.full(k_count, np.inf)
    columns = np.empty(width, dtype=np.int64)
    n = 0
    for c in range(width):
        if reuse[c]:
            for k in range(k_count):  # (columns as views would be counted)
                ambiguous[k, c] = passed[k, c]
            continue
        outranked[c] = False
        for k in range(k_count):
            if rows[k, c] >= 0:
                columns[n] = c
                n += 1
                break
    ref = np.full((k_count, width), np.inf)  # the reference of each column's last test
    rivals(peaks, lo, hi, order, rows, ambiguous, columns[:n], ref, beyond, margin, costs,
           has_prior, cot_alpha, geometry, ground_range_m, image_order, counted, outranked)
    passed[:, :] = ambiguous
    no_rank = np.zeros(0, dtype=np.bool_)
    anchored = np.empty(width, dtype=np.bool_)
    again = np.empty(width, dtype=np.int64)
    # the columns not anchored (ascending), kept up to date by each round: a round tests
    # only such columns, and only its tested ones change (an anchored one stays anchored)
    n = _anchored(ambiguous, anchored, columns)
    held, n_held = _held_columns(rows)  # rows do not change in the rounds
    medians, taken = _medians_memo(k_count, width, block)
    left = -1
    for _ in range(rounds):
        if n in (0, left):
            break  # all anchored, or the last round anchored nothing new
        left = n
        by_line = _continuity_columns(rows, anchored, held, n_held, medians, taken,
                                      columns[:n], reach, block, min_block, min_line,
                                      bridge_px, median_px)
        n_again = 0
        for i in range(n):  # each was tested in the last round (or pass 1)
            c = columns[i]
            if outranked[c] or _same_reference(ref, by_line, order, c, i):
                continue  # the same test again: the same result
            if _off_reference(rows, by_line, c, i, bridge_px):
                continue  # another surface's rows: they cannot settle this column's tie
            for k in range(k_count):
                ref[k, c] = by_line[order[k], i]
                ambiguous[k, c] = -1
            again[n_again] = c
            n_again += 1
        rivals(peaks, lo, hi, order, rows, ambiguous, again[:n_again], ref, beyond, margin,
               costs, has_prior, cot_alpha, geometry, ground_range_m, image_order, counted,
               no_rank)
        n = _still_open(ambiguous, anchored, again, n_again, columns, n)
    for k in range(k_count):
        for c in range(width):
            if ambiguous[k, c] >= 0:
                rows[k, c] = -1


@kernel()
def _lowest_band(row: int, lo: IntArray, hi: IntArray, order: IntArray) -> int:
    """The line lowest in the image whose band ``[lo, hi)`` (image ``order``) holds
    ``row``, -1 if none."""
    for k in range(lo.size - 1, -1, -1):
        if lo[k] <= row < hi[k]:
            return order[k]
    return -1


@kernel()
def _rivalled(p: int, first: IntArray, nearest: IntArray, c: int) -> bool:
    """True when a line of ``first`` whose sample in column c has a rival (``nearest``)
    holds the row ``p`` there."""
    for k in range(first.shape[0]):  # noqa: SIM110 (a generator does not compile)
        if nearest[k, c] >= 0 and first[k, c] == p:
            return True
    return False


@kernel()
def _held(peaks: IntArray, rows: IntArray, i: int, c: int) -> bool:
    """True when some line of ``rows`` holds the peak ``peaks[i, c]``."""
    for k in range(rows.shape[0]):  # noqa: SIM110 (a generator does not compile)
        if rows[k, c] >= 0 and rows[k, c] == peaks[i, c]:
            return True
    return False


@kernel("Tuple((int64[:], int64[:], int64[:], int64[:]))(int64[:, :], int64[:, :], "
        "int64[:, :], int64[:, :], int64[:], int64[:], int64[:], int64[:])")
def doubts(peaks: IntArray, first: IntArray, rows: IntArray, nearest: IntArray,
           unsure: IntArray, lo: IntArray, hi: IntArray, order: IntArray
           ) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """The doubts of :func:`atris_node.pipeline.rivals._unique`: (W,) ``unsure`` plus the
    samples of ``first`` (K, W) the rival test removed from ``rows``, and (n,) row, column
    and line of every doubt: first each removed sample (line by line, column by column)
    with its ``nearest`` rival line, then each peak of ``peaks`` (M, W) no line holds in
    a column with ``unsure`` peaks and no rival (peak slot by slot, column by column) with
    the lowest band ``[lo, hi)`` (image ``order``) that holds it (none: left out)."""
    k_count, width = rows.shape
    m_count = peaks.shape[0]
    removed = np.zeros(width, dtype=np.int64)
    unsure_at = np.empty(width, dtype=np.int64)
    n_rival, n_unsure = 0, 0
    for k in range(k_count):  # along the rows of the (K, W) tables
        for c in range(width):
            removed[c] += int(first[k, c] >= 0) - int(rows[k, c] >= 0)
            n_rival += nearest[k, c] >= 0
    out = np.empty(width, dtype=np.int64)
    for c in range(width):
        out[c] = unsure[c] + max(removed[c], 0)
        unsure_at[n_unsure] = c  # without a branch: written always, kept when unsure
        n_unsure += unsure[c] > 0
    lone = np.full((m_count, n_unsure), -1, dtype=np.int64)
    n_lone = 0
    for i in range(m_count):
        for u in range(n_unsure):
            c = unsure_at[u]
            p = peaks[i, c]
            if p >= 0 and not _rivalled(p, first, nearest, c) and not _held(peaks, rows, i, c):
                lone[i, u] = _lowest_band(p, lo, hi, order)
                n_lone += lone[i, u] >= 0
    row = np.empty(n_rival + n_lone, dtype=np.int64)
    col = np.empty(n_rival + n_lone, dtype=np.int64)
    line = np.empty(n_rival + n_lone, dtype=np.int64)
    n = 0
    for k in range(k_count):
        for c in range(width):
            if nearest[k, c] >= 0:
                row[n], col[n], line[n] = first[k, c], c, nearest[k, c]
                n += 1
    for i in range(m_count):
        for u in range(n_unsure):
            if lone[i, u] >= 0:
                row[n], col[n], line[n] = peaks[i, unsure_at[u]], unsure_at[u], lone[i, u]
                n += 1
    return out, row, col, line


@kernel("boolean[:, :](int64[:, :], boolean[:, :], int64[:, :])")
def strong_rows(peaks: IntArray, weak: BoolArray, rows: IntArray) -> BoolArray:
    """(K, W) True where a line of ``rows`` (K, W) holds a peak of ``peaks`` (M, W) that
    is not ``weak`` (M, W): the peak's own flag, looked up (each row >= 0 is one of its
    column's peaks)."""
    m_count = peaks.shape[0]
    k_count, width = rows.shape
    out = np.zeros((k_count, width), dtype=np.bool_)
    for k in range(k_count):
        for c in range(width):
            row = rows[k, c]
            if row < 0:
                continue
            for i in range(m_count):
                if peaks[i, c] == row:
                    out[k, c] = not weak[i, c]
                    break
    return out


@kernel("Tuple((int64[:, :], int64[:], int64[:], int64[:], int64[:]))(int64[:, :], "
        "int64[:, :], boolean[:, :], int64[:])")
def stable(rows: IntArray, alone: IntArray, held: BoolArray, position: IntArray
           ) -> tuple[IntArray, IntArray, IntArray, IntArray, IntArray]:
    """The identity ``rows`` (K, W) that stands without the weak peaks (``alone``, (K, W)):
    in every column where some line takes another row (or none) without them while it
    took a peak that is not weak (``held``) or takes a peak without them, the samples the
    two disagree on dropped. Returns the kept (K, W) rows, (W,) samples dropped, and per
    dropped sample (line by line, column by column) its row, column and the nearer
    (greater ``position`` (K,) from the top of the image) of its two lines."""
    k_count, width = rows.shape
    kept = rows.copy()
    lost = np.zeros(width, dtype=np.int64)
    unstable = np.zeros(width, dtype=np.bool_)
    for c in range(width):
        for k in range(k_count):
            if rows[k, c] != alone[k, c] and (alone[k, c] >= 0 or held[k, c]):
                unstable[c] = True
                break
        if unstable[c]:
            for k in range(k_count):
                if rows[k, c] != alone[k, c] and rows[k, c] >= 0:
                    kept[k, c] = -1
                    lost[c] += 1
    n = lost.sum()
    row = np.empty(n, dtype=np.int64)
    col = np.empty(n, dtype=np.int64)
    line = np.empty(n, dtype=np.int64)
    n = 0
    for k in range(k_count):
        for c in range(width):
            if kept[k, c] != rows[k, c]:
                other = -1
                for j in range(k_count):
                    if alone[j, c] == rows[k, c]:
                        other = j
                        break
                row[n], col[n] = rows[k, c], c
                line[n] = other if other >= 0 and position[other] > position[k] else k
                n += 1
    return kept, lost, row, col, line


@uncounted
def _as_they_are(peaks: IntArray, drop: BoolArray) -> bool:
    """True when nothing is to be dropped and every column of ``peaks`` (M, W) is sorted
    down with the -1 padding last already (passes along the rows, without a branch)."""
    m_count, width = peaks.shape
    dropped = False
    for i in range(m_count):
        for c in range(width):
            dropped |= drop[i, c]
    if dropped:
        return False
    unsorted = False
    for i in range(1, m_count):
        for c in range(width):
            p, above = peaks[i, c], peaks[i - 1, c]
            unsorted |= (p >= 0) & ((above < 0) | (above > p))
    return not unsorted


@kernel("Tuple((int64[:, :], int64[:]))(int64[:, :], boolean[:, :])")
def set_aside(peaks: IntArray, drop: BoolArray) -> tuple[IntArray, IntArray]:
    """``peaks`` (M, W) without the ``drop`` ones and the -1 padding, each column sorted
    down (insertion: the columns mostly are) with -1 padding last, and the (W,) count of
    ``drop``."""
    m_count, width = peaks.shape
    if _as_they_are(peaks, drop):
        return peaks.copy(), np.zeros(width, dtype=np.int64)
    out = np.full((m_count, width), -1, dtype=np.int64)
    count = np.zeros(width, dtype=np.int64)
    for c in range(width):
        m = 0
        for i in range(m_count):
            p = peaks[i, c]
            count[c] += drop[i, c]
            if drop[i, c] or p < 0:
                continue
            j = m
            while j > 0 and out[j - 1, c] > p:
                out[j, c] = out[j - 1, c]
                j -= 1
            out[j, c] = p
            m += 1
    return out, count


def warm_up() -> None:
    """Call every kernel once on a tiny input (argument typing before the first map)."""
    i64 = np.int64
    peaks = np.array([[1], [-1]], dtype=i64)
    one = np.array([0], dtype=i64)
    rows = np.array([[1]], dtype=i64)
    hi, none = np.array([4], dtype=i64), np.full((1, 1), -1, dtype=i64)
    costs, prior = np.array([10.0, 40.0, 10.0, 10.0]), (False, np.zeros(1), np.zeros(5),
                                                         np.zeros((1, 1)), one)
    rivals(peaks, one, hi, one, rows.copy(), none.copy(), one, np.full((1, 1), np.inf),
           np.array([np.inf]), 10.0, costs, *prior, np.full(1, -1, dtype=i64),
           np.zeros(1, dtype=np.bool_))
    unique(peaks, one, hi, one, rows.copy(), none.copy(), none.copy(),
           np.zeros(1, dtype=np.bool_), np.zeros(1, dtype=np.bool_), np.array([10.0, 4.0, 6.0]),
           np.array([4, 2, 1, 1, 3], dtype=i64), costs, *prior, np.full(1, -1, dtype=i64))
    doubts(peaks, rows, rows, none, one, one, hi, one)
    stable(rows, none, np.ones((1, 1), dtype=np.bool_), one)
    strong_rows(peaks, np.zeros((2, 1), dtype=np.bool_), rows)
    set_aside(peaks, np.zeros((2, 1), dtype=np.bool_))
    isolated(peaks, 2, 2)
    continuity(rows, np.ones(1, dtype=np.bool_), one, 4, 2, 1, 1, 4.0, 6.0)
