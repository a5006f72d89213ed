"""Synchronous mode: alignment to the leader's SYNC frame and the leak a misalignment causes.

With aligned chips all N - 1 non-constant Walsh rows are orthogonal at shift 0, but not at
other shifts, so the residual misalignment must be measured. Chips are rectangles one chip
long: an interferer shifted by ``s = k + f`` chips (k whole, 0 <= f < 1) lights each of our
chips for ``1 - f`` of chip ``i + k`` and ``f`` of chip ``i + k + 1``. Its residual in our
distortion map is ``R(s) = sum_i v_i * ((1 - f) u_(i+k) + f u_(i+k+1))``, linear in f
between the integer shifts; our own laser gives ``N / 2`` (same intensity), so the leak is
``|R(s)| / (N / 2)``.

Example:
    >>> misalignment_leak(3, 4, 16, 0.0)
    0.0
    >>> round(misalignment_leak(3, 4, 16, 0.1), 3)
    0.1
    >>> round(misalignment_leak(2, 3, 16, 0.3), 12)  # a cyclic orthogonal pair: no leak
    0.0
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from atris_node.errors import CodeError


def walsh_bipolar(code_length: int, row: int) -> tuple[int, ...]:
    """Row ``row`` (1-based) of the Sylvester Hadamard matrix H_N as +1/-1 chips."""
    if not 1 <= row <= code_length:
        raise CodeError(f"Walsh row must be in 1..{code_length}, got {row}")
    index = row - 1
    return tuple(-1 if (index & i).bit_count() % 2 else 1 for i in range(code_length))


def shifted_residual(own_row: int, other_row: int, code_length: int, shift_chips: float) -> float:
    """Residual R(s) of ``other_row``'s unipolar strobe, shifted by ``shift_chips``, in our map.

    In units of the laser intensity l times one chip; our own laser gives ``N / 2``.
    """
    if not math.isfinite(shift_chips):
        raise CodeError(f"shift must be a finite number of chips, got {shift_chips!r}")
    v = walsh_bipolar(code_length, own_row)
    u = [(1 + b) // 2 for b in walsh_bipolar(code_length, other_row)]
    k = math.floor(shift_chips)
    f = shift_chips - k
    n = code_length
    return float(sum(v[i] * ((1.0 - f) * u[(i + k) % n] + f * u[(i + k + 1) % n])
                     for i in range(n)))


def misalignment_leak(own_row: int, other_row: int, code_length: int,
                      error_chips: float) -> float:
    """Leak of ``other_row`` into ``own_row`` at a chip misalignment of ``error_chips``.

    A fraction of our own line energy (both lasers equally bright): 0.0 when aligned.
    """
    residual = shifted_residual(own_row, other_row, code_length, error_chips)
    return abs(residual) / (code_length / 2)


def worst_leak(own_row: int, other_rows: Iterable[int], code_length: int,
               error_chips: float) -> float:
    """Largest leak into ``own_row`` from any of ``other_rows`` shifted by +-``error_chips``."""
    leaks = [misalignment_leak(own_row, row, code_length, sign * error_chips)
             for row in other_rows if row != own_row for sign in (1.0, -1.0)]
    return max(leaks, default=0.0)


def fold_offset_chips(offset_s: float, chip_rate_hz: float, code_length: int) -> float:
    """Offset between two cycle starts, folded to the nearest whole cycle, in chips.

    The result is in ``(-N/2, N/2]``: a cycle start ``offset_s`` after the reference is as
    good as one a whole code period later.
    """
    chips = offset_s * chip_rate_hz
    folded = chips - code_length * round(chips / code_length)
    return folded if folded > -code_length / 2 else folded + code_length


@dataclass
class SyncState:
    """What a follower knows about the leader's SYNC.

    Attributes:
        last_sync_s: receipt time of the newest SYNC on the negotiator's clock, or None.
        counter: the newest SYNC counter.
        error_chips: our last measured cycle start minus the SYNC, folded, in chips; None
            until measured.
        measured_at_s: when ``error_chips`` was measured.
    """

    last_sync_s: float | None = None
    counter: int = 0
    error_chips: float | None = None
    measured_at_s: float | None = None

    def on_sync(self, counter: int, now: float) -> None:
        """Record a SYNC frame received at ``now``."""
        self.last_sync_s = now
        self.counter = counter

    def measure(self, cycle_start_s: float, chip_rate_hz: float, code_length: int) -> float | None:
        """Measure our cycle start against the newest SYNC; None when no SYNC was seen."""
        if self.last_sync_s is None:
            return None
        self.error_chips = fold_offset_chips(cycle_start_s - self.last_sync_s,
                                             chip_rate_hz, code_length)
        self.measured_at_s = cycle_start_s
        return self.error_chips

    def fresh(self, now: float, max_age_s: float) -> bool:
        """True when a SYNC and a measurement are both younger than ``max_age_s``."""
        return (self.last_sync_s is not None and self.measured_at_s is not None
                and now - self.last_sync_s <= max_age_s and now - self.measured_at_s <= max_age_s)

    def reset(self) -> None:
        """Forget the leader (plan change or leader change)."""
        self.last_sync_s = None
        self.error_chips = None
        self.measured_at_s = None
