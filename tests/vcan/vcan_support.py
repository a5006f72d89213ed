"""Helpers of the vcan tests: child processes speaking JSON lines, latency summaries."""

from __future__ import annotations

import json
import os
import selectors
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

VCAN_DIR = Path(__file__).resolve().parent
REPO_ROOT = VCAN_DIR.parent.parent
ROLES = VCAN_DIR / "roles.py"


class UnitProcess:
    """One child process running a role of ``roles.py``; it speaks JSON lines on stdout."""

    def __init__(self, role: str, *args: str) -> None:
        env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
        self.role = role
        self.proc = subprocess.Popen(
            [sys.executable, str(ROLES), role, *args], cwd=REPO_ROOT, env=env,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self._selector = selectors.DefaultSelector()
        assert self.proc.stdout is not None
        self._selector.register(self.proc.stdout, selectors.EVENT_READ)

    def read(self, timeout_s: float = 60.0) -> dict[str, Any]:
        """The next JSON object the child printed; fails the test after ``timeout_s``."""
        assert self.proc.stdout is not None
        if not self._selector.select(timeout_s):
            pytest.fail(f"{self.role}: no output within {timeout_s} s")
        line = self.proc.stdout.readline()
        if not line:
            pytest.fail(f"{self.role}: exited with {self.proc.wait(5)} before answering")
        return dict(json.loads(line))

    def wait_for(self, event: str, timeout_s: float = 60.0) -> dict[str, Any]:
        """Reads lines until one whose ``event`` is ``event``; returns it."""
        deadline = time.monotonic() + timeout_s
        while True:
            msg = self.read(max(deadline - time.monotonic(), 0.01))
            if msg.get("event") == event:
                return msg

    def stop(self) -> dict[str, Any]:
        """Asks the child to finish (closes its stdin) and returns its ``done`` report."""
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        return self.wait_for("done")

    def kill(self) -> None:
        """Ends the child at once (SIGKILL) and reaps it."""
        self.proc.kill()
        self.close()

    def close(self) -> None:
        """Reaps the child (killing it if it does not end in 10 s) and closes the pipes."""
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self._selector.close()
        for pipe in (self.proc.stdin, self.proc.stdout):
            if pipe is not None and not pipe.closed:
                pipe.close()


def summary_ms(values_s: list[float]) -> dict[str, float]:
    """Median, 99th percentile and maximum of durations in seconds, as milliseconds."""
    ordered = sorted(values_s)
    p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    return {"median_ms": round(statistics.median(ordered) * 1e3, 3),
            "p99_ms": round(p99 * 1e3, 3), "max_ms": round(ordered[-1] * 1e3, 3)}
