"""The two demodulators: non-overlapping block sums and the sliding window."""

from __future__ import annotations

import collections

import numpy as np
import numpy.typing as npt

from atris_node.demod.base import Demodulator
from atris_node.demod.kernels import SLIDE_CHUNK_BYTES, Array, Kernels
from atris_node.demod.pending import Info, PendingMap
from atris_node.types import SubFrame


class BlockDemodulator(Demodulator):
    """Paper §3: ``D = sum_(i<N) v_i F_i`` over non-overlapping windows of N sub-frames."""

    def _clear_window(self) -> None:
        self._acc: Array | None = None
        self._mask: npt.NDArray[np.bool_] | None = None
        self._infos: list[Info] = []
        self._frames: list[Array] = []

    def _add(self, sub: SubFrame, level: float | None) -> PendingMap | None:
        kernels, frame = self._kernels_for(sub.pixels), sub.pixels
        sign = self._sign(sub.sequence)
        if self._acc is None:
            self._acc = np.empty(frame.shape, dtype=self._dtype)
            update = kernels.start(self._acc, frame, sign, self._mark)
        else:
            update = kernels.add(self._acc, frame, sign, self._mark)
        self._infos.append(self._info(sub, level, update))
        self._frames.append(frame)
        if len(self._infos) < self._n:
            return None
        result = self._complete(self._acc, self._mask, self._infos, frame, self._frames)
        off = [(i.sequence, f) for i, f in zip(self._infos, self._frames, strict=True)
               if i.sign < 0]
        self._clear_window()
        self._before = off[-1] if off else None
        return result

    def _mark(self, rows: slice, chunk: Array) -> None:
        if self._mask is None:
            assert self._acc is not None
            self._mask = np.zeros(self._acc.shape, dtype=bool)
        target = self._mask[rows]
        np.logical_or(target, chunk == self._full_scale, out=target)


class SlidingDemodulator(Demodulator):
    """``D_t = D_(t-1) + v_(t mod N) (F_t - F_(t-N))``: a map every sub-frame once primed.

    Priming sums the first N sub-frames as the block demodulator does; then each sub-frame
    replaces the one N sub-frames older. Any N consecutive chips are a full code period, so
    ambient and orthogonal interferers cancel as in the block sum. Pixels at full scale are
    counted per pixel over the ring, only in the row chunks that hold any.
    """

    _chunk_bytes = SLIDE_CHUNK_BYTES

    def _clear_window(self) -> None:
        self._ring: collections.deque[tuple[Array, Info]] = collections.deque(maxlen=self._n)
        self._values: Array | None = None
        self._count: npt.NDArray[np.uint16] | None = None
        self._hot_frames: collections.Counter[int] = collections.Counter()

    def _add(self, sub: SubFrame, level: float | None) -> PendingMap | None:
        kernels, frame = self._kernels_for(sub.pixels), sub.pixels
        sign = self._sign(sub.sequence)
        if self._values is None:
            self._values = np.empty(frame.shape, dtype=self._dtype)
            update = kernels.start(self._values, frame, sign, self._enter)
        elif len(self._ring) < self._n:
            update = kernels.add(self._values, frame, sign, self._enter)
        else:
            return self._slide(sub, level, kernels)
        self._push_ring(frame, self._info(sub, level, update))
        if len(self._ring) < self._n:
            return None
        return self._complete(self._values, self._mask(), [i for _, i in self._ring], frame,
                              [f for f, _ in self._ring])

    def _slide(self, sub: SubFrame, level: float | None, kernels: Kernels) -> PendingMap:
        assert self._values is not None
        old_frame, old_info = self._ring[0]
        out = np.empty(sub.pixels.shape, dtype=self._dtype)
        update = kernels.slide(out, self._values, sub.pixels, (old_frame, old_info.hot_chunks),
                               self._sign(sub.sequence), (self._enter, self._leave))
        self._hot_frames.subtract(old_info.hot_chunks)
        if old_info.sign < 0:
            self._before = (old_info.sequence, old_frame)
        self._push_ring(sub.pixels, self._info(sub, level, update))
        self._values = out
        return self._complete(out, self._mask(), [i for _, i in self._ring], sub.pixels,
                              [f for f, _ in self._ring])

    def _push_ring(self, frame: Array, info: Info) -> None:
        self._ring.append((frame, info))
        self._hot_frames.update(info.hot_chunks)

    def _enter(self, rows: slice, chunk: Array) -> None:
        if self._count is None:
            self._count = np.zeros(self._kernels_shape(), dtype=np.uint16)
        target = self._count[rows]
        np.add(target, chunk == self._full_scale, out=target)

    def _leave(self, rows: slice, chunk: Array) -> None:
        assert self._count is not None
        target = self._count[rows]
        np.subtract(target, chunk == self._full_scale, out=target)

    def _kernels_shape(self) -> tuple[int, int]:
        assert self._kernels is not None
        return self._kernels.shape

    def _mask(self) -> npt.NDArray[np.bool_] | None:
        hot = [i for i, frames in self._hot_frames.items() if frames > 0]
        if not hot or self._count is None or self._kernels is None:
            return None
        mask = np.zeros(self._count.shape, dtype=bool)
        for i in hot:
            rows = self._kernels.chunks[i]
            np.greater(self._count[rows], 0, out=mask[rows])
        return mask
