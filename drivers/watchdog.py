"""A projector behind a watchdog: lit only while strobe commands keep coming.

Laser drivers on vehicles gate the emitter with a retriggerable watchdog, so a host
process that dies (SIGKILL, a crash) or hangs cannot leave the laser on. Two halves:

- :class:`LeasedProjector` wraps any projector in the node and publishes the lease in a
  small state file: the absolute ``time.monotonic()`` until which the emitter may be lit
  (0 = off), renewed by every strobe. On Linux the monotonic clock is shared by all
  processes.
- :class:`LeaseWatchdog` runs in ANOTHER process (``atris watchdog``) and drives the
  laser's enable line: the emitter is lit only where the node's chip AND the enable line
  say so (an AND gate in the laser driver). It clears the line once the lease has run
  out, whatever became of the node. The line is a file that takes ``1`` / ``0``: a sysfs
  GPIO ``value`` file on a vehicle computer, a plain file in tests and simulation.
"""

from __future__ import annotations

import logging
import os
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path

from atris_node.errors import DriverError
from drivers.base import Projector

logger = logging.getLogger(__name__)

_LEASE = struct.Struct("<d")


def read_lit_until(path: str | Path) -> float:
    """The lease end written in ``path`` (monotonic seconds; 0.0 = off)."""
    data = Path(path).read_bytes()
    return _LEASE.unpack(data[:_LEASE.size])[0] if len(data) >= _LEASE.size else 0.0


def is_lit_now(path: str | Path) -> bool:
    """True while the projector behind ``path`` may still emit."""
    return time.monotonic() < read_lit_until(path)


class LeasedProjector(Projector):
    """Wrap ``inner``; every strobe renews a lease of ``lease_s`` seconds in ``state_file``."""

    def __init__(self, inner: Projector, state_file: str | Path, lease_s: float) -> None:
        if lease_s <= 0:
            raise ValueError(f"lease_s must be > 0, got {lease_s}")
        self.inner, self.lease_s = inner, lease_s
        self._fd = os.open(state_file, os.O_RDWR | os.O_CREAT, 0o644)
        self._write(0.0)

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)

    def _write(self, lit_until: float) -> None:
        os.pwrite(self._fd, _LEASE.pack(lit_until), 0)

    def _strobe(self, chip: int, sequence: int) -> None:
        self.inner.strobe(chip, sequence)
        self._write(time.monotonic() + self.lease_s)

    def _off(self) -> None:
        self.inner.off()
        self._write(0.0)

    def set_intensity(self, fraction: float) -> None:
        self.inner.set_intensity(fraction)

    def close(self) -> None:
        if not self._closed:
            super().close()
            self.inner.close()
            os.close(self._fd)


class LeaseWatchdog:
    """Keeps the laser's enable line set only while the lease in ``state_file`` runs.

    Args:
        state_file: the lease a :class:`LeasedProjector` writes (a missing or short file
            is no lease: the line stays clear).
        enable_line: file that takes ``1`` / ``0`` (sysfs GPIO ``value``, or a plain file).
        poll_s: how often the lease is read, seconds (> 0). The laser is dark at most
            ``poll_s`` (plus this process's scheduling delay) after the lease ran out.

    ``transitions`` lists ``(monotonic time, enabled, lease end)`` of every change.
    """

    def __init__(self, state_file: str | Path, enable_line: str | Path,
                 poll_s: float = 0.005) -> None:
        if not 0.0 < poll_s <= 1.0:
            raise DriverError(f"watchdog poll period must be in (0, 1] s, got {poll_s}")
        self.state_file, self.enable_line = Path(state_file), Path(enable_line)
        self.poll_s = poll_s
        self.transitions: list[tuple[float, bool, float]] = []
        #: called with ``(time, enabled, lease end)`` after every change of the line
        self.on_transition: Callable[[float, bool, float], None] | None = None
        self._enabled: bool | None = None

    def lease_end(self) -> float:
        """The lease end in the state file (monotonic s); 0.0 when there is none."""
        try:
            return read_lit_until(self.state_file)
        except OSError:
            return 0.0

    def step(self, now: float | None = None) -> bool:
        """Read the lease once and set the line; True when the laser may be lit."""
        now = time.monotonic() if now is None else now
        lease_end = self.lease_end()
        enabled = now < lease_end
        if enabled != self._enabled:
            self._write(enabled)
            self._enabled = enabled
            self.transitions.append((now, enabled, lease_end))
            logger.info("laser enable %d at %.6f (lease end %.6f)", enabled, now, lease_end)
            if self.on_transition is not None:
                self.on_transition(now, enabled, lease_end)
        return enabled

    def run(self, stop: threading.Event) -> None:
        """Enforce the lease until ``stop`` is set; the line is cleared on the way out."""
        try:
            while not stop.is_set():
                self.step()
                stop.wait(self.poll_s)
        finally:
            self._write(False)
            self._enabled = False

    def _write(self, enabled: bool) -> None:
        try:
            self.enable_line.write_text("1" if enabled else "0")
        except OSError as exc:
            raise DriverError(f"cannot drive the laser enable line {self.enable_line}: "
                              f"{exc}") from exc
