"""CPU time per thread and per stage, for the real-time benchmark.

Per thread: ``utime + stime`` of every task in ``/proc/self/task`` (Linux; seconds, in
clock ticks of ``SC_CLK_TCK``, usually 10 ms), named by its Python thread name where it
has one, else by the kernel's ``comm`` (threads started by compiled libraries). Per stage:
a wrapper around a bound method that adds the wall and CPU time (``time.thread_time``,
the calling thread's CPU) of each call made inside a time window.

Example:
    >>> before = thread_cpu_s()
    >>> all(cpu >= 0.0 for _, cpu in before.values())
    True
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

TASKS = Path("/proc/self/task")


def _task_cpu_s(stat: str) -> float:
    """``utime + stime`` in seconds from the text of ``/proc/<pid>/task/<tid>/stat``."""
    fields = stat[stat.rindex(")") + 2:].split()  # the fields after "pid (comm) "
    ticks = int(fields[11]) + int(fields[12])  # utime, stime: fields 14 and 15 of stat
    return ticks / float(os.sysconf("SC_CLK_TCK"))


def thread_cpu_s() -> dict[int, tuple[str, float]]:
    """Native thread id -> (name, CPU seconds so far) of every thread of this process;
    empty where ``/proc`` is not there."""
    names = {t.native_id: t.name for t in threading.enumerate() if t.native_id is not None}
    out: dict[int, tuple[str, float]] = {}
    if not TASKS.is_dir():
        return out
    for task in TASKS.iterdir():
        try:
            stat = (task / "stat").read_text()
            comm = (task / "comm").read_text().strip()
        except OSError:  # the thread ended meanwhile
            continue
        tid = int(task.name)
        out[tid] = (names.get(tid, f"{comm} (native)"), _task_cpu_s(stat))
    return out


def process_cpu_s(pid: int) -> float:
    """CPU seconds (``utime + stime``) of process ``pid`` so far; 0.0 when it is gone or
    ``/proc`` is not there."""
    try:
        return _task_cpu_s(Path(f"/proc/{pid}/stat").read_text())
    except OSError:
        return 0.0


def per_thread(before: dict[int, tuple[str, float]], after: dict[int, tuple[str, float]],
               seconds: float) -> list[dict[str, Any]]:
    """CPU between two :func:`thread_cpu_s` samples, summed by thread name: rows with
    ``thread``, ``cpu_s`` and ``cpu_pct`` (of one core over ``seconds``), busiest first."""
    totals: dict[str, float] = {}
    for tid, (name, cpu) in after.items():
        start = before.get(tid, (name, 0.0))[1]
        totals[name] = totals.get(name, 0.0) + max(cpu - start, 0.0)
    rows = [{"thread": name, "cpu_s": round(cpu, 3),
             "cpu_pct": round(100.0 * cpu / seconds, 1) if seconds > 0 else 0.0}
            for name, cpu in totals.items() if cpu > 0.0]
    return sorted(rows, key=lambda r: -float(r["cpu_s"]))


@dataclass
class StageTimer:
    """Wall and CPU seconds of the calls of one stage that end inside ``[start_s, end_s)``
    of ``clock``."""

    clock: Callable[[], float] = time.monotonic
    start_s: float = float("inf")
    end_s: float = float("inf")
    wall_s: list[float] = field(default_factory=list)
    cpu_s: float = 0.0

    def wrap(self, method: Callable[..., Any]) -> Callable[..., Any]:
        """``method`` timed: the same arguments and result."""

        def timed(*args: Any, **kwargs: Any) -> Any:
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                return method(*args, **kwargs)
            finally:
                if self.start_s <= self.clock() < self.end_s:
                    self.wall_s.append(time.perf_counter() - wall)
                    self.cpu_s += time.thread_time() - cpu

        return timed

    def row(self, seconds: float) -> dict[str, Any]:
        """``calls``, ``p50_ms``, ``p99_ms``, ``max_ms`` (wall, per call), ``cpu_s`` and
        ``cpu_pct`` (of one core over ``seconds``); zeros when nothing was called."""
        wall = np.asarray(self.wall_s) * 1e3
        quantiles = ([round(float(np.percentile(wall, q)), 3) for q in (50, 99)]
                     + [round(float(wall.max()), 3)]) if wall.size else [0.0, 0.0, 0.0]
        return {"calls": int(wall.size), "p50_ms": quantiles[0], "p99_ms": quantiles[1],
                "max_ms": quantiles[2], "cpu_s": round(self.cpu_s, 3),
                "cpu_pct": round(100.0 * self.cpu_s / seconds, 1) if seconds > 0 else 0.0}
