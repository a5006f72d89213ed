"""Finding the strobe lag from the data: which chip a sub-frame really showed."""

from __future__ import annotations

import collections

import numpy as np
import numpy.typing as npt

#: a lock needs the best lag this many noise standard deviations above every other lag
LOCK_SIGMAS = 6.0
#: sub-frames (rounded up to whole code periods) a lock decision looks at
LOCK_HISTORY = 32
#: smallest laser contribution to the strips' mean level that a lock accepts, DN
LOCK_MIN_LEVEL_DN = 1e-3


class PhaseLock:
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
