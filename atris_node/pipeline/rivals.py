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
rows, a line skipped, a peak left spare, a row past z_max) plus the visibility prior's
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
column resolved in one round anchors the next. A peak that still has a rival is dropped and
counted ambiguous: the sectors it falls in cannot be VALID or NO_RETURN.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.pipeline import identity_kernels, rivals_kernels
from atris_node.pipeline.bands import Band, in_image_order
from atris_node.pipeline.identity import (
    _COSTS,
    CONTINUITY_BLOCK,
    MIN_BLOCK_SAMPLES,
    MIN_LINE_SAMPLES,
    SWITCH_PX,
    VisibilityPrior,
    beyond_rows,
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
CONTINUITY_ROUNDS = 8


def unique_identity(peaks: IntArray, bands: tuple[Band, ...], rows: IntArray,
                    prior: VisibilityPrior | None) -> tuple[IntArray, BoolArray]:
    """The identity ``rows`` (K, W) by line (-1 = none) with every sample that has a rival
    removed, and the (K, W) mask of those samples (by line, at their chosen line).

    Args:
        peaks: (M, W) int64 peak rows per column, -1 = none, any order.
        bands: one :class:`Band` per line.
        rows: (K, W) int64, the identity chosen so far (:func:`identify_lines`).
        prior: the visibility prior; without it only bands, order and continuity count.
    """
    lo, hi, order = in_image_order(bands)
    peaks = np.ascontiguousarray(peaks, dtype=np.int64)
    rows = np.array(rows, dtype=np.int64, order="C")
    shape = rows.shape
    ambiguous = np.zeros(shape, dtype=np.bool_)
    beyond = beyond_rows(prior, order)
    loose = np.full(shape, np.inf)  # pass 1: no continuity, never adopts
    _test(peaks, (lo, hi, order), rows, ambiguous, _has_peaks(rows), loose, beyond, prior,
          adopt=False)
    left = -1
    for _ in range(CONTINUITY_ROUNDS):
        anchored = np.asarray(~ambiguous.any(axis=0), dtype=np.bool_)
        again = np.flatnonzero(~anchored)
        if again.size in (0, left):
            break  # all anchored, or the last round anchored nothing new
        left = again.size
        ref = _reference(rows, anchored)
        ambiguous[:, again] = False
        _test(peaks, (lo, hi, order), rows, ambiguous, again, ref[order], beyond, prior,
              adopt=True)
    rows[ambiguous] = -1
    return rows, ambiguous


def stripe_peaks(peaks: IntArray, reach: int = LONE_REACH, max_step: int = LONE_STEP_PX
                 ) -> tuple[IntArray, IntArray]:
    """``peaks`` (M, W) without the isolated ones (-1 in their place) and the (W,) count
    removed per column. A stripe continues into a neighbouring column within ``max_step``
    rows; a maximum that does not is noise or a sliver too thin to identify, and must not
    anchor a comb. The count stays evidence: such a column is not free."""
    peaks = np.ascontiguousarray(peaks, dtype=np.int64)
    lone = rivals_kernels.isolated(peaks, reach, max_step)
    return np.where(lone, -1, peaks), lone.sum(axis=0).astype(np.int64)


def _has_peaks(rows: IntArray) -> IntArray:
    """(n,) int64 columns where some line took a peak."""
    return np.flatnonzero((rows >= 0).any(axis=0)).astype(np.int64)


def _reference(rows: IntArray, anchored: BoolArray) -> npt.NDArray[np.float64]:
    """(K, W) continuity reference by line: the row in the nearest anchored column within
    CONTINUITY_REACH; where there is none, the median of the anchored rows of the line in
    the column's block of CONTINUITY_BLOCK columns (or of the whole line), inf where
    neither exists."""
    local = rivals_kernels.local_reference(rows, anchored, CONTINUITY_REACH)
    good = np.ascontiguousarray((rows >= 0) & anchored[None, :])
    wide = identity_kernels.continuity_reference(rows, good, CONTINUITY_BLOCK,
                                                 MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES)
    return np.where(np.isfinite(local), local, wide)


def _test(peaks: IntArray, edges: tuple[IntArray, IntArray, IntArray], rows: IntArray,
          ambiguous: BoolArray, columns: IntArray, ref: npt.NDArray[np.float64],
          beyond: npt.NDArray[np.float64], prior: VisibilityPrior | None, *,
          adopt: bool) -> None:
    """One pass of the compiled rival test over ``columns`` (in place)."""
    lo, hi, order = edges
    rivals_kernels.rivals(peaks, lo, hi, order.astype(np.int64), rows, ambiguous,
                          np.ascontiguousarray(columns, dtype=np.int64),
                          np.ascontiguousarray(ref, dtype=np.float64), beyond,
                          RIVAL_MARGIN_PX, _COSTS, adopt, *prior_arrays(prior, rows.shape))


def warm_up() -> None:
    """Type the kernel's arguments once (the first map does not wait for it)."""
    band = Band(0, 0, 4)
    unique_identity(np.array([[1], [-1]], dtype=np.int64), (band,),
                    np.array([[1]], dtype=np.int64), None)
