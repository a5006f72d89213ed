"""Unique identity or none: a line sample is kept only when no rival identity explains its
column nearly as well.

Eight lines in 400 rows with a 7.5 cm baseline: a line's band (its rows between z_min and
z_max) is about five line spacings tall, so most peaks lie in several bands. Taking line
k + s for the stripe of line k moves the whole comb by s spacings and triangulates to a
coherent surface nearer than the true one (a phantom). Order and continuity alone choose
one of these; they cannot tell that the choice was a guess.

:func:`unique_identity` asks, in every column, whether some assignment that gives a peak
another line costs less than the chosen assignment plus ``RIVAL_MARGIN_PX``. The cost is
the alignment cost of :mod:`atris_node.pipeline.identity` (continuity to the reference
rows, a line skipped, a peak left spare; not a row past z_max: a surface beyond the range
returns the lines as well as a near one) plus the visibility prior's
cost of every line missing without a reason (a surface at the hypothesised range would
show that line, in the image, above the ground): the comb's ends and the ground anchor
the identity where continuity cannot. The cheapest rival for each (peak, line) pair is a
max-marginal of the alignment, read back and priced with the prior
(:func:`atris_node.pipeline.rivals_kernels.rivals`).

It runs in rounds. First without continuity, so that only the physics anchors a column
(a column cannot vouch for itself through a reference built from its own rows); the
columns left without a rival are *anchored*. Then every other column again, with each
line's row in the nearest anchored column within CONTINUITY_REACH columns as its
continuity reference (a stripe on one surface moves little from column to column); a
column resolved in one round anchors the next. The continuity never changes an identity,
it only settles a tie: replacing the chosen assignment by a cheaper one let a comb that
a noise maximum had anchored one line off spread along its row. A peak that still has a
rival is dropped and counted ambiguous, with its nearest hypothesis: a sector cannot be
NO_RETURN with it, nor VALID at a distance it may stand as near as.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.pipeline import rivals_kernels
from atris_node.pipeline.bands import Band, in_image_order
from atris_node.pipeline.identity import (
    _COSTS,
    CONTINUITY_BLOCK,
    MIN_BLOCK_SAMPLES,
    MIN_LINE_SAMPLES,
    SWITCH_PX,
    VisibilityPrior,
    identify_lines,
    prior_arrays,
)

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

#: px; a rival must cost at least this much more than the chosen identity: the cost of one
#: line missing without a reason (or 10 px of continuity)
RIVAL_MARGIN_PX = SWITCH_PX
#: a peak needs a peak within LONE_STEP_PX rows within LONE_REACH columns (a stripe)
LONE_REACH = 2
LONE_STEP_PX = 6
#: continuity comes from anchored columns at most this many columns away
CONTINUITY_REACH = 16
#: rounds of the continuity pass (a resolved column anchors the next round)
CONTINUITY_ROUNDS = 3
#: px; anchored rows of a line on both sides of a gap bridge it when they agree this well
BRIDGE_PX = 4.0
#: px past a line's row at infinite range that a rival may still give it (peak noise)
INFINITY_PX = 1.0
#: px; beyond a line's last anchor its median row is a reference only in columns whose
#: chosen rows all lie this near their lines' medians (elsewhere it is another surface's)
MEDIAN_PX = 6.0


def unique_identity(peaks: IntArray, bands: tuple[Band, ...], rows: IntArray,
                    prior: VisibilityPrior | None) -> tuple[IntArray, IntArray]:
    """The identity ``rows`` (K, W) by line (-1 = none) with every sample that has a rival
    removed, and (K, W) by line at the removed samples' chosen line: the line, among the
    chosen and its rivals, that puts the peak nearest (-1 where nothing was removed).

    Args:
        peaks: (M, W) int64 peak rows per column, -1 = none, any order.
        bands: one :class:`Band` per line.
        rows: (K, W) int64, the identity chosen so far (:func:`identify_lines`).
        prior: the visibility prior; without it only bands, order and continuity count.
    """
    lo, hi, order = in_image_order(bands)
    # a stripe from past its line's z_max (the ground or a wall beyond the range) is as
    # good an explanation as the next line at a near range, and the rival test must see
    # that tie: each line may take peaks down to its row at infinite range, with no
    # BEYOND_PX (the identity's own choice keeps both)
    hi = _to_infinity(hi, order, prior)
    peaks = np.ascontiguousarray(peaks, dtype=np.int64)
    rows = np.array(rows, dtype=np.int64, order="C")
    shape = rows.shape
    ambiguous = np.full(shape, -1, dtype=np.int64)
    beyond = np.full(order.size, np.inf)
    loose = np.full(shape, np.inf)  # pass 1: no continuity
    _test(peaks, (lo, hi, order), rows, ambiguous, _has_peaks(rows), loose, beyond, prior)
    left = -1
    for _ in range(CONTINUITY_ROUNDS):
        anchored = np.asarray(~(ambiguous >= 0).any(axis=0), dtype=np.bool_)
        again = np.flatnonzero(~anchored)
        if again.size in (0, left):
            break  # all anchored, or the last round anchored nothing new
        left = again.size
        ref = _reference(rows, anchored)
        ambiguous[:, again] = -1
        _test(peaks, (lo, hi, order), rows, ambiguous, again, ref[order], beyond, prior)
    rows[ambiguous >= 0] = -1
    return rows, ambiguous


@dataclass(frozen=True)
class Identity:
    """The identity of one map: ``rows`` (K, W) by line (-1 = none), ``unsure`` (W,)
    ambiguous peaks per column, and every ambiguous peak as (n,) ``doubt_row``,
    ``doubt_col`` and ``doubt_line``: the line among its hypotheses that puts it nearest
    (lowest in the image), so that a sector can tell whether the doubt reaches nearer than
    the distance it reports."""

    rows: IntArray
    unsure: IntArray
    doubt_row: IntArray
    doubt_col: IntArray
    doubt_line: IntArray

    def with_doubts(self, row: IntArray, col: IntArray, line: IntArray) -> Identity:
        return Identity(self.rows, self.unsure, np.concatenate([self.doubt_row, row]),
                        np.concatenate([self.doubt_col, col]),
                        np.concatenate([self.doubt_line, line]))


def robust_identity(peaks: IntArray, weak: Callable[[IntArray], BoolArray],
                    bands: tuple[Band, ...], sep: int, prior: VisibilityPrior | None, *,
                    aligned: bool) -> Identity:
    """Unique identity that also stands without the weak peaks.

    A noise maximum just above the threshold (in a tile whose σ comes from its quiet part)
    can complete a comb shifted by one line, and a complete comb has no rival. So the
    identity is made twice: with every peak, and without the ``weak`` ones
    (``weak(rows)`` says which of the given (., W) rows are weak). A column where a strong
    peak gets another line (or none) without the weak peaks depends on them: there only the
    samples both identities agree on are kept, the others count as ambiguous, with the
    nearer of their two lines as their doubt.
    """
    full = _unique(peaks, bands, sep, prior, aligned)
    weak_peaks = weak(peaks) & (peaks >= 0)
    if not weak_peaks.any():
        return full
    strong, _ = set_aside(peaks, weak_peaks)
    alone = _unique(strong, bands, sep, prior, aligned)
    rows, rows_b = full.rows, alone.rows
    held = (rows >= 0) & ~weak(rows)
    unstable = ((rows != rows_b) & ((rows_b >= 0) | held)).any(axis=0)
    dropped = unstable[None, :] & (rows != rows_b) & (rows >= 0)
    kept = np.where(dropped, -1, rows)
    lost = (rows >= 0).sum(axis=0) - (kept >= 0).sum(axis=0)
    k, c = np.nonzero(dropped)
    other = _line_of(rows_b, rows[k, c], c)
    position = _positions(bands)
    nearer = np.where((other >= 0) & (position[np.maximum(other, 0)] > position[k]), other, k)
    out = Identity(kept, full.unsure + lost, full.doubt_row, full.doubt_col, full.doubt_line)
    out = out.with_doubts(rows[k, c], c.astype(np.int64), nearer.astype(np.int64))
    return out.with_doubts(alone.doubt_row, alone.doubt_col, alone.doubt_line)


def _to_infinity(hi: IntArray, order: IntArray, prior: VisibilityPrior | None) -> IntArray:
    """(K,) upper band rows (exclusive, image ``order``) reaching at least INFINITY_PX
    past each line's row at infinite range, cy + f·cot α, within the image: where a
    line's stripe from beyond the operating range lies, and no farther (a peak past that
    row would be a negative disparity). Unchanged without a prior."""
    if prior is None:
        return hi
    infinity = prior.cy_px + prior.focal_px * np.asarray(prior.cot_alpha)[order]
    reach = np.floor(infinity + INFINITY_PX).astype(np.int64) + 1
    return np.minimum(np.maximum(hi, reach), prior.height_px).astype(np.int64)


def _line_of(rows: IntArray, row: IntArray, col: IntArray) -> IntArray:
    """(n,) the line holding ``row`` in column ``col`` of ``rows`` (K, W), -1 if none."""
    match = rows[:, col] == row[None, :]
    return np.where(match.any(axis=0), match.argmax(axis=0), -1).astype(np.int64)


def _positions(bands: tuple[Band, ...]) -> IntArray:
    """(K,) each line's position from the top of the image (0 = top)."""
    _, _, order = in_image_order(bands)
    position = np.empty(order.size, dtype=np.int64)
    position[order] = np.arange(order.size)
    return position


def _lowest_band(rows: IntArray, bands: tuple[Band, ...]) -> IntArray:
    """(n,) the line lowest in the image whose band holds each row (-1 if none): the
    nearest range a peak of unknown line may stand for."""
    lo, hi, order = in_image_order(bands)
    inside = (rows[:, None] >= lo[None, :]) & (rows[:, None] < hi[None, :])
    last = inside.shape[1] - 1 - inside[:, ::-1].argmax(axis=1)
    return np.where(inside.any(axis=1), order[last], -1).astype(np.int64)


def _unique(peaks: IntArray, bands: tuple[Band, ...], sep: int,
            prior: VisibilityPrior | None, aligned: bool) -> Identity:
    """:func:`identify_lines` then :func:`unique_identity`. Peaks the rival test removed
    keep their nearest rival as doubt; peaks the greedy matchings could not place, the
    lowest band that holds them."""
    first, unsure = identify_lines(peaks, bands, sep, prior, aligned=aligned)
    before = (first >= 0).sum(axis=0)
    rows, nearest = unique_identity(peaks, bands, first, prior)
    k, c = np.nonzero(nearest >= 0)
    rivalled = (first[k, c], c.astype(np.int64), nearest[k, c])
    placed = ((peaks[None, :, :] == rows[:, None, :]) & (rows[:, None, :] >= 0)).any(axis=0)
    unplaced = (peaks >= 0) & ~placed & (unsure > 0)[None, :]
    unplaced &= ~_is_rivalled(peaks, rivalled)
    i, j = np.nonzero(unplaced)
    lowest = _lowest_band(peaks[i, j], bands)
    known = lowest >= 0
    out = Identity(rows, unsure + np.maximum(before - (rows >= 0).sum(axis=0), 0),
                   *rivalled)
    return out.with_doubts(peaks[i, j][known], j[known].astype(np.int64), lowest[known])


def _is_rivalled(peaks: IntArray, rivalled: tuple[IntArray, IntArray, IntArray]
                 ) -> BoolArray:
    """(M, W) True at the peaks listed in ``rivalled`` (rows, columns, lines)."""
    out = np.zeros(peaks.shape, dtype=np.bool_)
    row, col, _ = rivalled
    m, n = np.nonzero(peaks[:, col] == row[None, :])
    out[m, col[n]] = True
    return out


def set_aside(peaks: IntArray, drop: BoolArray) -> tuple[IntArray, IntArray]:
    """``peaks`` without the ``drop`` ones, each column sorted down with the -1 padding
    last (as the greedy matchings expect), and the (W,) count dropped."""
    big = np.iinfo(np.int64).max
    kept = np.sort(np.where(drop | (peaks < 0), big, peaks), axis=0)
    return np.where(kept == big, -1, kept), drop.sum(axis=0).astype(np.int64)


def stripe_peaks(peaks: IntArray, reach: int = LONE_REACH, max_step: int = LONE_STEP_PX
                 ) -> tuple[IntArray, IntArray]:
    """``peaks`` (M, W) without the isolated ones (each column kept sorted, -1 padding
    last) and the (W,) count removed per column. A stripe continues into a neighbouring
    column within ``max_step`` rows; a maximum that does not is noise or a sliver too thin
    to identify, and must not anchor a comb. The count stays evidence: such a column is
    not free."""
    peaks = np.ascontiguousarray(peaks, dtype=np.int64)
    lone = rivals_kernels.isolated(peaks, reach, max_step)
    if not lone.any():
        return peaks, np.zeros(peaks.shape[1], dtype=np.int64)
    return set_aside(peaks, lone)


def _has_peaks(rows: IntArray) -> IntArray:
    """(n,) int64 columns where some line took a peak."""
    return np.flatnonzero((rows >= 0).any(axis=0)).astype(np.int64)


def _reference(rows: IntArray, anchored: BoolArray) -> npt.NDArray[np.float64]:
    """(K, W) continuity reference by line: the row in the nearest anchored column within
    CONTINUITY_REACH; where there is none, the median of the anchored rows of the line in
    the column's block of CONTINUITY_BLOCK columns; where there is none either and the
    line has anchored columns on both sides, its row there when they agree within
    BRIDGE_PX (the stripe runs on between them), else none; beyond the line's last
    anchored column, the median of all its anchored rows (MIN_LINE_SAMPLES at least);
    inf where none of these holds. Between anchors that disagree the line's median is
    no reference: it mixes surfaces at different ranges, and a comb shifted by one line
    can match it better than the true one (a wall turned away, its far part a line
    spacing higher in the image: a phantom at 1.4 m for a wall at 5.7 m)."""
    return np.asarray(rivals_kernels.continuity(
        np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(anchored, dtype=np.bool_),
        CONTINUITY_REACH, CONTINUITY_BLOCK, MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES, BRIDGE_PX,
        MEDIAN_PX))


def _test(peaks: IntArray, edges: tuple[IntArray, IntArray, IntArray], rows: IntArray,
          ambiguous: IntArray, columns: IntArray, ref: npt.NDArray[np.float64],
          beyond: npt.NDArray[np.float64], prior: VisibilityPrior | None) -> None:
    """One pass of the compiled rival test over ``columns`` (in place)."""
    lo, hi, order = edges
    rivals_kernels.rivals(peaks, lo, hi, order.astype(np.int64), rows, ambiguous,
                          np.ascontiguousarray(columns, dtype=np.int64),
                          np.ascontiguousarray(ref, dtype=np.float64), beyond,
                          RIVAL_MARGIN_PX, _COSTS, *prior_arrays(prior, rows.shape))


def warm_up() -> None:
    """Type the kernels' arguments once (the first map does not wait for it)."""
    rivals_kernels.warm_up()
    band = Band(0, 0, 4)
    unique_identity(np.array([[1], [-1]], dtype=np.int64), (band,),
                    np.array([[1]], dtype=np.int64), None)
