"""A complete window, and the distortion map built from it when a consumer takes it.

In sliding mode a window completes on every sub-frame (600 a second for the paper's
camera), while a consumer (the map thread) takes only the maps it keeps up with. So the
demodulator hands out a :class:`PendingMap`: what the map is made of, fixed when its window
completed (its sums, its saturation mask, the window's sub-frames and their records, the
lag, the sub-frames dropped before it). :meth:`PendingMap.take` builds the
:class:`~atris_node.types.DistortionMap` and measures its gain, SNR and ambient level then,
on the consumer's thread; the values are those the demodulator would have given at once.

A map that nobody takes costs no statistics.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.demod.kernels import Array
from atris_node.demod.stats import measure_gain, strip_level
from atris_node.types import DistortionMap, WindowFrames


@dataclass(frozen=True)
class Info:
    """What a window keeps of one sub-frame besides its pixels."""

    sequence: int
    host_time_s: float
    sign: int
    hot_chunks: tuple[int, ...]  # row chunks holding a pixel at full scale
    level: float | None  # mean raw level of the sampled strips, DN (when locking)

    @property
    def saturated(self) -> bool:
        """True when some pixel of the sub-frame is at full scale."""
        return bool(self.hot_chunks)


def window_frames(frames: Sequence[Array], infos: Sequence[Info],
                  before: tuple[int, Array] | None) -> WindowFrames | None:
    """The window's sub-frames and signs, when every one of them is at hand, and the last
    OFF sub-frame before it (``before``: sequence, pixels) when that is near enough."""
    if len(frames) != len(infos) or not frames:
        return None
    first = infos[0].sequence
    prior = None
    if before is not None and -len(infos) <= before[0] - first < 0:
        prior = (before[0] - first, before[1])
    return WindowFrames(tuple(frames), tuple(i.sign for i in infos), prior)


class AmbientLevel:
    """The mean raw level (DN) of one sub-frame's sampled strips, measured when first read.

    Maps of the same N sub-frames share one (the demodulator refreshes it once per N)."""

    __slots__ = ("_level", "_pixels")

    def __init__(self, pixels: Array) -> None:
        self._pixels = pixels
        self._level: float | None = None

    def dn(self) -> float:
        if self._level is None:
            self._level = strip_level(self._pixels)
        return self._level


@dataclass(frozen=True)
class Window:
    """What a map is made of, fixed when its window completed.

    ``saturated`` is None when no sub-frame of the window had a pixel at full scale (the
    map then carries ``clear``, the demodulator's all-False mask); ``ambient`` is the
    window's strip level when the sub-frames' own levels were not taken (lag known)."""

    values: Array
    saturated: npt.NDArray[np.bool_] | None
    clear: npt.NDArray[np.bool_]
    infos: tuple[Info, ...]
    frames: tuple[Array, ...]
    before: tuple[int, Array] | None
    code_length: int
    full_scale: int
    phase: int
    dropped: int
    exposure_us: float
    ambient: AmbientLevel | None


def _ambient_dn(window: Window) -> float:
    if window.ambient is None:
        return statistics.fmean([i.level for i in window.infos if i.level is not None])
    return window.ambient.dn()


def build_map(window: Window) -> DistortionMap:
    """The distortion map of ``window``, its gain, SNR and ambient level measured."""
    values, saturated = window.values, window.saturated
    mask = window.clear if saturated is None else saturated
    fraction = 0.0 if saturated is None else np.count_nonzero(mask) / mask.size
    gain, snr, signal, residual = measure_gain(values, window.code_length)
    infos = window.infos
    return DistortionMap(
        values=values, saturated=mask, code_length=window.code_length,  # type: ignore[arg-type]
        first_sequence=infos[0].sequence, last_sequence=infos[-1].sequence,
        first_time_s=infos[0].host_time_s, last_time_s=infos[-1].host_time_s,
        phase=window.phase, dropped=window.dropped, processing_gain=gain, snr=snr,
        extra={"ambient_level": _ambient_dn(window) / window.full_scale,
               "saturated_fraction": float(fraction),
               "signal_dn": signal, "residual_dn": residual},
        window=window_frames(window.frames, infos, window.before),
        exposure_us=window.exposure_us)


class PendingMap:
    """A complete window; :meth:`take` builds its distortion map (once).

    One consumer takes a pending map (the map thread, or the loop without one).
    """

    __slots__ = ("_map", "window")

    def __init__(self, window: Window) -> None:
        self.window = window
        self._map: DistortionMap | None = None

    @property
    def dropped(self) -> int:
        """Sub-frames lost since the previous complete window."""
        return self.window.dropped

    @property
    def phase(self) -> int:
        """The strobe lag the window was demodulated with."""
        return self.window.phase

    @property
    def code_length(self) -> int:
        """N, the sub-frames summed."""
        return self.window.code_length

    @property
    def first_sequence(self) -> int:
        """Sequence number of the window's oldest sub-frame."""
        return self.window.infos[0].sequence

    @property
    def last_sequence(self) -> int:
        """Sequence number of the window's newest sub-frame."""
        return self.window.infos[-1].sequence

    def take(self) -> DistortionMap:
        """The distortion map, built and measured on the first call."""
        if self._map is None:
            self._map = build_map(self.window)
        return self._map
