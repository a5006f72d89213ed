"""Overflow-safe accumulators and the chunked updates of the demodulators."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import types

from atris_node.errors import DemodulationError
from atris_node.jit import kernel

Array = npt.NDArray[np.generic]
#: accumulator bytes per chunk of a block update, which streams two arrays (accumulator,
#: sub-frame); measured best at 2048x1088 among 64..512 KiB
CHUNK_BYTES = 256 * 1024
#: accumulator bytes per chunk of a sliding update: the compiled update goes row by row,
#: the chunks are the units of its full-scale bookkeeping (the saturation counts are
#: updated only in chunks that hold a pixel at full scale)
SLIDE_CHUNK_BYTES = 128 * 1024
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


def _slide_signatures() -> list[Any]:
    """(out, prev, new, old, sign, chunk_rows, tops) for int16 and int32 sums of uint8 and
    uint16 sub-frames, all C-contiguous; the inputs read-only or not."""
    def c2(dtype: types.Type, readonly: bool = True) -> types.Array:
        return types.Array(dtype, 2, "C", readonly=readonly)
    return [types.void(c2(acc, False), c2(acc), c2(px), c2(px), types.int64, types.int64,
                       types.Array(types.int64, 1, "C"))
            for acc in (types.int16, types.int32) for px in (types.uint8, types.uint16)]


@kernel(_slide_signatures())
def _slide_rows(out: Array, prev: Array, new: Array, old: Array, sign: int,
                chunk_rows: int, tops: npt.NDArray[np.int64]) -> None:  # pragma: no cover
    """``out = prev + sign * (new - old)`` row by row, the maximum of the raw ``new`` pixels
    of each chunk of ``chunk_rows`` rows into ``tops``: each row's maximum is taken first
    (the row then stays in L1 for the update); one call per sub-frame, without the GIL."""
    height = new.shape[0]
    step = np.int32(sign)
    for c in range(tops.size):
        top = 0
        for r in range(c * chunk_rows, min((c + 1) * chunk_rows, height)):
            o, p, n, q = out[r], prev[r], new[r], old[r]
            top = max(top, n.max())
            for x in range(n.size):
                o[x] = p[x] + step * (np.int32(n[x]) - np.int32(q[x]))
        tops[c] = top


class Kernels:
    """Chunked updates for one accumulator dtype and frame shape.

    Each chunk of rows is loaded once into cache; there it is summed, its maximum is taken
    and, only if that maximum is full scale, ``enter`` marks its saturated pixels. Each
    update returns the frame's maximum and the indices of its full-scale chunks. A chunk
    holds ``chunk_bytes`` of accumulator (at least one row).
    """

    def __init__(self, dtype: np.dtype[np.signedinteger], shape: tuple[int, int],
                 full_scale: int, chunk_bytes: int = CHUNK_BYTES) -> None:
        self.dtype = dtype
        self.shape = shape
        self.full_scale = full_scale
        rows = max(1, chunk_bytes // (shape[1] * dtype.itemsize))
        self.chunks = [slice(r, min(r + rows, shape[0])) for r in range(0, shape[0], rows)]

    def signed(self, frame: Array) -> Array:
        """The frame as the accumulator adds it: int16 view of uint16 when exact."""
        if self.dtype == np.int16 and frame.dtype == np.uint16:
            return frame.view(np.int16)
        return frame

    def _check(self, rows: slice, chunk: Array, enter: ChunkHook | None) -> int:
        top = int(np.maximum.reduce(chunk, None))
        if top == self.full_scale and enter is not None:
            enter(rows, chunk)
        return top

    def _hot(self, tops: list[int]) -> tuple[int, tuple[int, ...]]:
        peak = max(tops)
        if peak < self.full_scale:
            return peak, ()
        return peak, tuple(i for i, t in enumerate(tops) if t >= self.full_scale)

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
        """``out = prev + sign * (new - old)``; ``hooks`` = (enter new, leave old) chunk.

        One compiled pass (:func:`_slide_rows`, the GIL released): per row, the maximum of
        the raw ``new`` pixels, then the update while the row is cached (sub-frames that
        are not C-contiguous are copied first; ``out`` and ``prev`` must be). Then ``enter``
        marks the new sub-frame's chunks at full scale and ``leave`` unmarks the old one's.
        For pixels in 0..F nothing overflows: ``|new - old| <= F`` and the result is a
        window sum, within ``N/2 * F``, which :func:`accumulator_dtype` holds; a pixel above
        F may wrap, but it is in the returned maximum and the caller refuses the sub-frame.
        """
        old_frame, old_hot = old
        tops = np.empty(len(self.chunks), dtype=np.int64)
        _slide_rows(out, prev, np.ascontiguousarray(new), np.ascontiguousarray(old_frame),
                    sign, self.chunks[0].stop, tops)
        peak, hot = self._hot(tops.tolist())
        if hooks is not None:
            enter, leave = hooks
            for i in hot:
                if tops[i] == self.full_scale:
                    enter(self.chunks[i], new[self.chunks[i]])
            for i in old_hot:
                leave(self.chunks[i], old_frame[self.chunks[i]])
        return peak, hot
