"""Compiled cheapest alignment of line identity (numba, ``nopython``).

The aligned identity of :mod:`atris_node.pipeline.identity` assigns the peaks of one column
to lines by dynamic programming: lines in image order, each takes the next peak in its band
or none, at a cost of its distance from the continuity reference (``align``,
``rows_cost``), and ``improve`` replaces a column's assignment by the aligned one where that
is cheaper by a margin. Kernels of :mod:`atris_node.pipeline.identity`, which checks the
arguments and documents the method; conventions (int64 rows, -1 = none; float64 costs in
px; explicit signatures, cached) as in :mod:`atris_node.pipeline.identity_kernels`.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel
from atris_node.pipeline.identity_kernels import (
    _line_terms,
    _sorted_peaks,
    _unexplained_column,
    uncounted,
)

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

_I1 = "int64[:]"
_I2 = "int64[:, :]"
_F1 = "float64[:]"
_F2 = "float64[:, :]"


@kernel()
def _in_bands(lo: IntArray, hi: IntArray) -> BoolArray:
    """(max hi,) True on the rows >= 0 that lie in one of the bands ``[lo, hi)``."""
    inside = np.zeros(max(hi.max(), 0) if hi.size else 0, dtype=np.bool_)
    for k in range(lo.size):
        inside[max(lo[k], 0):max(hi[k], 0)] = True
    return inside


@uncounted
def _inside(p: int, inside: BoolArray) -> bool:
    """True when row ``p`` >= 0 lies in a band (``inside`` of :func:`_in_bands`)."""
    return p < inside.size and inside[p]


@uncounted
def _align_line(j: int, column: IntArray, m: int, lo: IntArray, hi: IntArray, ref: float,
                beyond: float, spare: FloatArray, skip_px: float, beyond_px: float,
                d: FloatArray, choice: npt.NDArray[np.int8]) -> None:
    """Row j of the recursion D[j+1, i] from D[j, i] (in ``d``, overwritten)."""
    previous = d[0]  # D[j, i-1] before it is overwritten
    d[0] = previous + skip_px
    choice[j, 0] = 2
    for i in range(1, m + 1):
        p = column[i - 1]
        match = np.inf
        if lo[j] <= p < hi[j]:
            match = previous + (abs(p - ref) if np.isfinite(ref) else 0.0)
            match += beyond_px if p >= beyond else 0.0
        previous = d[i]
        skip = previous + skip_px
        best = min(match, skip)
        via_spare = d[i - 1] + spare[i - 1]
        if best <= via_spare:
            d[i] = best
            choice[j, i] = 1 if match <= skip else 2
        else:
            d[i] = via_spare
            choice[j, i] = 0


@uncounted
def _missing(rows: IntArray) -> int:
    """The count of lines without a row (-1) in ``rows`` (K,)."""
    count = 0
    for row in rows:
        count += row < 0
    return count


@uncounted
def _backtrack(choice: npt.NDArray[np.int8], column: IntArray, m: int, out: IntArray) -> None:
    """The rows each line took (``out``, -1 = none) from the choices of :func:`align`."""
    j, i = choice.shape[0], m
    while j > 0:
        c = choice[j - 1, i] if i > 0 else 2
        if c == 1:
            out[j - 1] = column[i - 1]
            j -= 1
            i -= 1
        elif c == 2:
            j -= 1
        else:
            i -= 1


@uncounted
def _align_column(peaks: IntArray, lo: IntArray, hi: IntArray, inside: BoolArray,
                  ref: FloatArray, beyond: FloatArray, costs: FloatArray, scratch: FloatArray,
                  column: IntArray, choice: npt.NDArray[np.int8], out: IntArray) -> float:
    """The cheapest alignment of one column: rows into ``out`` (K,) (-1 = none), the cost
    returned. ``inside`` the rows in a band (:func:`_in_bands`); ``costs`` (skip, spare,
    beyond) px; ``scratch`` (2, M + 1), ``column`` (M,) and ``choice`` (K, M + 1) work
    space."""
    skip_px, spare_px, beyond_px = costs[0], costs[1], costs[2]
    m = _sorted_peaks(peaks, column)
    spare, d = scratch[0], scratch[1]
    d[0] = 0.0
    for i in range(m):
        spare[i] = spare_px if _inside(column[i], inside) else 0.0
        d[i + 1] = d[i] + spare[i]
    for j in range(lo.size):
        _align_line(j, column, m, lo, hi, ref[j], beyond[j], spare, skip_px, beyond_px,
                    d, choice)
    out[:] = -1
    _backtrack(choice, column, m, out)
    return d[m]


@kernel(f"Tuple((int64[:, :], float64[:]))({_I2}, {_I1}, {_I1}, {_F2}, {_F1}, {_F1})")
def align(peaks: IntArray, lo: IntArray, hi: IntArray, ref: FloatArray, beyond: FloatArray,
          costs: FloatArray) -> tuple[IntArray, FloatArray]:
    """Per column the cheapest order-preserving alignment of K lines (bands ``[lo, hi)`` in
    image order) and the (M, n) ``peaks`` (-1 = none, any order): (K, n) rows (-1 = none)
    and (n,) cost, px. ``costs`` (skip, spare, beyond) px, as in
    :mod:`atris_node.pipeline.identity`; ``ref`` (K, n) and ``beyond`` (K,) in image order."""
    k_count, (m_count, n) = lo.size, peaks.shape
    rows = np.full((k_count, n), -1, dtype=np.int64)
    total = np.zeros(n)
    scratch = np.empty((2, m_count + 1))
    column = np.empty(m_count, dtype=np.int64)
    choice = np.zeros((k_count, m_count + 1), dtype=np.int8)
    out = np.empty(k_count, dtype=np.int64)
    inside = _in_bands(lo, hi)
    for c in range(n):
        total[c] = _align_column(peaks[:, c], lo, hi, inside, ref[:, c], beyond, costs,
                                 scratch, column, choice, out)
        rows[:, c] = out
    return rows, total


@uncounted
def _assignment_cost(rows: IntArray, order: IntArray, peaks: IntArray, inside: BoolArray,
                     ref: FloatArray, beyond: FloatArray,
                     costs: FloatArray) -> tuple[float, float, int]:
    """Of one column's assignment ``rows`` (K,) by line: (the match cost beyond what no
    alignment avoids: distances to known references and BEYOND past z_max; the floor of
    skips and spares; the lines assigned). ``ref`` (K,) by line; ``beyond`` (K,) in image
    order, ``order`` the line of each; ``inside`` the rows in a band (:func:`_in_bands`)."""
    skip_px, spare_px, beyond_px = costs[0], costs[1], costs[2]
    excess, assigned = 0.0, 0
    for k in range(order.size):
        row = rows[order[k]]
        if row < 0:
            continue
        assigned += 1
        if np.isfinite(ref[order[k]]):
            excess += abs(row - ref[order[k]])
        if row >= beyond[k]:
            excess += beyond_px
    in_bands = 0
    for p in peaks:
        in_bands += p >= 0 and _inside(p, inside)
    floor = skip_px * (order.size - assigned) + spare_px * (in_bands - assigned)
    return excess, floor, assigned


@kernel(f"void({_I2}, {_I1}, {_I1}, {_I1}, {_I2}, {_I1}, {_I1}, {_F2}, {_F1}, float64, {_F1}, "
      f"boolean, {_F1}, {_F1}, {_F2}, {_I1}, {_I1})")
def improve(peaks: IntArray, lo: IntArray, hi: IntArray, order: IntArray, rows: IntArray,
            unsure: IntArray, columns: IntArray, ref: FloatArray, beyond: FloatArray,
            margin: float, costs: FloatArray, has_prior: bool, cot_alpha: FloatArray,
            geometry: FloatArray, ground_range_m: FloatArray, image_order: IntArray,
            known: IntArray) -> None:
    """:func:`atris_node.pipeline.identity.improve` on the given ``columns``, in place on
    ``rows`` (K, W) by line and ``unsure`` (W,). ``costs`` (skip, spare, beyond,
    unexplained) px; the prior (``cot_alpha``, ``geometry``, ``ground_range_m``,
    ``image_order``, as :func:`unexplained` takes them) counts only with ``has_prior``;
    ``known`` (W,) its count for the given rows where already taken (-1 elsewhere), in
    place: on return the count of the returned rows where this call or an earlier one
    took it."""
    k_count, m_count = order.size, peaks.shape[0]
    unexplained_px = costs[3]
    scratch = np.empty((2, m_count + 1))
    column = np.empty(m_count, dtype=np.int64)
    choice = np.zeros((k_count, m_count + 1), dtype=np.int8)
    aligned = np.empty(k_count, dtype=np.int64)
    new = np.empty(k_count, dtype=np.int64)
    ref_image = np.empty(k_count)
    z = np.empty(k_count)
    old = np.empty(k_count, dtype=np.int64)  # column c copied, not viewed (no count)
    peaks_c = np.empty(m_count, dtype=np.int64)
    ref_c = np.empty(k_count)
    inside = _in_bands(lo, hi)
    terms = _line_terms(cot_alpha, geometry, image_order)
    for c in columns:
        for k in range(k_count):
            old[k], ref_c[k] = rows[k, c], ref[k, c]
        for i in range(m_count):
            peaks_c[i] = peaks[i, c]
        missing = 0.0
        if has_prior:
            if known[c] < 0:
                known[c] = _unexplained_column(old, c, terms, geometry, ground_range_m,
                                               image_order, z)
            missing = unexplained_px * known[c]
        excess, floor, assigned = _assignment_cost(old, order, peaks_c, inside, ref_c, beyond,
                                                   costs)
        if excess + missing < margin:
            continue  # no alignment can save the margin here
        old_total = excess + floor + missing
        for k in range(k_count):
            ref_image[k] = ref[order[k], c]
        total = _align_column(peaks_c, lo, hi, inside, ref_image, beyond, costs, scratch,
                              column, choice, aligned)
        if total + margin > old_total:
            continue
        for k in range(k_count):
            new[order[k]] = aligned[k]
        # the prior's cost can only raise the alignment's total, by at most its count of
        # missing lines: taken only when that could undo the switch
        count = -1  # of the new rows, where taken
        if has_prior and total + unexplained_px * _missing(new) + margin > old_total:
            count = _unexplained_column(new, c, terms, geometry, ground_range_m,
                                        image_order, z)
            total += unexplained_px * count
            if total + margin > old_total:
                continue
        known[c] = count
        kept = 0
        for k in range(k_count):
            kept += new[k] >= 0
            rows[k, c] = new[k]
        unsure[c] = max(assigned - kept, 0)


@kernel(f"float64[:]({_I2}, {_I2}, {_I1}, {_I1}, {_F2}, {_F1}, {_F1})")
def rows_cost(rows: IntArray, peaks: IntArray, lo: IntArray, hi: IntArray, ref: FloatArray,
              beyond: FloatArray, costs: FloatArray) -> FloatArray:
    """(n,) cost of the assignment ``rows`` (K, n, image order) of the (M, n) ``peaks``,
    in the terms :func:`align` minimises (``ref`` (K, n), ``beyond`` (K,) image order)."""
    order = np.arange(lo.size)
    out = np.empty(rows.shape[1])
    inside = _in_bands(lo, hi)
    for c in range(rows.shape[1]):
        excess, floor, _ = _assignment_cost(rows[:, c], order, peaks[:, c], inside, ref[:, c],
                                            beyond, costs)
        out[c] = excess + floor
    return out


def warm_up() -> None:
    """Call every kernel once on a tiny input (first-call argument typing, see
    :func:`atris_node.pipeline.identity_kernels.warm_up`)."""
    i64 = np.int64
    peaks = np.array([[1], [-1]], dtype=i64)
    lo, hi, line = np.array([0], dtype=i64), np.array([4], dtype=i64), np.array([0], dtype=i64)
    rows, ref, beyond = np.array([[-1]], dtype=i64), np.zeros((1, 1)), np.array([np.inf])
    costs = np.array([10.0, 40.0, 10.0, 10.0])
    cot, geometry, ground = np.array([0.1]), np.array([100.0, 2.0, 4.0, 0.1, 5.0, 0.0]), ref.copy()
    align(peaks, lo, hi, ref, beyond, costs)
    rows_cost(rows, peaks, lo, hi, ref, beyond, costs)
    improve(peaks, lo, hi, line, rows.copy(), np.zeros(1, dtype=i64), line, ref, beyond, 10.0,
            costs, True, cot, geometry, ground, line, np.full(1, -1, dtype=i64))
