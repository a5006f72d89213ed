"""Block and sliding demodulation of strobed sub-frames into distortion maps (paper §3, §5).

Sub-frame ``seq`` is multiplied by the sign ``v[(seq - lag) % N]`` of the code's bipolar
form and summed over N consecutive sub-frames: ambient light, slow drift and other units
strobing orthogonal codes cancel, the own laser adds up to ``l * N / 2``.

- :class:`BlockDemodulator` sums non-overlapping windows: one map every N sub-frames.
- :class:`SlidingDemodulator` updates ``D_t = D_(t-1) + v_t (F_t - F_(t-N))``: one map per
  sub-frame once primed, for a ring of N sub-frame references.

Both track sequence numbers (a gap re-primes the window and is counted, so a map never
mixes signs), re-prime on an exposure or frame-shape change (counted; a new shape is
accepted, not an error), flag pixels at full scale, lock to an unknown strobe lag by
correlation (``lag=None``), and measure processing gain and SNR (paper Eq. 5-6) of each
map, with ``extra`` keys ``ambient_level`` and ``saturated_fraction`` (fractions) and
``signal_dn`` and ``residual_dn`` (``I_S`` and ``delta``). ``push`` returns the map;
``push_pending`` a :class:`PendingMap` whose map, the same to the bit, is built and
measured when a consumer takes it (a sliding map nobody takes costs no statistics).

Constant ambient light cancels exactly (balanced codes). A linear drift ``d`` per
sub-frame leaves the paper's remainder ``delta = d * sum_i v_i i``: zero for Walsh rows
whose 0-based index has two or more bits set (rows 4, 6, 7, 8, ...), ``-d N 2^j / 2`` for
the rows 2, 3, 5, 9, ... (index ``2^j``).

Accumulators are int16 when ``N * (2**bits - 1) <= 32767``, else int32, so no sum can
overflow; uint16 sub-frames are added through an int16 view when the accumulator is
int16 (values below 2**15 read the same), never cast. Work is done in row chunks that
stay in cache (CHUNK_BYTES, SLIDE_CHUNK_BYTES of accumulator), so the full-scale check
reads pixels the arithmetic has just loaded; it reads the raw pixels, so a value above
full scale is refused even where its int16 view is negative. The sliding update is one
compiled call per sub-frame (numba, the GIL released), row by row.

Ownership: the demodulators keep references to pushed pixel arrays (no copy); a camera
backend must hand over a fresh array per sub-frame and not write into it afterwards.
Returned map arrays are read-only.

Example:
    >>> import numpy as np
    >>> from atris_node.types import SubFrame
    >>> demod = BlockDemodulator([1, 0, 1, 0], bits=8)
    >>> maps = [demod.push(SubFrame(np.full((2, 3), 10 + 5 * (s % 2 == 0), np.uint8),
    ...                             s, 0.0, 0.0, 100.0)) for s in range(4)]
    >>> maps[-1].values.tolist()
    [[10, 10, 10], [10, 10, 10]]
"""


from __future__ import annotations

from atris_node.demod.base import Demodulator
from atris_node.demod.kernels import CHUNK_BYTES, SLIDE_CHUNK_BYTES, Kernels, accumulator_dtype
from atris_node.demod.lock import LOCK_HISTORY, LOCK_SIGMAS, PhaseLock
from atris_node.demod.pending import PendingMap
from atris_node.demod.stats import (
    RESIDUAL_FLOOR_DN,
    STRIP_POSITIONS,
    STRIP_WIDTH,
    measure_gain,
    strip_level,
    strip_sample,
)
from atris_node.demod.windows import BlockDemodulator, SlidingDemodulator

__all__ = [
    "CHUNK_BYTES",
    "LOCK_HISTORY",
    "LOCK_SIGMAS",
    "RESIDUAL_FLOOR_DN",
    "SLIDE_CHUNK_BYTES",
    "STRIP_POSITIONS",
    "STRIP_WIDTH",
    "BlockDemodulator",
    "Demodulator",
    "Kernels",
    "PendingMap",
    "PhaseLock",
    "SlidingDemodulator",
    "accumulator_dtype",
    "measure_gain",
    "strip_level",
    "strip_sample",
]
