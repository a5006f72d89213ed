"""What both demodulators share: validation, sequence tracking, phase lock, the pending map
of a complete window."""

from __future__ import annotations

import collections
import logging
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from atris_node import codes
from atris_node.demod.kernels import CHUNK_BYTES, Array, Kernels, accumulator_dtype
from atris_node.demod.lock import PhaseLock
from atris_node.demod.pending import AmbientLevel, Info, PendingMap, Window
from atris_node.demod.stats import strip_level
from atris_node.errors import CodeError, DemodulationError
from atris_node.types import DistortionMap, SubFrame

logger = logging.getLogger(__name__)


def _check_chips(chips: Sequence[int] | npt.NDArray[np.integer]) -> npt.NDArray[np.int8]:
    signs = codes.bipolar(chips)
    if not codes.is_balanced(chips):
        raise CodeError(
            f"code {codes.chips_string(chips)} is not balanced; ambient light would not "
            "cancel; accepted: as many 1 chips as 0 chips"
        )
    return signs


class Demodulator:
    """Validation, sequence tracking, phase lock and the pending maps of both demodulators."""

    def __init__(self, chips: Sequence[int] | npt.NDArray[np.integer], bits: int,
                 lag: int | None = 0) -> None:
        self._signs = _check_chips(chips)
        self._n = int(self._signs.size)
        self._dtype = accumulator_dtype(self._n, bits)
        self._bits = bits
        self._full_scale = (1 << bits) - 1
        self._pixel_dtype = np.dtype(np.uint8 if bits == 8 else np.uint16)
        self._auto = lag is None
        self._lag = None if lag is None else int(lag) % self._n
        self._lock = PhaseLock(self._signs)
        self._pending: collections.deque[tuple[SubFrame, float | None]] = collections.deque(
            maxlen=self._n)
        self._last: SubFrame | None = None
        self._kernels: Kernels | None = None
        self._dropped_total = self._exposure_changes = self._shape_changes = 0
        self._relocks = self._dropped_since_map = 0
        self._clear_window()

    # --- public ------------------------------------------------------------------------

    @property
    def code_length(self) -> int:
        """N, the number of sub-frames in one window."""
        return self._n

    @property
    def accumulator(self) -> np.dtype[np.signedinteger]:
        """The dtype of the sums (see :func:`accumulator_dtype`)."""
        return self._dtype

    @property
    def lag(self) -> int | None:
        """Strobe lag in sub-frames, 0..N-1, or None while it is not yet locked."""
        return self._lag

    @property
    def locked(self) -> bool:
        """True once the lag is known (given, or found by correlation)."""
        return self._lag is not None

    @property
    def dropped_total(self) -> int:
        """Sub-frames missing from the sequence numbers since construction."""
        return self._dropped_total

    @property
    def exposure_changes(self) -> int:
        """Windows restarted because the exposure changed inside them."""
        return self._exposure_changes

    @property
    def shape_changes(self) -> int:
        """Windows restarted because the sub-frame shape changed inside them."""
        return self._shape_changes

    @property
    def relocks(self) -> int:
        """Times the lag was found to have moved and was changed (``lag=None`` only)."""
        return self._relocks

    def reset(self) -> None:
        """Forget the window, the last sequence number and (if it was found) the lag.

        The ``*_total`` and ``*_changes`` counters are kept.
        """
        self._reprime()
        self._last = None
        self._dropped_since_map = 0
        if self._auto:
            self._lag = None

    def push(self, sub: SubFrame) -> DistortionMap | None:
        """Add one sub-frame; return a map when a window is complete, else None.

        Raises DemodulationError for pixels of the wrong shape, dtype or bit depth, or
        above full scale (the window is re-primed first).
        """
        pending = self.push_pending(sub)
        return None if pending is None else pending.take()

    def push_pending(self, sub: SubFrame) -> PendingMap | None:
        """As :meth:`push`, but a complete window comes back as a :class:`PendingMap`: its
        map (the same values, measures and mask) is built when a consumer takes it, and a
        sliding map nobody takes costs no statistics."""
        self._validate(sub)
        self._follow(sub)
        self._last = sub
        level = strip_level(sub.pixels) if self._auto else None
        decided = None
        if self._auto:
            due = self._lag is None or self._lock.fresh >= self._lock.history
            decided = self._lock.feed(sub.sequence, level or 0.0, decide=due)
        if self._lag is None:
            return self._try_lock(sub, level, decided)
        self._track(decided)
        return self._add(sub, level)

    # --- sequence, exposure and shape ----------------------------------------------------

    def _validate(self, sub: SubFrame) -> None:
        pixels = sub.pixels
        if not isinstance(pixels, np.ndarray) or pixels.ndim != 2 or pixels.size == 0:
            raise DemodulationError(
                f"sub-frame {sub.sequence}: pixels must be a non-empty 2-D array (H, W), got "
                f"{getattr(pixels, 'shape', type(pixels).__name__)}")
        if sub.bits != self._bits or pixels.dtype != self._pixel_dtype:
            raise DemodulationError(
                f"sub-frame {sub.sequence}: {sub.bits}-bit {pixels.dtype} pixels; this "
                f"demodulator accepts {self._bits}-bit {self._pixel_dtype} only")

    def _follow(self, sub: SubFrame) -> None:
        last = self._last
        if last is None:
            return
        gap = sub.sequence - last.sequence - 1
        if gap != 0:
            self._count_gap(last.sequence, sub.sequence, gap)
        elif sub.exposure_us != last.exposure_us:
            self._exposure_changes += 1
            logger.info("exposure %.1f -> %.1f us at sub-frame %d: window restarted",
                        last.exposure_us, sub.exposure_us, sub.sequence)
        elif sub.pixels.shape != last.pixels.shape:
            self._shape_changes += 1
            logger.info("sub-frame shape %s -> %s at %d: window restarted",
                        last.pixels.shape, sub.pixels.shape, sub.sequence)
        else:
            return
        self._reprime()

    def _count_gap(self, last: int, sequence: int, gap: int) -> None:
        if gap > 0:
            self._dropped_total += gap
            self._dropped_since_map += gap
            logger.info("%d sub-frame(s) dropped before %d: window restarted", gap, sequence)
        else:
            logger.warning("sequence went back from %d to %d: window restarted", last, sequence)

    def _reprime(self) -> None:
        self._ambient_cache = None
        self._before = None
        self._clear_window()
        self._pending.clear()
        self._lock.reset()

    # --- phase lock ----------------------------------------------------------------------

    def _try_lock(self, sub: SubFrame, level: float | None,
                  decided: int | None) -> PendingMap | None:
        self._pending.append((sub, level))
        if decided is None:
            return None
        self._lag = decided
        self._lock.fresh = 0
        logger.info("strobe lag locked at %d sub-frame(s)", decided)
        return self._replay()

    def _replay(self) -> PendingMap | None:
        result = None
        for sub, level in self._pending:
            result = self._add(sub, level) or result
        self._pending.clear()
        return result

    def _track(self, decided: int | None) -> None:
        if not self._auto or decided is None:
            return
        if decided == self._lag:
            self._lock.fresh = 0  # confirmed; look again after a whole new history
            return
        logger.warning("strobe lag moved from %s to %d sub-frame(s): window restarted",
                       self._lag, decided)
        self._lag = decided
        self._relocks += 1
        self._lock.fresh = 0
        self._before = None
        self._clear_window()

    # --- helpers for the windows ---------------------------------------------------------

    def _sign(self, sequence: int) -> int:
        assert self._lag is not None
        return int(self._signs[(sequence - self._lag) % self._n])

    def _kernels_for(self, pixels: Array) -> Kernels:
        if self._kernels is None or self._kernels.shape != pixels.shape:
            self._kernels = Kernels(self._dtype, (pixels.shape[0], pixels.shape[1]),
                                     self._full_scale, self._chunk_bytes)
        return self._kernels

    def _info(self, sub: SubFrame, level: float | None,
              update: tuple[int, tuple[int, ...]]) -> Info:
        peak, hot_chunks = update
        if peak > self._full_scale:
            self._reprime()
            raise DemodulationError(
                f"sub-frame {sub.sequence}: pixel value {peak} above the full scale "
                f"{self._full_scale} of {self._bits}-bit data; accepted: 0..{self._full_scale}")
        return Info(sub.sequence, sub.host_time_s, self._sign(sub.sequence), hot_chunks, level)

    def _no_saturation(self, shape: tuple[int, ...]) -> npt.NDArray[np.bool_]:
        if self._clear_mask is None or self._clear_mask.shape != shape:
            self._clear_mask = np.zeros(shape, dtype=bool)
            self._clear_mask.setflags(write=False)
        return self._clear_mask

    def _ambient(self, infos: Sequence[Info], newest: Array) -> AmbientLevel | None:
        """None when every sub-frame of the window has its strip level (taken for the
        lock; the map's ambient level is their mean); with a known lag that of the newest
        sub-frame, refreshed once per N sub-frames and measured when a map is taken."""
        if all(i.level is not None for i in infos):
            return None
        last = infos[-1].sequence
        if self._ambient_cache is None or not 0 <= last - self._ambient_cache[0] < self._n:
            self._ambient_cache = (last, AmbientLevel(newest))
        return self._ambient_cache[1]

    def _complete(self, values: Array, saturated: npt.NDArray[np.bool_] | None,
                  infos: Sequence[Info], newest: Array,
                  frames: Sequence[Array] = ()) -> PendingMap:
        """The pending map of a complete window (its statistics wait for take())."""
        values.setflags(write=False)
        dropped, self._dropped_since_map = self._dropped_since_map, 0
        window = Window(
            values=values, saturated=saturated, clear=self._no_saturation(values.shape),
            infos=tuple(infos), frames=tuple(frames), before=self._before,
            code_length=self._n, full_scale=self._full_scale, phase=self._lag or 0,
            dropped=dropped, ambient=self._ambient(infos, newest),
            exposure_us=0.0 if self._last is None else float(self._last.exposure_us))
        return PendingMap(window)

    # --- per window, in the subclasses ---------------------------------------------------

    _chunk_bytes = CHUNK_BYTES  # accumulator bytes per row chunk of the updates
    _clear_mask: npt.NDArray[np.bool_] | None = None
    _ambient_cache: tuple[int, AmbientLevel] | None = None
    #: the last OFF sub-frame before the current window (sequence, pixels)
    _before: tuple[int, Array] | None = None

    def _clear_window(self) -> None:
        raise NotImplementedError

    def _add(self, sub: SubFrame, level: float | None) -> PendingMap | None:
        raise NotImplementedError
