"""A still stripe keeps its line: an identity that changes under a stripe that has not
moved is no evidence of either.

Maps follow each other N sub-frames apart (a few tens of milliseconds). A stripe that lies
on the same row of a column in two consecutive maps, within STILL_PX, lies on the same
surface at the same range: it is the same line's. When the identity of the later map gives
it another line than the earlier one did, one of the two is wrong, and nothing in the
column says which: light from another unit that beats with the code can add stripes in
one map that complete a comb shifted by whole lines (a retro-reflective wall's line 0 at
6.2 m taken for line 2 at 0.56 m, under two stripes of a same-code unit strobing at
another chip rate). Such a column is a doubt at both lines' ranges, with every sample in
it (its comb is the one in question), not a point.

A line given instead of another whose sheet puts the stripe at about the same range
(within the sector verdicts' doubt margin, max(10 %, 20 cm): near-parallel sheets, a
clipped pair whose two stripes trade lines) changes no distance and is no conflict
(:func:`conflicts`). A stripe that moved keeps nothing: a line whose stripe moved by a
whole line spacing between maps onto another line's row (a surface closing fast at close
range) makes its column a doubt for one map, which is INVALID, not wrong. The first map,
and columns where the earlier map kept no sample, are not asked. Units: rows in px
(float64), (K, W) arrays by line and column, NaN where a line has no sample; depths in m.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel
from atris_node.pipeline.geometry import Points
from atris_node.pipeline.peaks import LineSamples
from atris_node.pipeline.verdicts import DOUBT_ABS_M, DOUBT_REL

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

#: px; a stripe within this many rows of where it was a map earlier has not moved
STILL_PX = 1.0


def rows_by_line(samples: LineSamples, lines: int, width: int) -> FloatArray:
    """(K, W) float64 the row (px) of each line's sample in each column, NaN where none."""
    out = np.full((lines, width), np.nan)
    col = np.clip(np.rint(samples.col_px).astype(np.int64), 0, width - 1)
    out[samples.line.astype(np.int64), col] = samples.row_px
    return out


def flipped(samples: LineSamples, earlier: FloatArray | None) -> tuple[BoolArray, IntArray]:
    """(n,) True for the samples whose row held another line's sample in the ``earlier``
    map (:func:`rows_by_line`; None: no earlier map) within STILL_PX while their own line
    was not there, and (n,) that other line (the nearest in rows; -1 elsewhere). One
    compiled pass (:func:`_flipped`)."""
    n = len(samples)
    flip, before = np.zeros(n, dtype=np.bool_), np.full(n, -1, dtype=np.int64)
    if earlier is not None and n:
        _flipped(np.ascontiguousarray(samples.line, dtype=np.int64),
                 np.ascontiguousarray(samples.row_px, dtype=np.float64),
                 np.ascontiguousarray(samples.col_px, dtype=np.float64), earlier, STILL_PX,
                 flip, before)
    return flip, before


@kernel()
def _flipped(line: IntArray, row_px: FloatArray, col_px: FloatArray, earlier: FloatArray,
             still_px: float, flip: BoolArray, before: IntArray) -> None:
    """:func:`flipped` into ``flip`` and ``before`` (n,): per sample, the lines of the
    ``earlier`` (K, W) rows in its column (rounded, clipped to the image) within
    ``still_px`` of its row; NaN rows are no sample."""
    lines, width = earlier.shape
    for i in range(line.size):
        c = min(max(int(np.rint(col_px[i])), 0), width - 1)
        own = abs(earlier[line[i], c] - row_px[i]) <= still_px  # False for NaN
        best, nearest = np.inf, -1
        for k in range(lines):
            offset = abs(earlier[k, c] - row_px[i])
            if k != line[i] and offset < best:  # False for NaN; the first of equal ones
                best, nearest = offset, k
        if not own and best <= still_px:
            flip[i], before[i] = True, nearest


def warm_up() -> None:
    """Type the kernel's arguments once (the first map does not wait for it)."""
    one = np.zeros(1)
    _flipped(np.zeros(1, np.int64), one, one, np.full((1, 1), np.nan), STILL_PX,
             np.zeros(1, np.bool_), np.full(1, -1, np.int64))


def conflicts(now: Points, before: Points) -> BoolArray:
    """(n,) True where the point of a flipped sample under the line it was given (``now``)
    and under the earlier map's line (``before``, the same (n,) samples) are not the
    same obstacle: one of them invalid (outside the range), or their camera-frame depths
    further apart than max(DOUBT_REL·z, DOUBT_ABS_M) of the nearer."""
    z_now, z_before = now.xyz_m.reshape(-1, 3)[:, 2], before.xyz_m.reshape(-1, 3)[:, 2]
    nearer = np.minimum(z_now, z_before)
    apart = np.abs(z_now - z_before) > np.maximum(DOUBT_REL * nearer, DOUBT_ABS_M)
    return ~now.valid | ~before.valid | apart
