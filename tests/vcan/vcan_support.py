"""Helpers of the vcan tests: unit processes speaking JSON lines, latency summaries.

Without KVM, importing numpy, cantools and canopen costs tens of seconds per process, so
units are forked from one pre-loaded process (``roles.py zygote``, started once per test
session). Every unit is still its own process with its own sockets: killing one is a real
crash, starting another is a real restart. Each unit talks to the test through two FIFOs.
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import IO, Any

import pytest

VCAN_DIR = Path(__file__).resolve().parent
REPO_ROOT = VCAN_DIR.parent.parent
ROLES = VCAN_DIR / "roles.py"

#: the units' publish.max_age_s, s: above one window of 8 sub-frames at UNIT_RATE_HZ (0.8
#: s) plus its map, or every map would be stale before the next and no distance would go
#: out valid
UNIT_MAX_AGE_S = 2.0
#: sub-frames/s of each ``atris run`` unit: two units (and a babbler) share the VM's two
#: emulated CPUs
UNIT_RATE_HZ = 10.0
#: the units' driver.strobe_margin_s: a loop late by more than this goes dark and restarts
#: its window (its own safety rule). In a CI run's VM (booted in 40 s, 19 s on an idle host;
#: a VM beside a busy loop boots as slowly) two units on indoor_lab (640 x 400) at 30
#: sub-frames/s and a 0.05 s margin lapsed on every window and negotiated for the whole
#: test (the babble test; the node test too in a VM that booted in 62 s); on an idle host
#: they ran, but with a 0.25 s max age every map was stale (0 valid cycles)
UNIT_STROBE_MARGIN_S = 0.5
#: the lab room at 480 x 300 (56 % of indoor_lab's pixels; at 320 x 200 every sector is
#: INVALID). Beside a busy loop, at the values above: RUNNING 26.7 and 26.8 of 26 s heard,
#: 716 valid cycles (babble test); indoor_lab itself: RUNNING 10.8 and 8.4 s, 22 valid
UNIT_SCENE = str(VCAN_DIR / "small_lab.toml")


def starved_vm_settings() -> dict[str, object]:
    """``--set`` settings that let ``atris run`` units measure in a starved test VM: the
    small scene, paced at UNIT_RATE_HZ (a loop slower than the max age is FAULT,
    correctly, and a test would see nothing run), the wide strobe margin and max age."""
    return {"driver.scene": UNIT_SCENE, "driver.rate_hz": UNIT_RATE_HZ,
            "driver.realtime": "true", "driver.strobe_margin_s": UNIT_STROBE_MARGIN_S,
            "publish.max_age_s": UNIT_MAX_AGE_S}


class Zygote:
    """A pre-loaded process that forks one child per unit on request."""

    def __init__(self) -> None:
        env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "OPENBLAS_NUM_THREADS": "1"}
        self.tmp = tempfile.TemporaryDirectory(prefix="atris-vcan-")
        self.log_path = Path(os.environ.get("ATRIS_VCAN_RESULTS", self.tmp.name)) / "units.log"
        with open(self.log_path, "a") as log:
            self.proc = subprocess.Popen([sys.executable, str(ROLES), "zygote"], cwd=REPO_ROOT,
                                         env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=log, text=True)
        self.count = 0

    def wait_preloaded(self, timeout_s: float) -> None:
        """Waits until the zygote has imported and warmed everything (its answer of id 0):
        in a starved VM that took most of the first test's 300 s, and the load test timed
        out in its measurement."""
        assert self.proc.stdout is not None
        with selectors.DefaultSelector() as selector:
            selector.register(self.proc.stdout, selectors.EVENT_READ)
            if not selector.select(timeout_s):
                pytest.fail(f"the unit zygote did not preload within {timeout_s:.0f} s")
        answer = self.proc.stdout.readline()
        if not answer or json.loads(answer).get("id") != 0:
            pytest.fail(f"the unit zygote did not preload: {answer!r}")

    def fork(self, role: str, args: tuple[str, ...]) -> tuple[int, Path, Path]:
        """Starts ``role``; returns its pid and the paths of its stdin and stdout FIFOs."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.count += 1
        fifo_in, fifo_out = (Path(self.tmp.name) / f"{self.count}.{d}" for d in ("in", "out"))
        os.mkfifo(fifo_in)
        os.mkfifo(fifo_out)
        request = {"id": self.count, "role": role, "args": list(args),
                   "stdin": str(fifo_in), "stdout": str(fifo_out)}
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        while True:  # an answer to an earlier request whose test gave up waiting is skipped
            answer = self.proc.stdout.readline()
            if not answer:
                pytest.fail(f"the unit zygote exited with {self.proc.wait(5)}")
            reply = json.loads(answer)
            if reply["id"] == self.count:
                return int(reply["pid"]), fifo_in, fifo_out

    def close(self) -> None:
        """Ends the zygote (closing its stdin) and removes the FIFOs."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.close()
        self.proc.wait(30)
        self.proc.stdout.close()
        self.tmp.cleanup()


class UnitProcess:
    """One unit process running a role of ``roles.py``; it speaks JSON lines."""

    def __init__(self, zygote: Zygote, role: str, *args: str) -> None:
        self.role = role
        self.pid, fifo_in, fifo_out = zygote.fork(role, args)
        self.stdin: IO[str] = open(fifo_in, "w")  # noqa: SIM115 (closed by close())
        self.stdout: IO[bytes] = open(fifo_out, "rb", buffering=0)  # noqa: SIM115
        self._pending = b""
        self.events: list[dict[str, Any]] = []
        self._selector = selectors.DefaultSelector()
        self._selector.register(self.stdout, selectors.EVENT_READ)

    def alive(self) -> bool:
        """True while the process exists (the zygote reaps its children at once)."""
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return False
        return True

    def read(self, timeout_s: float = 60.0) -> dict[str, Any]:
        """The next JSON object the unit printed; fails the test after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._pending:
            if not self._selector.select(max(deadline - time.monotonic(), 0.0)):
                pytest.fail(f"{self.role}: no output within {timeout_s} s")
            chunk = os.read(self.stdout.fileno(), 65536)
            if not chunk:
                pytest.fail(f"{self.role}: exited before answering")
            self._pending += chunk
        line, self._pending = self._pending.split(b"\n", 1)
        self.events.append(dict(json.loads(line)))
        return self.events[-1]

    def wait_for(self, event: str, timeout_s: float = 60.0) -> dict[str, Any]:
        """Reads lines until one whose ``event`` is ``event``; returns it."""
        deadline = time.monotonic() + timeout_s
        while True:
            msg = self.read(max(deadline - time.monotonic(), 0.01))
            if msg.get("event") == event:
                return msg

    def drain(self) -> None:
        """Reads every line the unit has printed so far, without waiting."""
        while b"\n" in self._pending or self._selector.select(0.0):
            try:
                self.read(0.0)
            except pytest.fail.Exception:
                return

    def of(self, event: str) -> list[dict[str, Any]]:
        """Every line read so far whose ``event`` is ``event``."""
        return [e for e in self.events if e.get("event") == event]

    def stop(self) -> dict[str, Any]:
        """Asks the unit to finish (closes its stdin) and returns its ``done`` report."""
        if not self.stdin.closed:
            self.stdin.close()
        return self.wait_for("done")

    def kill(self) -> None:
        """Ends the unit at once (SIGKILL), as a crash would."""
        os.kill(self.pid, signal.SIGKILL)
        self.close()

    def close(self) -> None:
        """Waits for the unit to end (SIGKILL after 10 s) and closes the FIFOs."""
        if not self.stdin.closed:
            self.stdin.close()
        deadline = time.monotonic() + 10.0
        while self.alive() and time.monotonic() < deadline:
            time.sleep(0.02)
        if self.alive():
            os.kill(self.pid, signal.SIGKILL)
        self._selector.close()
        self.stdout.close()


def summary_ms(values_s: list[float]) -> dict[str, float]:
    """Median, 99th percentile and maximum of durations in seconds, as milliseconds."""
    ordered = sorted(values_s)
    p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    return {"median_ms": round(statistics.median(ordered) * 1e3, 3),
            "p99_ms": round(p99 * 1e3, 3), "max_ms": round(ordered[-1] * 1e3, 3)}
