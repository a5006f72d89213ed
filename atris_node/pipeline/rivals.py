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
a noise maximum had anchored one line off spread along its row. Nor does it overrule the
physics: a column where, without continuity, a rival costs less than the chosen identity
by more than RIVAL_MARGIN_PX (*outranked*: the prior prefers another identity by more
than one unexplained line) is not tested again, and stays ambiguous. A preference of
exactly one line is a tie the continuity may settle: the prior misses by one line where
a faint ground return is not found (indoor_lab's wall beside the box, whose sector would
go INVALID in 2 maps of 4 if it were outranked). A reference is rows only,
and rows cannot tell a comb from the same comb shifted by one line at another range: a
far box's two stripes taken one line low (0.67 m for a box at 4.1 m) lay within
MEDIAN_PX of a near pole's comb 120 columns away, and its line medians anchored the
shift against a prior that preferred the truth by two lines. Nor does a reference
settle a column none of whose stripes lies within BRIDGE_PX of it: it is then other
surfaces' rows, and the identity nearer to them is the lesser of two misfits, not a fit
(a thin pole's two stripes 0.79 m away, tied between the comb and the comb one line off,
were settled for the latter by other surfaces' rows: 1.58 m). A peak that still has a
rival is dropped and counted ambiguous, with its nearest hypothesis: a sector cannot be
NO_RETURN with it, nor VALID at a distance it may stand as near as.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.pipeline import rivals_kernels
from atris_node.pipeline.bands import Band, image_positions, in_image_order
from atris_node.pipeline.identity import (
    _COSTS,
    CONTINUITY_BLOCK,
    MIN_BLOCK_SAMPLES,
    MIN_LINE_SAMPLES,
    SWITCH_PX,
    VisibilityPrior,
    identify_counted,
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
#: chosen rows all lie this near their lines' medians (elsewhere it is another surface's).
#: A surface at another range moves every line by the same rows, so a comb a few rows
#: off the medians is the medians' comb at another range or the next line's comb at a
#: third: the medians vouch only for a comb on them (an integer peak's rounding and a
#: row of slope). At 6 px a far wall's comb of three, 4-5 px below lines 1-3's medians,
#: was settled one line low (2.6 m for 3.66 m); 2 px changed no sector-frame of the
#: shipped and stress scenes on seed 1.
MEDIAN_PX = 2.0
#: the rival test's px and column counts as :func:`rivals_kernels.unique` takes them
_MARGINS = np.array([RIVAL_MARGIN_PX, BRIDGE_PX, MEDIAN_PX])
_SPANS = np.array([CONTINUITY_REACH, CONTINUITY_BLOCK, MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES,
                   CONTINUITY_ROUNDS], dtype=np.int64)


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
    rows, ambiguous, _ = _unique_rows(peaks, in_image_order(bands), rows, prior, None, None)
    return rows, ambiguous


def _unique_rows(peaks: IntArray, edges: tuple[IntArray, IntArray, IntArray],
                 rows: IntArray, prior: VisibilityPrior | None,
                 earlier: tuple[FirstPass, BoolArray] | None, counted: IntArray | None
                 ) -> tuple[IntArray, IntArray, FirstPass]:
    """:func:`unique_identity` (bands as ``edges``, :func:`in_image_order`), and the rival
    test's result without continuity (pass 1) in every column. ``earlier``: that pass-1
    result of an earlier identity and (W,) the columns where its peaks and ``rows`` were
    these, which take it over. ``counted``: (W,) the prior's count of the lines of
    ``rows`` missing without a reason where known (-1 elsewhere; None: nowhere)."""
    lo, hi, order = edges
    # a stripe from past its line's z_max (the ground or a wall beyond the range) is as
    # good an explanation as the next line at a near range, and the rival test must see
    # that tie: each line may take peaks down to its row at infinite range, with no
    # BEYOND_PX (the identity's own choice keeps both)
    hi = _to_infinity(hi, order, prior)
    rows = np.array(rows, dtype=np.int64, order="C")
    ambiguous = np.full(rows.shape, -1, dtype=np.int64)
    if earlier is None:
        passed, outranked = np.empty_like(ambiguous), np.zeros(rows.shape[1], dtype=np.bool_)
        reuse = np.zeros(rows.shape[1], dtype=np.bool_)
    else:
        passed, outranked = earlier[0].ambiguous.copy(), earlier[0].outranked.copy()
        reuse = np.ascontiguousarray(earlier[1], dtype=np.bool_)
    counted = (np.full(rows.shape[1], -1, dtype=np.int64) if counted is None else
               np.array(counted, dtype=np.int64))
    rivals_kernels.unique(np.ascontiguousarray(peaks, dtype=np.int64), lo, hi, order, rows,
                          ambiguous, passed, outranked, reuse, _MARGINS, _SPANS, _COSTS,
                          *prior_arrays(prior, rows.shape), counted)
    return rows, ambiguous, FirstPass(passed, outranked)


@dataclass(frozen=True)
class FirstPass:
    """The rival test without continuity (pass 1): ``ambiguous`` (K, W) by line, the
    nearest rival line of each peak that has one (-1 elsewhere), and ``outranked`` (W,)
    the columns where a rival costs less than the chosen identity by more than the
    margin: the physics prefers another identity there, and no continuity may settle it."""

    ambiguous: IntArray
    outranked: BoolArray


@dataclass(frozen=True)
class Identity:
    """The identity of one map: ``rows`` (K, W) by line (-1 = none), ``unsure`` (W,)
    ambiguous peaks per column, every ambiguous peak as (n,) ``doubt_row``,
    ``doubt_col`` and ``doubt_line``: the line among its hypotheses that puts it nearest
    (lowest in the image), so that a sector can tell whether the doubt reaches nearer than
    the distance it reports; and ``tied`` (K, W), True at the kept samples whose peak had a
    rival in the test without continuity, every rival putting it farther: the physics
    could not tell their line, and the continuity to other columns settled it for the
    nearest hypothesis, where a wrong choice is a near phantom (the chain asks their
    brightness more, :attr:`atris_node.pipeline.chain.PipelineConfig.tied_reflectance`)."""

    rows: IntArray
    unsure: IntArray
    doubt_row: IntArray
    doubt_col: IntArray
    doubt_line: IntArray
    tied: BoolArray


def robust_identity(peaks: IntArray, weak: Callable[[IntArray], BoolArray],
                    bands: tuple[Band, ...], sep: int, prior: VisibilityPrior | None, *,
                    aligned: bool) -> Identity:
    """Unique identity that also stands without the weak peaks.

    A noise maximum just above the threshold (in a tile whose σ comes from its quiet part)
    can complete a comb shifted by one line, and a complete comb has no rival. So the
    identity is made twice: with every peak, and without the ``weak`` ones
    (``weak(rows)`` says which of the given (., W) rows are weak, each by its own row and
    column: the identity's rows, peaks of ``peaks``, take their peaks' flags). A column
    where a strong peak gets another line (or none) without the weak peaks depends on them:
    there only the samples both identities agree on are kept, the others count as
    ambiguous, with the nearer of their two lines as their doubt.
    """
    edges = in_image_order(bands)
    full, first, passed = _unique(peaks, bands, edges, sep, prior, aligned, None)
    weak_peaks = weak(peaks) & (peaks >= 0)
    if not weak_peaks.any():
        return full
    strong, _ = set_aside(peaks, weak_peaks)
    # columns where no peak is weak keep their peaks: where the identity chooses the same
    # rows again, their rival test without continuity is the one just made
    alone, _, _ = _unique(strong, bands, edges, sep, prior, aligned,
                          (first, passed, np.asarray(~weak_peaks.any(axis=0))))
    rows = full.rows  # each row one of ``peaks``: whether it is weak is looked up
    kept, lost, row, col, line = rivals_kernels.stable(
        rows, alone.rows,
        rivals_kernels.strong_rows(np.ascontiguousarray(peaks, dtype=np.int64), weak_peaks,
                                   np.ascontiguousarray(rows, dtype=np.int64)),
        image_positions(edges[2]))
    doubt_row, doubt_col, doubt_line = (np.concatenate(parts) for parts in zip(
        (full.doubt_row, full.doubt_col, full.doubt_line), (row, col, line),
        (alone.doubt_row, alone.doubt_col, alone.doubt_line), strict=True))
    return Identity(kept, full.unsure + lost, doubt_row, doubt_col, doubt_line,
                    full.tied & (kept >= 0))


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


def _unique(peaks: IntArray, bands: tuple[Band, ...],
            edges: tuple[IntArray, IntArray, IntArray], sep: int,
            prior: VisibilityPrior | None, aligned: bool,
            earlier: tuple[IntArray, FirstPass, BoolArray] | None
            ) -> tuple[Identity, IntArray, FirstPass]:
    """:func:`identify_lines` then :func:`unique_identity` (starting from the prior's
    counts the identity took). Peaks the rival test removed keep their nearest rival as
    doubt; peaks the greedy matchings could not place, the lowest band that holds them.
    Also returns the (K, W) identity before the rival test and the test's result without
    continuity, for a later identity of the same map (``earlier``: those two and (W,)
    the columns where its peaks are these).
    ``edges``: the bands in image order (:func:`in_image_order`)."""
    first, unsure, counted = identify_counted(peaks, bands, sep, prior, aligned=aligned,
                                              edges=edges)
    first = np.ascontiguousarray(first, dtype=np.int64)
    reuse = None
    if earlier is not None:
        same = earlier[2] & (first == earlier[0]).all(axis=0)
        reuse = (earlier[1], same)
    rows, nearest, passed = _unique_rows(peaks, edges, first, prior, reuse, counted)
    unsure, doubt_row, doubt_col, doubt_line = rivals_kernels.doubts(
        np.ascontiguousarray(peaks, dtype=np.int64), first, rows, nearest,
        np.ascontiguousarray(unsure, dtype=np.int64), *edges)
    # the rival test's first pass keeps, per peak with a rival, the line among the chosen
    # and its rivals that puts it nearest: the chosen one itself when every rival is
    # farther
    tied = (passed.ambiguous == np.arange(rows.shape[0])[:, None]) & (rows >= 0)
    return Identity(rows, unsure, doubt_row, doubt_col, doubt_line, tied), first, passed


def set_aside(peaks: IntArray, drop: BoolArray) -> tuple[IntArray, IntArray]:
    """``peaks`` without the ``drop`` ones, each column sorted down with the -1 padding
    last (as the greedy matchings expect), and the (W,) count dropped."""
    return rivals_kernels.set_aside(np.ascontiguousarray(peaks, dtype=np.int64),
                                    np.ascontiguousarray(drop, dtype=np.bool_))


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
    spacing higher in the image: a phantom at 1.4 m for a wall at 5.7 m). Nor is it for
    a stripe alone in its column (one line's row at most): every line explains it at its
    own range, and lying on one line's median row says only that another surface shows
    that line there (five sheets merged into one stripe on a box top 3 cm below the
    camera lay on line 0's median and read 1.50 m, the farthest of their readings, for
    1.09 m). Nor for a line the column does not hold, unless every line it holds has a
    reference: the median of a left-out line only prices the rival that gives that line
    a peak, and with no held line tied to a surface it would settle the tie alone (a far
    comb of three with its lowest line lost on the ground, its held lines between
    anchors that disagree: line 0's median from nearer surfaces took it one line low,
    2.6 m for 3.66 m); with one held stripe untied it prices only the rival that hands
    that stripe the left-out line, the chosen line paying nothing (a hanging sphere's
    one stripe, the ground lines under it tied to their neighbours: line 0's median
    from a pole and boxes 1.3-1.4 m away took it one line down, 1.45 m for 4.10 m)."""
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    return np.asarray(rivals_kernels.continuity(
        rows, np.ascontiguousarray(anchored, dtype=np.bool_),
        np.arange(rows.shape[1], dtype=np.int64), CONTINUITY_REACH, CONTINUITY_BLOCK,
        MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES, BRIDGE_PX, MEDIAN_PX))


def warm_up() -> None:
    """Type the kernels' arguments once (the first map does not wait for it)."""
    rivals_kernels.warm_up()
    band = Band(0, 0, 4)
    unique_identity(np.array([[1], [-1]], dtype=np.int64), (band,),
                    np.array([[1]], dtype=np.int64), None)
