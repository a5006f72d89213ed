"""Small timing helpers for the benchmarks: best-of-k and median with ``perf_counter``.

Benchmarks are run on shared machines, so every figure is a median (robust to a few slow
repeats) with the best repeat beside it.

Example:
    >>> timing = time_call(lambda: sum(range(1000)), repeats=5)
    >>> timing.best_s <= timing.median_s
    True
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from atris_node.errors import ConfigError


@dataclass(frozen=True)
class Timing:
    """Seconds per call (or per item, see :func:`time_per_item`) over ``repeats`` repeats."""

    best_s: float
    median_s: float
    repeats: int

    @property
    def median_ms(self) -> float:
        """Median, in milliseconds."""
        return self.median_s * 1e3

    @property
    def best_ms(self) -> float:
        """Best repeat, in milliseconds."""
        return self.best_s * 1e3


def _check_repeats(repeats: int) -> None:
    if repeats < 1:
        raise ConfigError(f"repeats must be at least 1, got {repeats}; accepted: >= 1")


def time_call(fn: Callable[[], object], repeats: int = 7, warmup: int = 1) -> Timing:
    """Time ``fn()`` ``repeats`` times after ``warmup`` untimed calls."""
    return time_per_item(fn, items=1, repeats=repeats, warmup=warmup)


def time_per_item(fn: Callable[[], object], items: int, repeats: int = 7,
                  warmup: int = 1) -> Timing:
    """Time ``fn()``, which processes ``items`` items, and divide by ``items``."""
    _check_repeats(repeats)
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        samples.append((time.perf_counter() - start) / max(items, 1))
    return Timing(min(samples), statistics.median(samples), repeats)


def time_interleaved(work: dict[str, tuple[Callable[[], object], int]], repeats: int = 7,
                     warmup: int = 1) -> dict[str, Timing]:
    """Time several ``(fn, items)`` in turn within each repeat; per-item Timing by name.

    Interleaving exposes every candidate to the same load on a shared machine, so ratios
    between them stay meaningful when absolute times drift.
    """
    _check_repeats(repeats)
    for fn, _ in work.values():
        for _ in range(warmup):
            fn()
    samples: dict[str, list[float]] = {name: [] for name in work}
    for _ in range(repeats):
        for name, (fn, items) in work.items():
            start = time.perf_counter()
            fn()
            samples[name].append((time.perf_counter() - start) / max(items, 1))
    return {name: Timing(min(s), statistics.median(s), repeats) for name, s in samples.items()}


def spread_ms(values_ms: Sequence[float]) -> dict[str, float | int | None]:
    """``samples`` and the p50, p99 and max (ms, rounded to µs) of ``values_ms``; the three
    are None when there is no value."""
    values = np.asarray(values_ms, dtype=np.float64)
    if values.size == 0:
        return {"samples": 0, "p50": None, "p99": None, "max": None}
    return {"samples": int(values.size), "p50": round(float(np.percentile(values, 50)), 3),
            "p99": round(float(np.percentile(values, 99)), 3),
            "max": round(float(values.max()), 3)}
