"""A projector behind a watchdog: lit only while strobe commands keep coming.

Laser drivers on vehicles gate the emitter with a retriggerable watchdog, so a host
process that dies (SIGKILL, a crash, a power cut of the computer) cannot leave the laser
on. :class:`LeasedProjector` wraps any projector and publishes that lease in a small state
file: the absolute ``time.monotonic()`` until which the emitter may be lit (0 = off).
Another process reads it with :func:`read_lit_until` / :func:`is_lit_now`; on Linux the
monotonic clock is shared by all processes.
"""

from __future__ import annotations

import os
import struct
import time
from pathlib import Path

from drivers.base import Projector

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
