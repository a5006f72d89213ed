"""A camera that hands out pre-rendered sub-frames at their scheduled times, for benchmarks.

:class:`PacedCamera` stands in for a real camera at its native rate without rendering
anything while it runs: its own thread (the "sensor") produces sub-frame ``s`` at
``start_s + s / rate_hz`` on the host clock and puts it into a bounded queue of
``queue_depth`` sub-frames, the way a camera driver fills a fixed set of frame buffers.
The consumer (the unit's loop) takes sub-frames from that queue.

Drop rule (as a V4L2 driver with no free buffer): a sub-frame that finds the queue full
when it is due is dropped; the sub-frames already queued stay, and the consumer sees the
gap in sequence numbers. A sensor thread that wakes late (a busy machine, the GIL) hands
out every sub-frame that is due at once, each under the same rule. The host timestamp of a
sub-frame is its scheduled arrival time, not the moment the late thread got to it, so the
data age measured from it includes that lateness.

Chips: the projector strobes the code it was given with ``set_code`` (as a device that
strobes on its own, the depthai Script) for every sequence number, while it is lit; the
sub-frame shows the pre-rendered ON or OFF picture of its index accordingly.

Counting: sub-frames with sequence numbers in ``[first, end)`` (:meth:`PacedCamera.count`)
are counted as offered, dropped (queue full) and consumed (read), and ``gaps`` counts the
consumed ones that do not follow the sub-frame read before (the demodulator restarts its
window there). After the run,
``offered == consumed + dropped + pending`` where ``pending`` is what was still queued.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.calibration import Calibration
from atris_node.errors import CameraLostError, ConfigError
from atris_node.mounting import Mounting
from atris_node.types import SubFrame
from drivers.base import Camera, Projector

Pixels = npt.NDArray[np.uint8] | npt.NDArray[np.uint16]


@dataclass
class Counts:
    """Sub-frames of the counted sequence range ``[first, end)``."""

    first: int = 0
    end: int = 0
    offered: int = 0
    dropped: int = 0
    consumed: int = 0
    gaps: int = 0  # consumed sub-frames not following the one before (a window restart)

    def holds(self, sequence: int) -> bool:
        """True when ``sequence`` is in the counted range."""
        return self.first <= sequence < self.end


@dataclass(frozen=True)
class Prerendered:
    """Pre-rendered pictures: ``off[i]`` and ``on[i]`` for index ``i = sequence % len``
    (each (H, W) uint8/uint16, DN), and what the camera says about them."""

    off: Sequence[Pixels]
    on: Sequence[Pixels]
    rate_hz: float
    bits: int
    exposure_us: float
    calibration: Calibration
    mounting: Mounting

    @property
    def nbytes(self) -> int:
        """Bytes held by the pictures."""
        return sum(int(p.nbytes) for p in (*self.off, *self.on))


class PacedProjector(Projector):
    """Strobes the code given by :meth:`set_code` on every sub-frame while lit."""

    def __init__(self) -> None:
        self._code: npt.NDArray[np.uint8] | None = None

    def set_code(self, chips: npt.ArrayLike) -> None:
        """The chips (0/1) strobed from now on, chip ``s % N`` for sequence ``s``."""
        self._code = np.asarray(chips, dtype=np.uint8).copy()

    def chip_for(self, sequence: int) -> int:
        """The chip emitted during ``sequence``: 0 while off, closed or without a code."""
        code = self._code
        if code is None or not self._lit or self._closed:
            return 0
        return int(code[sequence % code.size])

    def _strobe(self, chip: int, sequence: int) -> None:
        """Nothing to do: the code is strobed by sequence number (``set_code``)."""

    def _off(self) -> None:
        """Dark at once: :meth:`chip_for` reads ``is_lit``."""


class PacedCamera(Camera):
    """Pre-rendered sub-frames, due at ``start_s + sequence / rate_hz``, through a queue.

    Args:
        frames: the pictures and their camera facts.
        projector: decides the chip of each sub-frame.
        queue_depth: frame buffers between the sensor and the consumer (>= 1).
        clock: seconds, the host clock (``time.monotonic``).
    """

    def __init__(self, frames: Prerendered, projector: PacedProjector, queue_depth: int = 4,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if queue_depth < 1:
            raise ConfigError(f"queue_depth must be at least 1, got {queue_depth}")
        self.pictures, self.projector, self.clock = frames, projector, clock
        self.rate_hz = frames.rate_hz
        self.bits = frames.bits
        self.size = (int(frames.off[0].shape[1]), int(frames.off[0].shape[0]))
        self.mounting = frames.mounting
        self.counts = Counts()
        self.start_s = 0.0
        self.sensor_late_max_s = 0.0  # worst lateness of the sensor thread
        self._queue: queue.Queue[SubFrame] = queue.Queue(maxsize=queue_depth)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_read = -1  # sequence of the last sub-frame read

    def factory_calibration(self) -> Calibration:
        """The calibration of the rendered scene."""
        return self.pictures.calibration

    def count(self, first: int, end: int) -> None:
        """Count the sub-frames with sequence numbers in ``[first, end)``."""
        self.counts = Counts(first, end)

    def due_s(self, sequence: int) -> float:
        """Scheduled host arrival time of ``sequence``, seconds on ``clock``."""
        return self.start_s + sequence / self.rate_hz

    def start(self, lead_s: float = 0.05) -> None:
        """Start the sensor thread; sub-frame 0 is due ``lead_s`` from now."""
        self.start_s = self.clock() + lead_s
        self._thread = threading.Thread(target=self._sense, name="atris-bench-sensor",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> int:
        """Stop the sensor thread; the counted sub-frames still queued (``pending``)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        pending = 0
        while True:
            try:
                pending += self.counts.holds(self._queue.get_nowait().sequence)
            except queue.Empty:
                return pending

    def _sense(self) -> None:
        sequence = 0
        while not self._stop.is_set():
            delay = self.due_s(sequence) - self.clock()
            if delay > 0 and self._stop.wait(delay):
                return
            late = self.clock() - self.due_s(sequence)
            self.sensor_late_max_s = max(self.sensor_late_max_s, late)
            self._offer(sequence)
            sequence += 1

    def _offer(self, sequence: int) -> None:
        chip = self.projector.chip_for(sequence)
        index = sequence % len(self.pictures.off)
        pixels = (self.pictures.on if chip else self.pictures.off)[index]
        sub = SubFrame(pixels, sequence, sequence / self.rate_hz, self.due_s(sequence),
                       self.pictures.exposure_us, bits=self.bits, chip=chip)
        counted = self.counts.holds(sequence)
        self.counts.offered += counted
        try:
            self._queue.put_nowait(sub)
        except queue.Full:
            self.counts.dropped += counted

    def _close(self) -> None:
        """The sensor stops producing; :meth:`stop` joins it and counts what is left."""
        self._stop.set()

    def _read(self, timeout_s: float) -> SubFrame:
        if self._closed:
            raise CameraLostError("paced camera is closed")
        try:
            sub = self._queue.get(timeout=timeout_s)
        except queue.Empty:
            raise CameraLostError(f"no sub-frame within {timeout_s} s") from None
        counted = self.counts.holds(sub.sequence)
        self.counts.consumed += counted
        self.counts.gaps += counted and sub.sequence != self._last_read + 1
        self._last_read = sub.sequence
        return sub
