"""Progress bars for long commands (calibration, simulation, benchmarks; tqdm on stderr).

tqdm's monitor thread is switched off: these runs are short, and a thread that
outlives the command would be a leak in the tests and in a host process.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import TypeVar

from tqdm import tqdm

tqdm.monitor_interval = 0

T = TypeVar("T")


def progress(items: Iterable[T], desc: str, unit: str, total: int | None = None) -> Iterator[T]:
    """Yield ``items`` while drawing a progress bar labelled ``desc`` counting ``unit``s."""
    with tqdm(items, desc=desc, unit=unit, total=total, leave=False) as bar:
        yield from bar
