"""Decision to hop away from a code jammed by a unit that is not on this bus.

The demodulator measures, per distortion map, the energy of its own code beyond what its
own strobe explains (``own_excess``) and the energy of the plan's other codes
(``foreign``, row -> energy), both as fractions of its own line energy. A unit on another
vehicle strobing our code shows up as sustained ``own_excess``: when it stays above
``threshold`` for ``sustain_s`` the unit hops to a free code through the normal claim
path. The jammed row is avoided for ``hold_s``; rows with less foreign energy are tried
first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from atris_node.errors import DemodulationError


def _check_energy(value: float, what: str) -> float:
    if not (math.isfinite(value) and value >= 0.0):
        raise DemodulationError(f"{what} must be a finite energy >= 0, got {value!r}")
    return float(value)


@dataclass
class InterferenceMonitor:
    """Sustain timer and the memory of jammed rows.

    Attributes:
        threshold: own-code excess energy (fraction of own line energy) counted as jamming.
        sustain_s: how long the excess must last before a hop, seconds.
        hold_s: how long a jammed row is avoided, seconds.
    """

    threshold: float = 0.2
    sustain_s: float = 1.0
    hold_s: float = 10.0
    hop_count: int = 0
    foreign: dict[int, float] = field(default_factory=dict)
    jammed_until_s: dict[int, float] = field(default_factory=dict)
    excess_since_s: float | None = None
    jammed_now: bool = False

    def report(self, own_excess: float, foreign: Mapping[int, float], now: float,
               strobing: bool) -> bool:
        """Record one measurement; True when the unit should hop now."""
        excess = _check_energy(own_excess, "own_excess")
        self.foreign = {int(row): _check_energy(e, f"foreign[{row}]") for row, e in foreign.items()}
        if not strobing or excess <= self.threshold:
            self.excess_since_s = None
            self.jammed_now = False
            return False
        if self.excess_since_s is None:
            self.excess_since_s = now
        self.jammed_now = now - self.excess_since_s >= self.sustain_s
        return self.jammed_now

    def mark_jammed(self, row: int, now: float) -> None:
        """Avoid ``row`` for ``hold_s`` and count a hop."""
        self.jammed_until_s[row] = now + self.hold_s
        self.hop_count += 1
        self.excess_since_s = None
        self.jammed_now = False

    def is_jammed(self, row: int, now: float) -> bool:
        """True while ``row`` is being avoided."""
        return now < self.jammed_until_s.get(row, -math.inf)

    def preference(self, rows: list[int]) -> list[int]:
        """``rows`` ordered by the foreign energy last measured on them, then by row."""
        return sorted(rows, key=lambda row: (self.foreign.get(row, 0.0), row))

    def active(self, now: float) -> bool:
        """True while jamming is measured or a hop is recent (the FOREIGN_CODE status bit)."""
        recent = any(now < until for until in self.jammed_until_s.values())
        return self.jammed_now or recent
