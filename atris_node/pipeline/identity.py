"""Line identity where the two greedy matchings disagree: the cheapest alignment of lines
and peaks in each column.

The top-down and bottom-up greedy matchings of :func:`identify_lines` are
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
(:func:`atris_node.pipeline.alignment_kernels.align`). All rows are int64 px; costs float64 px,
finite.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from atris_node.pipeline import alignment_kernels
from atris_node.pipeline import identity_kernels as kernels
from atris_node.pipeline.bands import Band, image_positions, in_image_order

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
#: agreed samples a block of columns / a whole line needs to serve as continuity reference
MIN_BLOCK_SAMPLES = 4
MIN_LINE_SAMPLES = 16
#: columns per block of the continuity reference used to resolve overlapping bands
CONTINUITY_BLOCK = 32


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
    rows, cost = alignment_kernels.align(np.ascontiguousarray(peaks, dtype=np.int64), lo, hi,
                               np.ascontiguousarray(ref, dtype=np.float64),
                               np.ascontiguousarray(beyond, dtype=np.float64), _COSTS)
    return np.asarray(rows), np.asarray(cost)


def rows_cost(rows: IntArray, peaks: IntArray, bands: tuple[tuple[int, int], ...],
              ref: FloatArray, beyond: FloatArray) -> FloatArray:
    """(n,) cost in px of a given assignment ``rows`` (K, n, image order, -1 = none; each
    assigned row one of the (M, n) ``peaks`` inside its band), in the terms of
    :func:`align`: what the alignment minimises, so the two compare."""
    lo, hi = _edges(bands)
    return np.asarray(alignment_kernels.rows_cost(
        np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(peaks, dtype=np.int64),
        lo, hi, np.ascontiguousarray(ref, dtype=np.float64),
        np.ascontiguousarray(beyond, dtype=np.float64), _COSTS))


def _edges(bands: tuple[tuple[int, int], ...]) -> tuple[IntArray, IntArray]:
    """(K,) lower and (K,) upper band rows, int64."""
    return (np.array([b[0] for b in bands], dtype=np.int64),
            np.array([b[1] for b in bands], dtype=np.int64))


def beyond_rows(prior: VisibilityPrior | None, order: IntArray) -> FloatArray:
    """(K,) first integer row past each line's z_max range, lines in ``order`` (inf
    without a prior): observed rows, no lens correction (a plausibility bound)."""
    if prior is None:
        return np.full(order.size, np.inf)
    f = prior.focal_px
    row = prior.cy_px + f * prior.cot_alpha - f * prior.baseline_m / prior.z_max_m
    return np.asarray(np.floor(row[order]) + 1.0)


def improve(peaks: IntArray, edges: tuple[IntArray, IntArray], order: IntArray,
            greedy: tuple[IntArray, IntArray], unsettled: BoolArray, ref: FloatArray,
            prior: VisibilityPrior | None, sep: int, missing: IntArray | None = None
            ) -> tuple[IntArray, IntArray]:
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
        missing: (W,) the prior's count of the greedy rows' lines missing without a
            reason where it is known (-1 elsewhere; None: nowhere).

    Returns:
        rows (K, W) and (W,) unsure counts. A peak the greedy choice used that the
        alignment leaves to no line counts as unsure, so the foreign-peak count (peaks in
        the bands minus assigned minus unsure) is that of the greedy matching. ``missing``
        (when given) then holds the count of the returned rows where it was taken.
    """
    rows, unsure = rows_and_unsure = (greedy[0].copy(), greedy[1].copy())
    cols = np.flatnonzero(unsettled & (unsure == 0))
    lo, hi = edges
    known = (np.full(rows.shape[1], -1, dtype=np.int64) if missing is None else
             np.ascontiguousarray(missing, dtype=np.int64))
    alignment_kernels.improve(np.ascontiguousarray(peaks, dtype=np.int64), lo, hi,
                    order.astype(np.int64), rows, unsure, cols.astype(np.int64),
                    np.ascontiguousarray(ref, dtype=np.float64), beyond_rows(prior, order),
                    max(SWITCH_PX, float(sep)), _COSTS, *prior_arrays(prior, rows.shape),
                    known)
    if missing is not None and known is not missing:
        missing[:] = known
    return rows_and_unsure


def prior_arrays(prior: VisibilityPrior | None, shape: tuple[int, ...]) -> tuple[
        bool, FloatArray, FloatArray, FloatArray, IntArray]:
    """The prior as the kernels of :mod:`atris_node.pipeline.identity_kernels` take it: (has_prior,
    cot α (K,), geometry (5,), ground range (K, W) m, image order (K,)); placeholders and
    False without one. ``shape`` is (K, W)."""
    if prior is None:
        k = shape[0]
        return False, np.zeros(k), np.zeros(5), np.zeros(shape), np.arange(k, dtype=np.int64)
    return (True, np.asarray(prior.cot_alpha, dtype=np.float64), prior.geometry,
            np.ascontiguousarray(prior.ground_range_m, dtype=np.float64), prior.image_order)


def _continuity_reference(rows: IntArray, good: BoolArray) -> FloatArray:
    """(The kernel :func:`identify_lines` uses, with this module's constants.) (K, W) per
    line: the median of the good rows in each block of CONTINUITY_BLOCK
    columns (at least MIN_BLOCK_SAMPLES of them; the upper median of an even count);
    elsewhere the median of all the line's good rows when there are at least
    MIN_LINE_SAMPLES; inf where no reference can be trusted. ``rows`` (K, W) int,
    ``good`` (K, W) bool."""
    return np.asarray(kernels.continuity_reference(
        np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(good, dtype=np.bool_),
        CONTINUITY_BLOCK, MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES))


@dataclass(frozen=True)
class VisibilityPrior:
    """Where each line would be seen if a surface were there, from the calibration and
    the mounting: it tells a missing line that is explained (below the ground, off the
    image, out of range) from one that is not.

    ``cot_alpha`` (K,) cot α_k; ``ground_range_m`` (K, W) float64 camera range z (m) at
    which line k's plane meets the ground (plus clearance) in column c, ``np.inf`` when it
    never does; other fields in pixels and metres.
    """

    cot_alpha: FloatArray
    focal_px: float
    cy_px: float
    height_px: int
    baseline_m: float
    z_max_m: float
    ground_range_m: FloatArray
    #: px; a missing line whose row lies within this of a stripe of a sheet nearly
    #: parallel to its own (their stripes this near on any surface) is explained: the
    #: peak search keeps one maximum within ``min_separation_px`` rows (0: none is)
    masked_px: float = 0.0

    def unexplained(self, rows: IntArray, columns: IntArray | None = None) -> IntArray:
        """(n,) number of unassigned lines that should be visible at the range of their
        nearest assigned neighbour (above ground, inside the image, within z_max).
        ``rows`` (K, n) by line are those of the image ``columns`` (default: all W)."""
        ground = self.ground_range_m if columns is None else self.ground_range_m[:, columns]
        return np.asarray(kernels.unexplained(
            np.ascontiguousarray(rows, dtype=np.int64), self.cot_alpha, self.geometry,
            np.ascontiguousarray(ground, dtype=np.float64), self.image_order))

    @cached_property
    def geometry(self) -> FloatArray:
        """(6,) focal px, cy px, height px, baseline m, z_max m, masked px (as the kernels
        take them)."""
        return np.array([self.focal_px, self.cy_px, self.height_px, self.baseline_m,
                         self.z_max_m, self.masked_px], dtype=np.float64)

    @cached_property
    def looks_beyond(self) -> BoolArray:
        """(W,) True where some line meets the ground beyond z_max (or never): that line
        looks over the whole operating range. Where none does, nothing beyond the
        farthest ground hit is looked at, and the column cannot show free space."""
        return np.asarray((self.ground_range_m > self.z_max_m).any(axis=0))

    @cached_property
    def image_order(self) -> IntArray:
        """(K,) the lines from the top of the image down (ascending cot α)."""
        return np.argsort(self.cot_alpha)

    @cached_property
    def masked_pairs(self) -> list[tuple[int, int]]:
        """The line pairs (j, k) whose stripes lie MERGED_PX to ``masked_px`` apart on
        every surface (f·|cot α_j − cot α_k|): the peak search keeps one maximum of such a
        pair, at one line's row or, where the two merge, between them. Empty without
        masking (no such pair). Taken once per prior, not per map."""
        if self.masked_px <= 0.0:
            return []
        rows = self.focal_px * np.asarray(self.cot_alpha, dtype=np.float64)
        k_count = rows.size
        return [(j, k) for j in range(k_count) for k in range(j + 1, k_count)
                if kernels.MERGED_PX <= abs(rows[j] - rows[k]) < self.masked_px]

    @cached_property
    def image_rank(self) -> IntArray:
        """(K,) each line's position from the top of the image (0 = top)."""
        return image_positions(self.image_order)


def masking_px(cot_alpha: FloatArray, focal_px: float, sep: int) -> float:
    """The :attr:`VisibilityPrior.masked_px` of sheets ``cot_alpha`` (K,) seen at
    ``focal_px`` by a peak search of separation ``sep`` rows: sep + 0.5 when the stripes of
    two sheets lie MERGED_PX to that far apart on every surface (f·|cot α_j − cot α_k|),
    else 0: without such a pair no line can be masked, and the check is left out."""
    masked = sep + 0.5
    rows = focal_px * np.sort(np.asarray(cot_alpha, dtype=np.float64))
    apart = np.abs(rows[:, None] - rows[None, :])
    return masked if bool(((apart >= kernels.MERGED_PX) & (apart < masked)).any()) else 0.0


def off_masked_pairs(rows: IntArray, prior: VisibilityPrior | None
                     ) -> tuple[IntArray, IntArray, tuple[IntArray, IntArray, IntArray]]:
    """``rows`` (K, W) without the peaks of a masked pair's line whose partner is missing
    in their column, (W,) how many were taken out per column (ambiguous peaks), and those
    peaks as doubts (row, column, line), once per line of the pair. Such a peak is one
    maximum of two stripes: the upper line's, the lower one's, or the two merged between
    their rows; the lines' ranges at its row differ by r²/(f·b) per row of their
    separation (two sheets 0.37 deg apart, 2.4 px: a merged peak on a ball at 2.34 m,
    read as the lower line at its row, gave 2.01 m, a near phantom in every map). Taken as
    the line the identity chose with the other one explained as masked, it was a guess;
    now it is ambiguous. Nothing is done without a masked pair
    (:attr:`VisibilityPrior.masked_pairs`)."""
    width = rows.shape[1]
    pairs = [] if prior is None else prior.masked_pairs
    if not pairs:
        return rows, np.zeros(width, dtype=np.int64), _NO_DOUBTS
    out = np.array(rows, dtype=np.int64, copy=True)
    removed = np.zeros(width, dtype=np.int64)
    found: list[tuple[IntArray, IntArray, IntArray]] = []
    for j, k in pairs:
        for seen, partner in ((j, k), (k, j)):
            lone = np.flatnonzero((rows[seen] >= 0) & (rows[partner] < 0))
            if not lone.size:
                continue
            peak = rows[seen, lone].astype(np.int64)
            found += [(peak, lone, np.full(lone.size, line, dtype=np.int64))
                      for line in (seen, partner)]
            out[seen, lone] = -1
            removed[lone] += 1
    if not found:
        return rows, removed, _NO_DOUBTS
    row, col, line = (np.concatenate(parts) for parts in zip(*found, strict=True))
    return out, removed, (row, col, line)


_NO_DOUBTS = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))


def identify_lines(peaks: IntArray, bands: tuple[Band, ...], sep: int,
                   prior: VisibilityPrior | None = None, *, aligned: bool = False,
                   edges: tuple[IntArray, IntArray, IntArray] | None = None
                   ) -> tuple[IntArray, IntArray]:
    """(K, W) row of each line per column (-1 = none) and (W,) ambiguous samples per column.

    Order: lines keep their top-to-bottom order and each stays in its band. Both greedy
    matchings (top down and bottom up) have the most pairs; where they agree the identity
    is certain. Where they differ, the ``prior`` (if given) prefers the matching that
    leaves fewer lines missing without a reason; then continuity decides: the matching
    whose differing rows lie closer (by at least ``sep`` px) to each line's rows in the
    neighbouring columns wins; otherwise the differing samples are dropped and counted
    ambiguous. With ``aligned``, a confident choice is then replaced where the cheapest
    alignment (:func:`improve`) is clearly cheaper (a line missing in the
    middle of a column, which both greedy matchings answer with a shifted run of lines).
    ``edges``: ``in_image_order(bands)`` where the caller has it.
    """
    rows, unsure, _ = identify_counted(peaks, bands, sep, prior, aligned=aligned, edges=edges)
    return rows, unsure


def identify_counted(peaks: IntArray, bands: tuple[Band, ...], sep: int,
                     prior: VisibilityPrior | None = None, *, aligned: bool = False,
                     edges: tuple[IntArray, IntArray, IntArray] | None = None
                     ) -> tuple[IntArray, IntArray, IntArray]:
    """:func:`identify_lines`, and (W,) int64 the prior's count of the rows' lines missing
    without a reason (:meth:`VisibilityPrior.unexplained`) in the columns where the
    matchings or the alignment took it (-1 elsewhere), for the rival test."""
    lo, hi, line = in_image_order(bands) if edges is None else edges
    rows, unsure, unsettled, certain, missing = kernels.greedy_identity(
        np.ascontiguousarray(peaks, dtype=np.int64), lo, hi, line, int(sep), aligned,
        *prior_arrays(prior, (len(bands), peaks.shape[1])), CONTINUITY_BLOCK,
        MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES)
    if not aligned or not unsettled.any():
        return rows, unsure, missing
    rows, unsure = improve(peaks, (lo, hi), line, (rows, unsure), unsettled, certain, prior,
                           sep, missing)
    return rows, unsure, missing
