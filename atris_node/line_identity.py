"""Line identity where the two greedy matchings disagree: the cheapest alignment of lines
and peaks in each column.

The top-down and bottom-up greedy matchings of :func:`atris_node.lines.identify_lines` are
the two extreme order-preserving matchings. When a line is missing in the middle of a
column (occluded, in a shadow, off a small object) the true identity lies between them:
the lines above the gap keep their rows, those below it keep theirs. Both greedy
matchings then shift a run of lines by one, and a shifted line is triangulated at a range
that can be metres off (a phantom obstacle, or a near one taken for far).

:func:`align` finds, per column, the order-preserving assignment of lines to
peaks (each line in its band) of least cost, by the sequence alignment recursion

    D[j, i] = min(D[j-1, i-1] + match(j-1, i-1),   line j-1 takes peak i-1
                  D[j-1, i] + SKIP_PX,              line j-1 has no peak
                  D[j, i-1] + spare(i-1))           peak i-1 belongs to no line

with the costs in pixels: a match costs the distance of the peak to the line's row in the
neighbouring columns (continuity), plus BEYOND_PX when the row is past the line's z_max
row (the sample would be no return, while the same peak may be a near range of the next
line); a missing line costs SKIP_PX; a spare peak inside a band costs SPARE_PX (it would
count as foreign light). A column costs K·M steps of a compiled loop
(:func:`atris_node.identity_kernels.align`). All rows are int64 px; costs float64 px,
finite.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import numpy.typing as npt

from atris_node import identity_kernels as kernels

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: cost (px) of a line without a peak in a column
SKIP_PX = 10.0
#: cost (px) of a peak inside a band that no line takes
SPARE_PX = 40.0
#: extra cost (px) of a row past the line's z_max row
BEYOND_PX = 10.0
#: cost (px) of a line missing without a reason (:meth:`VisibilityPrior.unexplained`)
UNEXPLAINED_PX = 10.0
#: least saving (px) for which the alignment replaces the greedy choice: one missing line
SWITCH_PX = 10.0
#: the costs as the kernels take them
_COSTS = np.array([SKIP_PX, SPARE_PX, BEYOND_PX, UNEXPLAINED_PX])


def align(peaks: IntArray, bands: tuple[tuple[int, int], ...], ref: FloatArray,
          beyond: FloatArray) -> tuple[IntArray, FloatArray]:
    """The cheapest alignment as (K, n) rows (-1 = none) and its (n,) cost in px.

    Ties go to a match over a skip, and to either over leaving a peak spare.

    Args:
        peaks: (M, n) peak rows of the columns to resolve, -1 = none, any order.
        bands: (lo, hi) of each line, in image order.
        ref: (K, n) continuity reference rows (inf: unknown).
        beyond: (K,) first row past each line's z_max range (inf: none).
    """
    lo, hi = _edges(bands)
    rows, cost = kernels.align(np.ascontiguousarray(peaks, dtype=np.int64), lo, hi,
                               np.ascontiguousarray(ref, dtype=np.float64),
                               np.ascontiguousarray(beyond, dtype=np.float64), _COSTS)
    return np.asarray(rows), np.asarray(cost)


def rows_cost(rows: IntArray, peaks: IntArray, bands: tuple[tuple[int, int], ...],
              ref: FloatArray, beyond: FloatArray) -> FloatArray:
    """(n,) cost in px of a given assignment ``rows`` (K, n, image order, -1 = none; each
    assigned row one of the (M, n) ``peaks`` inside its band), in the terms of
    :func:`align`: what the alignment minimises, so the two compare."""
    lo, hi = _edges(bands)
    return np.asarray(kernels.rows_cost(
        np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(peaks, dtype=np.int64),
        lo, hi, np.ascontiguousarray(ref, dtype=np.float64),
        np.ascontiguousarray(beyond, dtype=np.float64), _COSTS))


def _edges(bands: tuple[tuple[int, int], ...]) -> tuple[IntArray, IntArray]:
    """(K,) lower and (K,) upper band rows, int64."""
    return (np.array([b[0] for b in bands], dtype=np.int64),
            np.array([b[1] for b in bands], dtype=np.int64))


class Prior(Protocol):
    """What :func:`improve` needs of :class:`atris_node.lines.VisibilityPrior`."""

    @property
    def cot_alpha(self) -> FloatArray: ...
    @property
    def focal_px(self) -> float: ...
    @property
    def cy_px(self) -> float: ...
    @property
    def baseline_m(self) -> float: ...
    @property
    def z_max_m(self) -> float: ...
    @property
    def ground_range_m(self) -> FloatArray: ...
    @property
    def geometry(self) -> FloatArray: ...
    @property
    def image_order(self) -> IntArray: ...


def beyond_rows(prior: Prior | None, order: IntArray) -> FloatArray:
    """(K,) first integer row past each line's z_max range, lines in ``order`` (inf
    without a prior): observed rows, no lens correction (a plausibility bound)."""
    if prior is None:
        return np.full(order.size, np.inf)
    f = prior.focal_px
    row = prior.cy_px + f * prior.cot_alpha - f * prior.baseline_m / prior.z_max_m
    return np.asarray(np.floor(row[order]) + 1.0)


def improve(peaks: IntArray, edges: tuple[IntArray, IntArray], order: IntArray,
            greedy: tuple[IntArray, IntArray], unsettled: BoolArray, ref: FloatArray,
            prior: Prior | None, sep: int) -> tuple[IntArray, IntArray]:
    """The greedy identity ``greedy = (rows, unsure)`` ((K, W) by line, (W,)), replaced in
    each column where the cheapest alignment costs at least max(SWITCH_PX, ``sep``) px
    less and the greedy choice was not ambiguous.

    Only columns where the greedy choice itself costs that much above the floor every
    assignment pays (skips and spares; the greedy matching has the most pairs, so the
    least floor) are aligned: elsewhere nothing can beat it by that margin.

    Args:
        peaks: (M, W) peak rows, -1 = none.
        edges: (K,) int64 lower and (K,) upper band rows in image order; ``order`` (K,)
            the line of each.
        unsettled: (W,) columns where the two greedy matchings disagree.
        ref: (K, W) continuity reference by line, from the columns where both greedy
            matchings agree (inf: unknown).
        prior: the visibility prior (adds UNEXPLAINED_PX per line missing without reason).
        sep: px, the peak separation; a smaller saving never switches.

    Returns:
        rows (K, W) and (W,) unsure counts. A peak the greedy choice used that the
        alignment leaves to no line counts as unsure, so the foreign-peak count (peaks in
        the bands minus assigned minus unsure) is that of the greedy matching.
    """
    rows, unsure = rows_and_unsure = (greedy[0].copy(), greedy[1].copy())
    cols = np.flatnonzero(unsettled & (unsure == 0))
    lo, hi = edges
    kernels.improve(np.ascontiguousarray(peaks, dtype=np.int64), lo, hi,
                    order.astype(np.int64), rows, unsure, cols.astype(np.int64),
                    np.ascontiguousarray(ref, dtype=np.float64), beyond_rows(prior, order),
                    max(SWITCH_PX, float(sep)), _COSTS, *prior_arrays(prior, rows.shape))
    return rows_and_unsure


def prior_arrays(prior: Prior | None, shape: tuple[int, ...]) -> tuple[
        bool, FloatArray, FloatArray, FloatArray, IntArray]:
    """The prior as the kernels of :mod:`atris_node.identity_kernels` take it: (has_prior,
    cot α (K,), geometry (5,), ground range (K, W) m, image order (K,)); placeholders and
    False without one. ``shape`` is (K, W)."""
    if prior is None:
        k = shape[0]
        return False, np.zeros(k), np.zeros(5), np.zeros(shape), np.arange(k, dtype=np.int64)
    return (True, np.asarray(prior.cot_alpha, dtype=np.float64), prior.geometry,
            np.ascontiguousarray(prior.ground_range_m, dtype=np.float64), prior.image_order)


