"""A camera wrapper that injects the faults of a real camera link, for tests and soak runs.

Faults are scheduled by the number of reads: a disconnect for a number of reads (each
raises CameraLostError, as a dead link does), dropped sub-frames (a gap in the sequence
numbers), a repeated sub-frame, a sub-frame of the wrong size or dtype, and an exposure
change. Everything else is passed through from the wrapped camera unchanged.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from atris_node.calibration import Calibration
from atris_node.errors import CameraLostError
from atris_node.types import SubFrame
from drivers.base import Camera


@dataclass
class CameraFaults:
    """Read indices (0-based count of ``read`` calls) at which each fault happens."""

    disconnect_at: int | None = None
    disconnect_reads: int = 0
    drop_at: set[int] = field(default_factory=set)
    repeat_at: set[int] = field(default_factory=set)
    wrong_size_at: set[int] = field(default_factory=set)
    wrong_dtype_at: set[int] = field(default_factory=set)
    exposure_change_at: int | None = None
    exposure_factor: float = 0.5


@dataclass(frozen=True)
class InjectedFault:
    """One fault as it happened: which read, what kind, the sub-frame sequence returned
    (None for a disconnect) and the host ``time.monotonic()`` time of the read, seconds."""

    read: int
    kind: str
    sequence: int | None
    time_s: float


class FaultyCamera(Camera):
    """Wrap ``inner`` and inject :class:`CameraFaults`; ``injected`` lists what was done."""

    def __init__(self, inner: Camera, faults: CameraFaults) -> None:
        self.inner = inner
        self.faults = faults
        self.reads = 0
        self.rate_hz = inner.rate_hz
        self._previous: SubFrame | None = None
        self._exposure_scale = 1.0
        self.injected: list[InjectedFault] = []

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)

    def factory_calibration(self) -> Calibration | None:
        return self.inner.factory_calibration()

    def _disconnected(self, index: int) -> bool:
        start = self.faults.disconnect_at
        return start is not None and start <= index < start + self.faults.disconnect_reads

    def _note(self, index: int, kind: str, sequence: int | None) -> None:
        self.injected.append(InjectedFault(index, kind, sequence, time.monotonic()))

    def _read(self, timeout_s: float) -> SubFrame:
        index = self.reads
        self.reads += 1
        if self._disconnected(index):
            self._note(index, "disconnect", None)
            raise CameraLostError(f"injected camera disconnect at read {index}")
        if index in self.faults.repeat_at and self._previous is not None:
            self._note(index, "repeat", self._previous.sequence)
            return self._previous
        sub = self._fetch(index, timeout_s)
        self._previous = sub
        return self._corrupt(sub, index)

    def _fetch(self, index: int, timeout_s: float) -> SubFrame:
        """Read from ``inner``, dropping one sub-frame or changing the exposure when due."""
        sub = self.inner.read(timeout_s)
        if index in self.faults.drop_at:
            sub = self.inner.read(timeout_s)
            self._note(index, "drop", sub.sequence)
        if index == self.faults.exposure_change_at:
            self._exposure_scale = self.faults.exposure_factor
            self._note(index, "exposure", sub.sequence)
        return replace(sub, exposure_us=sub.exposure_us * self._exposure_scale)

    def _corrupt(self, sub: SubFrame, index: int) -> SubFrame:
        if index in self.faults.wrong_size_at:
            self._note(index, "wrong_size", sub.sequence)
            cropped: Any = np.ascontiguousarray(sub.pixels[:-8, :-8])
            return replace(sub, pixels=cropped)
        if index in self.faults.wrong_dtype_at:
            self._note(index, "wrong_dtype", sub.sequence)
            wrong: Any = sub.pixels.astype(np.float32)
            return replace(sub, pixels=wrong)
        return sub

    def _close(self) -> None:
        self.inner.close()
