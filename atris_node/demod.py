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
correlation (``lag=None``), and measure processing gain and SNR (paper Eq. 5-6) for every
map, with ``extra`` keys ``ambient_level`` and ``saturated_fraction`` (fractions) and
``signal_dn`` and ``residual_dn`` (``I_S`` and ``delta``).

Constant ambient light cancels exactly (balanced codes). A linear drift ``d`` per
sub-frame leaves the paper's remainder ``delta = d * sum_i v_i i``: zero for Walsh rows
whose 0-based index has two or more bits set (rows 4, 6, 7, 8, ...), ``-d N 2^j / 2`` for
the rows 2, 3, 5, 9, ... (index ``2^j``).

Accumulators are int16 when ``N * (2**bits - 1) <= 32767``, else int32, so no sum can
overflow; uint16 sub-frames are added through an int16 view when the accumulator is
int16 (values below 2**15 read the same), never cast. Work is done in row chunks that
stay in cache, so the full-scale check reads pixels the addition has just loaded.

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

import collections
import functools
import logging
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node import codes
from atris_node.errors import CodeError, DemodulationError
from atris_node.types import DistortionMap, SubFrame

logger = logging.getLogger(__name__)

Array = npt.NDArray[np.generic]
#: accumulator bytes processed per chunk (fits the L2 cache with its sub-frame rows)
CHUNK_BYTES = 128 * 1024
#: columns sampled for lock, ambient level and gain statistics: strips of this width ...
STRIP_WIDTH = 8
#: ... at these fractions of the frame width (laser lines are horizontal: every row counts)
STRIP_POSITIONS = (0.25, 0.75)
#: a lock needs the best lag this many noise standard deviations above every other lag
LOCK_SIGMAS = 6.0
#: sub-frames (rounded up to whole code periods) a lock decision looks at
LOCK_HISTORY = 32
#: smallest laser contribution to the strips' mean level that a lock accepts, DN
LOCK_MIN_LEVEL_DN = 1e-3
#: quantisation floor of the residual delta in DN, keeps the SNR finite on noiseless data
RESIDUAL_FLOOR_DN = 0.5
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


def _check_chips(chips: Sequence[int] | npt.NDArray[np.integer]) -> npt.NDArray[np.int8]:
    signs = codes.bipolar(chips)
    if not codes.is_balanced(chips):
        raise CodeError(
            f"code {codes.chips_string(chips)} is not balanced; ambient light would not "
            "cancel; accepted: as many 1 chips as 0 chips"
        )
    return signs


@functools.lru_cache(maxsize=8)
def _strip_starts(width: int) -> tuple[int, ...]:
    return tuple(sorted({min(int(p * width), max(width - STRIP_WIDTH, 0))
                         for p in STRIP_POSITIONS}))


def strip_sample(image: Array) -> Array:
    """All rows of the sampled column strips, (H, <= 2 * STRIP_WIDTH), same dtype.

    Strips are short contiguous runs of each row, so reading them touches few cache lines;
    laser lines are horizontal, so every row is kept.
    """
    return np.concatenate([image[:, s:s + STRIP_WIDTH] for s in _strip_starts(image.shape[1])],
                          axis=1)


def strip_level(pixels: Array) -> float:
    """Mean raw level of the sampled strips of a sub-frame, in DN."""
    starts = _strip_starts(pixels.shape[1])
    total = sum(int(pixels[:, s:s + STRIP_WIDTH].sum(dtype=np.int64)) for s in starts)
    return total / (pixels.shape[0] * min(STRIP_WIDTH, pixels.shape[1]) * len(starts))


def measure_gain(values: Array, code_length: int) -> tuple[float, float, float, float]:
    """Processing gain and SNR of a distortion map (paper Eq. 5-6), measured on strips.

    The background of a map is symmetric about 0 and the laser only adds, so the noise
    scale is taken from the negative values: ``sigma^2 = 2 sum(x^2 | x < 0) / n``. Signal
    pixels are those above ``max(6 sigma, max / 4, 1 DN)``; ``I_S`` is their mean,
    ``delta = I_B`` the RMS of the others (floored at RESIDUAL_FLOOR_DN). Then
    ``l = 2 (I_S - delta) / N``, ``PG = I_S / l``, ``SNR = I_S / delta``. Returns
    (PG, SNR, I_S, delta), all finite; PG = SNR = 0.0 when no laser signal is found.
    """
    sample = strip_sample(values).ravel().astype(np.float32)
    negative = np.minimum(sample, 0.0)
    sigma = float(np.sqrt(2.0 * float(negative @ negative) / sample.size))
    threshold = max(6.0 * sigma, 0.25 * float(sample.max()), 1.0)
    signal = sample > threshold
    count = int(np.count_nonzero(signal))
    background_energy = float(sample @ sample) - float(sample[signal] @ sample[signal])
    background = sample.size - count
    delta = max(np.sqrt(max(background_energy, 0.0) / background) if background else 0.0,
                RESIDUAL_FLOOR_DN)
    if not count:
        return 0.0, 0.0, 0.0, delta
    i_s = float(sample[signal].mean())
    laser = 2.0 * (i_s - delta) / code_length
    if laser <= 0.0:
        return 0.0, 0.0, i_s, delta
    return i_s / laser, i_s / delta, i_s, delta


@dataclass(frozen=True)
class _Info:
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


class _PhaseLock:
    """Finds the strobe lag from the mean level x_s of the sampled strips of each sub-frame.

    The levels are differenced (``x'_s = x_s - x_(s-1)``), which turns a linear drift into a
    constant; over M consecutive differences (whole code periods, at least two and at least
    LOCK_HISTORY) lag L scores ``sum_s v'[(s - L) % N] x'_s`` with ``v'_i = v_i - v_(i-1)``.
    The own laser adds ``l`` on ON chips only, so the true lag scores highest; constant
    ambient, linear drift and interferers on orthogonal codes (differencing keeps their
    cross-correlation zero) score zero at every lag. Lags giving the same sign sequence are
    equivalent; the smallest is reported.
    """

    def __init__(self, signs: npt.NDArray[np.int8]) -> None:
        n = signs.size
        self._n = n
        self._signs = np.stack([np.roll(signs, lag) for lag in range(n)])
        steps = (signs - np.roll(signs, 1)).astype(np.float64)
        self._matrix = np.stack([np.roll(steps, lag) for lag in range(n)])
        self.history = n * max(2, -(-LOCK_HISTORY // n))  # M, at least two periods
        self._levels: collections.deque[tuple[int, float]] = collections.deque(
            maxlen=self.history + 1)
        self.fresh = 0  # levels fed since the last decision that was acted on

    def reset(self) -> None:
        self._levels.clear()
        self.fresh = 0

    def feed(self, sequence: int, level: float, decide: bool = True) -> int | None:
        """Add the level of sub-frame ``sequence``; return the lag when the history shows it.

        With ``decide=False`` the level is only stored (no correlation is computed).
        """
        if self._levels and sequence != self._levels[-1][0] + 1:
            self._levels.clear()
        self._levels.append((sequence, level))
        self.fresh += 1
        if not decide or len(self._levels) <= self.history:
            return None
        return self._decide()

    def _decide(self) -> int | None:
        sequences = np.array([s for s, _ in self._levels], dtype=np.int64)[1:]
        steps = np.diff(np.array([x for _, x in self._levels], dtype=np.float64))
        by_chip = np.bincount(sequences % self._n, weights=steps, minlength=self._n)
        scores = self._matrix @ by_chip  # matrix[L, c] = v'[(c - L) % N]
        best = int(np.argmax(scores))
        same = (self._signs == self._signs[best]).all(axis=1)
        runner_up = float(scores[~same].max()) if (~same).any() else 0.0
        floor = max(LOCK_SIGMAS * self._score_sigma(sequences, steps, best),
                    LOCK_MIN_LEVEL_DN * self.history)
        if scores[best] - runner_up <= floor or scores[best] <= floor:
            return None
        return int(np.flatnonzero(same)[0])

    def _score_sigma(self, sequences: npt.NDArray[np.int64], steps: npt.NDArray[np.float64],
                     best: int) -> float:
        """Standard deviation of a score from the part of the steps that is not N-periodic.

        Everything periodic (own laser, interferers, the ambient pattern) is removed by
        subtracting each chip phase's mean step; what remains is noise.
        """
        phase = sequences % self._n
        periods = steps.size // self._n
        residual = steps - np.bincount(phase, weights=steps, minlength=self._n)[phase] / periods
        pattern = self._matrix[best][phase]
        variance = float(residual @ residual) / max(steps.size - self._n, 1)
        return float(np.sqrt(variance * float(pattern @ pattern)))


#: called with (row slice, sub-frame rows) for a chunk that holds a pixel at full scale
ChunkHook = Callable[[slice, Array], None]


class _Kernels:
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


class _Demodulator:
    """Validation, sequence tracking, phase lock and map statistics of both demodulators."""

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
        self._lock = _PhaseLock(self._signs)
        self._pending: collections.deque[tuple[SubFrame, float | None]] = collections.deque(
            maxlen=self._n)
        self._last: SubFrame | None = None
        self._kernels: _Kernels | None = None
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
        self._clear_window()
        self._pending.clear()
        self._lock.reset()

    # --- phase lock ----------------------------------------------------------------------

    def _try_lock(self, sub: SubFrame, level: float | None,
                  decided: int | None) -> DistortionMap | None:
        self._pending.append((sub, level))
        if decided is None:
            return None
        self._lag = decided
        self._lock.fresh = 0
        logger.info("strobe lag locked at %d sub-frame(s)", decided)
        return self._replay()

    def _replay(self) -> DistortionMap | None:
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
        self._clear_window()

    # --- helpers for the windows ---------------------------------------------------------

    def _sign(self, sequence: int) -> int:
        assert self._lag is not None
        return int(self._signs[(sequence - self._lag) % self._n])

    def _kernels_for(self, pixels: Array) -> _Kernels:
        if self._kernels is None or self._kernels.shape != pixels.shape:
            self._kernels = _Kernels(self._dtype, (pixels.shape[0], pixels.shape[1]),
                                     self._full_scale)
        return self._kernels

    def _info(self, sub: SubFrame, level: float | None,
              update: tuple[int, tuple[int, ...]]) -> _Info:
        peak, hot_chunks = update
        if peak > self._full_scale:
            self._reprime()
            raise DemodulationError(
                f"sub-frame {sub.sequence}: pixel value {peak} above the full scale "
                f"{self._full_scale} of {self._bits}-bit data; accepted: 0..{self._full_scale}")
        return _Info(sub.sequence, sub.host_time_s, self._sign(sub.sequence), hot_chunks, level)

    def _no_saturation(self, shape: tuple[int, ...]) -> npt.NDArray[np.bool_]:
        if self._clear_mask is None or self._clear_mask.shape != shape:
            self._clear_mask = np.zeros(shape, dtype=bool)
            self._clear_mask.setflags(write=False)
        return self._clear_mask

    def _ambient_dn(self, infos: Sequence[_Info], newest: Array) -> float:
        """Mean raw level of the window's strips; with a known lag (levels not taken per
        sub-frame) that of the newest sub-frame, refreshed once per N sub-frames."""
        levels = [i.level for i in infos if i.level is not None]
        if len(levels) == len(infos):
            return statistics.fmean(levels)
        last = infos[-1].sequence
        if self._ambient_cache is None or not 0 <= last - self._ambient_cache[0] < self._n:
            self._ambient_cache = (last, strip_level(newest))
        return self._ambient_cache[1]

    def _make_map(self, values: Array, saturated: npt.NDArray[np.bool_] | None,
                  infos: Sequence[_Info], newest: Array) -> DistortionMap:
        values.setflags(write=False)
        mask = self._no_saturation(values.shape) if saturated is None else saturated
        fraction = 0.0 if saturated is None else np.count_nonzero(mask) / mask.size
        gain, snr, signal, residual = measure_gain(values, self._n)
        dropped, self._dropped_since_map = self._dropped_since_map, 0
        ambient = self._ambient_dn(infos, newest) / self._full_scale
        return DistortionMap(
            values=values, saturated=mask, code_length=self._n,  # type: ignore[arg-type]
            first_sequence=infos[0].sequence, last_sequence=infos[-1].sequence,
            first_time_s=infos[0].host_time_s, last_time_s=infos[-1].host_time_s,
            phase=self._lag or 0, dropped=dropped, processing_gain=gain, snr=snr,
            extra={"ambient_level": ambient, "saturated_fraction": float(fraction),
                   "signal_dn": signal, "residual_dn": residual})

    # --- per window, in the subclasses ---------------------------------------------------

    _clear_mask: npt.NDArray[np.bool_] | None = None
    _ambient_cache: tuple[int, float] | None = None

    def _clear_window(self) -> None:
        raise NotImplementedError

    def _add(self, sub: SubFrame, level: float | None) -> DistortionMap | None:
        raise NotImplementedError


class BlockDemodulator(_Demodulator):
    """Paper §3: ``D = sum_(i<N) v_i F_i`` over non-overlapping windows of N sub-frames."""

    def _clear_window(self) -> None:
        self._acc: Array | None = None
        self._mask: npt.NDArray[np.bool_] | None = None
        self._infos: list[_Info] = []

    def _add(self, sub: SubFrame, level: float | None) -> DistortionMap | None:
        kernels, frame = self._kernels_for(sub.pixels), sub.pixels
        sign = self._sign(sub.sequence)
        if self._acc is None:
            self._acc = np.empty(frame.shape, dtype=self._dtype)
            update = kernels.start(self._acc, frame, sign, self._mark)
        else:
            update = kernels.add(self._acc, frame, sign, self._mark)
        self._infos.append(self._info(sub, level, update))
        if len(self._infos) < self._n:
            return None
        result = self._make_map(self._acc, self._mask, self._infos, frame)
        self._clear_window()
        return result

    def _mark(self, rows: slice, chunk: Array) -> None:
        if self._mask is None:
            assert self._acc is not None
            self._mask = np.zeros(self._acc.shape, dtype=bool)
        target = self._mask[rows]
        np.logical_or(target, chunk == self._full_scale, out=target)


class SlidingDemodulator(_Demodulator):
    """``D_t = D_(t-1) + v_(t mod N) (F_t - F_(t-N))``: a map every sub-frame once primed.

    Priming sums the first N sub-frames as the block demodulator does; then each sub-frame
    replaces the one N sub-frames older. Any N consecutive chips are a full code period, so
    ambient and orthogonal interferers cancel as in the block sum. Pixels at full scale are
    counted per pixel over the ring, only in the row chunks that hold any.
    """

    def _clear_window(self) -> None:
        self._ring: collections.deque[tuple[Array, _Info]] = collections.deque(maxlen=self._n)
        self._values: Array | None = None
        self._count: npt.NDArray[np.uint16] | None = None
        self._hot_frames: collections.Counter[int] = collections.Counter()

    def _add(self, sub: SubFrame, level: float | None) -> DistortionMap | None:
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
        return self._make_map(self._values, self._mask(), [i for _, i in self._ring], frame)

    def _slide(self, sub: SubFrame, level: float | None, kernels: _Kernels) -> DistortionMap:
        assert self._values is not None
        old_frame, old_info = self._ring[0]
        out = np.empty(sub.pixels.shape, dtype=self._dtype)
        update = kernels.slide(out, self._values, sub.pixels, (old_frame, old_info.hot_chunks),
                               self._sign(sub.sequence), (self._enter, self._leave))
        self._hot_frames.subtract(old_info.hot_chunks)
        self._push_ring(sub.pixels, self._info(sub, level, update))
        self._values = out
        return self._make_map(out, self._mask(), [i for _, i in self._ring], sub.pixels)

    def _push_ring(self, frame: Array, info: _Info) -> None:
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
