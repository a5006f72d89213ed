"""Time-varying light integrated over an exposure window: strobes and lamp flicker.

A strobe is any ``Callable[[float, float], float]`` answering the fraction of
``[t0_s, t1_s]`` during which the source was ON. Integrating (not sampling) makes a
different chip rate or a fractional phase offset act as it does on a real sensor.

Flicker: a lamp of mean output 1 emits ``1 + depth · cos(2π f t)``; its mean over the
window is ``1 + depth · (sin 2πf t1 - sin 2πf t0) / (2πf (t1 - t0))``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from atris_node.sim.scene import Lamp

Strobe = Callable[[float, float], float]


def always_on(t0_s: float, t1_s: float) -> float:
    """A continuous source: ON for the whole window."""
    return 1.0


def code_strobe(chips: Sequence[int], rate_hz: float, phase_sub_frames: float,
                on_s: float) -> Strobe:
    """Strobe of a unit strobing ``chips`` cyclically at ``rate_hz``.

    Its sub-frame j starts at ``(j + phase_sub_frames) / rate_hz`` and the emitter is ON
    for ``min(on_s, 1 / rate_hz)`` seconds when ``chips[j % N]`` is 1.
    """
    period = 1.0 / rate_hz
    on = min(on_s, period)
    n = len(chips)

    def fraction(t0_s: float, t1_s: float) -> float:
        if t1_s <= t0_s:
            return 0.0
        first = math.floor(t0_s * rate_hz - phase_sub_frames) - 1
        last = math.ceil(t1_s * rate_hz - phase_sub_frames)
        lit = 0.0
        for j in range(first, last + 1):
            if chips[j % n]:
                start = (j + phase_sub_frames) * period
                lit += max(0.0, min(start + on, t1_s) - max(start, t0_s))
        return lit / (t1_s - t0_s)

    return fraction


def log_strobe(log: Sequence[tuple[int, float, int]], on_s: float) -> Strobe:
    """Strobe of a recorded emitter: ``(sequence, start_time_s, chip)`` entries in time
    order, each lit for ``on_s`` seconds from its start when chip is 1."""
    def fraction(t0_s: float, t1_s: float) -> float:
        if t1_s <= t0_s:
            return 0.0
        lit = 0.0
        for _, start, chip in reversed(log):
            if start + on_s <= t0_s:
                break
            if chip:
                lit += max(0.0, min(start + on_s, t1_s) - max(start, t0_s))
        return min(lit / (t1_s - t0_s), 1.0)

    return fraction


def flicker_factor(flicker_hz: float, depth: float, t0_s: float, t1_s: float) -> float:
    """Mean of ``1 + depth · cos(2π f t)`` over ``[t0_s, t1_s]``."""
    if flicker_hz <= 0.0 or depth <= 0.0:
        return 1.0
    w = 2.0 * math.pi * flicker_hz
    if t1_s <= t0_s:
        return 1.0 + depth * math.cos(w * t0_s)
    return 1.0 + depth * (math.sin(w * t1_s) - math.sin(w * t0_s)) / (w * (t1_s - t0_s))


def lamps_factor(lamps: Sequence[Lamp], t0_s: float, t1_s: float) -> float:
    """Mean output of several lamps over ``[t0_s, t1_s]`` relative to their summed mean
    lux: the lux-weighted mean of their :func:`flicker_factor` (1 without lamps)."""
    total = sum(lamp.lux for lamp in lamps)
    if total <= 0.0:
        return 1.0
    return sum(lamp.lux * flicker_factor(lamp.flicker_hz, lamp.flicker_depth, t0_s, t1_s)
               for lamp in lamps) / total
