"""Overflow-safe accumulators and the chunked updates of the demodulators."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from atris_node.errors import DemodulationError

Array = npt.NDArray[np.generic]
#: accumulator bytes processed per chunk (fits the L2 cache with its sub-frame rows)
CHUNK_BYTES = 256 * 1024
INT16_MAX = int(np.iinfo(np.int16).max)


def accumulator_dtype(code_length: int, bits: int) -> np.dtype[np.signedinteger]:
    """int16 when ``code_length * (2**bits - 1) <= 32767``, else int32.

    ``bits`` is the sub-frame bit depth, 8..16. Raises DemodulationError otherwise.
    """
    _check_bits(bits)
    if code_length < 2:
        raise DemodulationError(f"code length {code_length} is too short; accepted: >= 2")
    if code_length * ((1 << bits) - 1) <= INT16_MAX:
        return np.dtype(np.int16)
    return np.dtype(np.int32)


def _check_bits(bits: int) -> None:
    if isinstance(bits, bool) or not isinstance(bits, int) or not 8 <= bits <= 16:
        raise DemodulationError(f"bit depth {bits!r} is not supported; accepted: 8..16")


#: called with (row slice, sub-frame rows) for a chunk that holds a pixel at full scale
ChunkHook = Callable[[slice, Array], None]


class Kernels:
    """Chunked updates for one accumulator dtype and frame shape.

    Each chunk of rows is loaded once into cache; there it is summed, its maximum is taken
    and, only if that maximum is full scale, ``enter`` marks its saturated pixels. Each
    update returns the frame's maximum and the indices of its full-scale chunks.
    """

    def __init__(self, dtype: np.dtype[np.signedinteger], shape: tuple[int, int],
                 full_scale: int) -> None:
        self.dtype = dtype
        self.shape = shape
        self.full_scale = full_scale
        rows = max(1, CHUNK_BYTES // (shape[1] * dtype.itemsize))
        self.chunks = [slice(r, r + rows) for r in range(0, shape[0], rows)]
        self._diff = np.empty((rows, shape[1]), dtype=dtype)

    def signed(self, frame: Array) -> Array:
        """The frame as the accumulator adds it: int16 view of uint16 when exact."""
        if self.dtype == np.int16 and frame.dtype == np.uint16:
            return frame.view(np.int16)
        return frame

    def _check(self, rows: slice, chunk: Array, enter: ChunkHook | None) -> int:
        top = int(chunk.max())
        if top == self.full_scale and enter is not None:
            enter(rows, chunk)
        return top

    def _hot(self, tops: list[int]) -> tuple[int, tuple[int, ...]]:
        return max(tops), tuple(i for i, t in enumerate(tops) if t >= self.full_scale)

    def start(self, out: Array, frame: Array, sign: int,
              enter: ChunkHook | None = None) -> tuple[int, tuple[int, ...]]:
        """``out = sign * frame``."""
        src, tops = self.signed(frame), []
        for rows in self.chunks:
            if sign > 0:
                np.copyto(out[rows], src[rows], casting="safe")
            else:
                np.negative(src[rows], out=out[rows], dtype=self.dtype)
            tops.append(self._check(rows, frame[rows], enter))
        return self._hot(tops)

    def add(self, acc: Array, frame: Array, sign: int,
            enter: ChunkHook | None = None) -> tuple[int, tuple[int, ...]]:
        """``acc += sign * frame``."""
        src, tops = self.signed(frame), []
        op = np.add if sign > 0 else np.subtract
        for rows in self.chunks:
            chunk = acc[rows]
            op(chunk, src[rows], out=chunk, dtype=self.dtype)
            tops.append(self._check(rows, frame[rows], enter))
        return self._hot(tops)

    def slide(self, out: Array, prev: Array, new: Array, old: tuple[Array, tuple[int, ...]],
              sign: int, hooks: tuple[ChunkHook, ChunkHook] | None = None
              ) -> tuple[int, tuple[int, ...]]:
        """``out = prev + sign * (new - old)``; ``hooks`` = (enter new, leave old) chunk."""
        old_frame, old_hot = old
        src_new, src_old, tops = self.signed(new), self.signed(old_frame), []
        op = np.add if sign > 0 else np.subtract
        enter, leave = hooks if hooks is not None else (None, None)
        for i, rows in enumerate(self.chunks):
            target = out[rows]
            diff = self._diff[: target.shape[0]]
            np.subtract(src_new[rows], src_old[rows], out=diff, dtype=self.dtype)
            op(prev[rows], diff, out=target)
            tops.append(self._check(rows, new[rows], enter))
            if leave is not None and i in old_hot:
                leave(rows, old_frame[rows])
        return self._hot(tops)
