"""The ``replay`` backend: sub-frames written by ``atris record``, read back unchanged.

A replay cannot strobe anything: its projector is a no-op that only remembers which chip
was commanded for which sequence number. The chip that was really commanded when the
recording was made is the ``chip`` column of the recording (``SubFrame.chip``), and the
demodulator uses that one.

Sub-frames are yielded exactly as recorded (pixels, sequence, device and host times,
exposure, bits, chip). With ``loop=True`` the recording restarts at its end and each lap
shifts sequence numbers and times forward by one recording length, so they keep
increasing; with ``realtime=True`` reads are paced by the recorded host times.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

from atris_node.errors import CameraLostError
from atris_node.types import SubFrame
from drivers.base import Camera, Projector
from drivers.recording import Recording

logger = logging.getLogger(__name__)

#: commanded chips the replay projector keeps (the newest ones)
COMMAND_HISTORY = 4096


class EndOfRecordingError(CameraLostError, EOFError):
    """The replay reached the end of a recording opened without ``loop``."""


class ReplayCamera(Camera):
    """A camera that yields the sub-frames of a recording in order."""

    def __init__(self, recording: Recording, loop: bool = False, realtime: bool = False,
                 sleep: Callable[[float], None] = time.sleep,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.recording = recording
        self.loop = loop
        self.realtime = realtime
        self.rate_hz = recording.meta.rate_hz
        self.bits = recording.meta.bits
        self.size = (recording.meta.width, recording.meta.height)
        self._sleep, self._clock = sleep, clock
        self._position = 0
        self._lap = 0
        self._start: tuple[float, float] | None = None  # (clock, recorded host time)

    def _lap_shift(self) -> tuple[int, float]:
        """Sequence and time added to lap ``self._lap`` so both keep increasing."""
        index = self.recording.index
        if self._lap == 0 or len(self.recording) == 0:
            return 0, 0.0
        seq_span = int(index.sequence[-1] - index.sequence[0]) + 1
        period_s = 1.0 / self.rate_hz if self.rate_hz > 0 else 0.0
        time_span = float(index.host_time_s[-1] - index.host_time_s[0]) + period_s
        return self._lap * seq_span, self._lap * time_span

    def _next_position(self) -> int:
        if self._position >= len(self.recording):
            if not self.loop or len(self.recording) == 0:
                raise EndOfRecordingError(
                    f"end of recording {self.recording.directory} after "
                    f"{len(self.recording)} sub-frames (open it with loop=True to repeat)")
            self._position, self._lap = 0, self._lap + 1
        position = self._position
        self._position += 1
        return position

    def _pace(self, host_time_s: float) -> None:
        """Sleep until ``host_time_s`` is due, relative to the first sub-frame read."""
        now = self._clock()
        if self._start is None:
            self._start = (now, host_time_s)
            return
        delay = (host_time_s - self._start[1]) - (now - self._start[0])
        if delay > 0:
            self._sleep(delay)

    def _read(self, timeout_s: float) -> SubFrame:
        if self._closed:
            raise CameraLostError(f"replay of {self.recording.directory} is closed")
        sub = self.recording.sub_frame(self._next_position())
        seq_shift, time_shift = self._lap_shift()
        if seq_shift:
            sub = replace(sub, sequence=sub.sequence + seq_shift,
                          device_time_s=sub.device_time_s + time_shift,
                          host_time_s=sub.host_time_s + time_shift)
        if self.realtime:
            self._pace(sub.host_time_s)
        return sub

    def frames(self, timeout_s: float = 1.0) -> Iterator[SubFrame]:
        """Yield sub-frames until the end of the recording (never ends with ``loop``)."""
        try:
            yield from super().frames(timeout_s)
        except EndOfRecordingError:
            return


class ReplayProjector(Projector):
    """A projector that strobes nothing and remembers the commanded chips.

    ``commanded`` maps sequence number -> chip for the newest COMMAND_HISTORY commands.
    """

    def __init__(self) -> None:
        self.commanded: OrderedDict[int, int] = OrderedDict()

    def _strobe(self, chip: int, sequence: int) -> None:
        self.commanded[sequence] = chip
        self.commanded.move_to_end(sequence)
        while len(self.commanded) > COMMAND_HISTORY:
            self.commanded.popitem(last=False)

    def _off(self) -> None:
        """Nothing to switch off."""


def open_backend(path: str | Path, loop: bool = False,
                 realtime: bool = False) -> tuple[ReplayCamera, ReplayProjector]:
    """Open the recording directory ``path``; return its camera and a no-op projector.

    Raises ConfigError naming the file when the recording is missing, unfinished,
    truncated or corrupt.
    """
    recording = Recording(path)
    logger.info("replaying %d sub-frames of %s (loop=%s, realtime=%s)", len(recording),
                recording.directory, loop, realtime)
    return ReplayCamera(recording, loop=loop, realtime=realtime), ReplayProjector()
