"""How much light of other units' codes reaches this unit's camera (issue 6.5 / 11.1).

On the sampled column strips of the sub-frames (every row, a few columns, the same as the
demodulator's statistics), each window of N consecutive sub-frames is demodulated with:

- each foreign code of the plan, at every whole-chip shift (the other unit's phase is not
  known), keeping the shift of highest energy;
- the own code at every shift after the own strobe's share has been taken out: per pixel
  the own laser ``l_p = max(2 D_own / N, 0)`` is subtracted on the ON chips, and what the
  own code still finds is light of another unit strobing the same code (a plan conflict).
  A same-code strobe at exactly the own phase cannot be told from the own laser.

Energies are sums of squares of the demodulated strips (DN^2) and are reported as
fractions of the own line energy (sum of squares of the positive part of the own map,
``UnitStatus.foreign_code_energy``), with the own energy floored at 1 DN^2 per sampled
pixel so that a dark scene gives finite fractions. The noise floor (about ``N sigma^2``
per sampled pixel) is included in every energy. Only the codes given are evaluated.

Example:
    >>> from atris_node import codes
    >>> meter = InterferenceMeter({r: codes.walsh_chips(8, r) for r in (2, 3, 5)}, own_row=2)
    >>> meter.rows
    (3, 5)
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node import codes
from atris_node.demod import strip_sample
from atris_node.errors import CodeError
from atris_node.types import SubFrame

logger = logging.getLogger(__name__)

Chips = Sequence[int] | npt.NDArray[np.integer]


@dataclass(frozen=True)
class InterferenceReport:
    """Energies of one window of N sub-frames; fractions are of the own line energy."""

    foreign: dict[int, float]  # 1-based row -> energy fraction of that foreign code
    foreign_shift: dict[int, int]  # 1-based row -> shift (sub-frames) of its highest energy
    own_excess: float  # own code beyond what the own strobe explains, fraction
    own_energy: float  # sum of squares of the own lines (positive part of D_own), DN^2
    first_sequence: int
    last_sequence: int

    @property
    def total(self) -> float:
        """Everything that is not the own strobe, as one fraction."""
        return sum(self.foreign.values()) + self.own_excess


def _shift_matrix(chips: Chips, lag: int) -> npt.NDArray[np.float64]:
    """(N, N) float64: row tau holds ``v[(c - lag - tau) % N]`` for chip phase c."""
    signs = codes.bipolar(chips).astype(np.float64)
    return np.stack([np.roll(signs, lag + tau) for tau in range(signs.size)])


class InterferenceMeter:
    """Per-window energy of the plan's foreign codes and of a same-code intruder.

    ``chips_by_row`` maps 1-based rows to chips (all of one length, balanced), and must
    hold ``own_row``; ``lag`` is the own strobe lag (see the demodulators).
    """

    def __init__(self, chips_by_row: Mapping[int, Chips], own_row: int, lag: int = 0) -> None:
        if own_row not in chips_by_row:
            raise CodeError(f"own row {own_row} is not in the plan's rows {sorted(chips_by_row)}")
        lengths = {len(c) for c in chips_by_row.values()}
        if len(lengths) != 1 or not all(codes.is_balanced(c) for c in chips_by_row.values()):
            raise CodeError("plan codes must be balanced and of one length; got lengths "
                            f"{sorted(lengths)}")
        self._n = lengths.pop()
        self._own_chips = np.asarray(chips_by_row[own_row], dtype=np.float64)
        self._lag = lag % self._n
        self._own = _shift_matrix(chips_by_row[own_row], self._lag)
        self.rows = tuple(sorted(r for r in chips_by_row if r != own_row))
        self._foreign = {r: _shift_matrix(chips_by_row[r], 0) for r in self.rows}
        self._window: list[tuple[int, npt.NDArray[np.float64]]] = []

    def reset(self) -> None:
        """Forget the sub-frames of the current window."""
        self._window.clear()

    def push(self, sub: SubFrame) -> InterferenceReport | None:
        """Add one sub-frame; return a report at the end of each window of N sub-frames."""
        if self._window and sub.sequence != self._window[-1][0] + 1:
            self._window.clear()
        self._window.append((sub.sequence, strip_sample(sub.pixels).astype(np.float64).ravel()))
        if len(self._window) < self._n:
            return None
        report = self._report()
        self._window.clear()
        return report

    def _by_phase(self) -> npt.NDArray[np.float64]:
        """(N, P): the window's strips ordered by chip phase ``sequence % N``."""
        stacked = np.empty((self._n, self._window[0][1].size))
        for sequence, sample in self._window:
            stacked[sequence % self._n] = sample
        return stacked

    @staticmethod
    def _best(matrix: npt.NDArray[np.float64], phases: npt.NDArray[np.float64]
              ) -> tuple[float, int]:
        energies = ((matrix @ phases) ** 2).sum(axis=1)
        shift = int(np.argmax(energies))
        return float(energies[shift]), shift

    def _own_residual(self, phases: npt.NDArray[np.float64]) -> tuple[float, float]:
        demodulated = self._own[0] @ phases
        laser = np.maximum(2.0 * demodulated / self._n, 0.0)
        chips_seen = np.roll(self._own_chips, self._lag)
        residual = phases - np.outer(chips_seen, laser)
        lines = laser * (self._n / 2.0)
        return float(lines @ lines), self._best(self._own, residual)[0]

    def _report(self) -> InterferenceReport:
        phases = self._by_phase()
        own_energy, excess = self._own_residual(phases)
        scale = max(own_energy, float(phases.shape[1]))
        foreign, shifts = {}, {}
        for row, matrix in self._foreign.items():
            energy, shifts[row] = self._best(matrix, phases)
            foreign[row] = energy / scale
        return InterferenceReport(foreign, shifts, excess / scale, own_energy,
                                  self._window[0][0], self._window[-1][0])


class InterferenceWatch:
    """Runs an :class:`InterferenceMeter` on one window of N sub-frames out of ``every``.

    Interference that makes a unit hop must be sustained for a second or more, so a
    sampled window is enough, and the meter's cost (a few ms per sub-frame) is paid on
    1/``every`` of the sub-frames only. The codes measured are the own row and the rows
    ``rows_in_use()`` names (claimed on the bus); a code nobody strobes carries only noise.
    """

    def __init__(self, code_length: int, own_row: int, lag: int, every: int,
                 rows_in_use: Callable[[], Iterable[int]]) -> None:
        if every < 1:
            raise CodeError(f"interference sampling 'every' must be >= 1, got {every}")
        self.code_length, self.own_row, self.lag, self.every = code_length, own_row, lag, every
        self._rows_in_use = rows_in_use
        self._meter: InterferenceMeter | None = None
        self.windows_measured = 0

    def _start(self) -> InterferenceMeter:
        rows = {r for r in self._rows_in_use() if 1 < r <= self.code_length}
        chips = {r: codes.walsh_chips(self.code_length, r) for r in rows | {self.own_row}}
        return InterferenceMeter(chips, self.own_row, self.lag)

    def push(self, sub: SubFrame) -> InterferenceReport | None:
        """Feed every sub-frame; only those of a sampled window reach the meter."""
        window = sub.sequence // self.code_length
        if window % self.every:
            self._meter = None
            return None
        if self._meter is None:
            if sub.sequence % self.code_length:
                return None  # start sampled windows at chip phase 0
            self._meter = self._start()
        report = self._meter.push(sub)
        if report is not None:
            self.windows_measured += 1
            self._meter = None
        return report
