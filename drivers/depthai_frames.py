"""From ``dai.ImgFrame`` messages on an output queue to :class:`SubFrame`.

This is the one piece of the depthai backend that both a real OAK and the hardware-free
test use: the frames come from a ``dai.MessageQueue``, whether a MonoCamera on a device
or a host node of a ``dai.Pipeline(createImplicitDevice=False)`` produced them.

Alignment is by sequence number, never by arrival order: ``FrameReader`` counts the
sequence numbers that never arrived (``dropped``), and asks ``chip_for(sequence)`` which
chip the projector was commanded for each sub-frame.

Time: a sub-frame's ``host_time_s`` is its exposure mid-time on the host's monotonic
clock, as depthai maps the device clock to the host (``ImgFrame.getTimestamp``:
``dai::Clock``, the steady clock ``time.monotonic`` reads on Linux), never the time the
host happened to read it: a frame that sat in a queue for seconds is seconds old. A
timestamp ahead of the host clock is a clock error; it is kept (its age is negative, and
a negative age is never fresh) and logged.
"""

from __future__ import annotations

import datetime
import logging
import time
from collections.abc import Callable
from typing import Any, Protocol

import depthai as dai
import numpy as np

from atris_node.errors import CameraLostError, DriverError
from atris_node.types import SubFrame

logger = logging.getLogger(__name__)

#: a timestamp this far ahead of the host clock is reported as a clock error, seconds
FUTURE_TOLERANCE_S = 0.001
#: significant bits of the unpacked single-plane frame types this reader accepts
BITS_BY_TYPE: dict[Any, int] = {
    dai.ImgFrame.Type.GRAY8: 8, dai.ImgFrame.Type.RAW8: 8, dai.ImgFrame.Type.RAW10: 10,
    dai.ImgFrame.Type.RAW12: 12, dai.ImgFrame.Type.RAW14: 14, dai.ImgFrame.Type.RAW16: 16,
}


class FrameQueue(Protocol):
    """What the reader needs of a ``dai.MessageQueue``."""

    def get(self, timeout: datetime.timedelta) -> Any: ...


def frame_bits(frame: dai.ImgFrame) -> int:
    """Significant bits per pixel of ``frame``; DriverError for other frame types."""
    bits = BITS_BY_TYPE.get(frame.getType())
    if bits is None:
        accepted = ", ".join(t.name for t in BITS_BY_TYPE)
        raise DriverError(f"frame type {frame.getType().name} is not a single-plane grey or "
                          f"unpacked raw type; accepted: {accepted}")
    return bits


def frame_pixels(frame: dai.ImgFrame, bits: int) -> np.ndarray[Any, Any]:
    """(H, W) pixels of ``frame``: uint8 for 8 bits, uint16 for 10..16 bits."""
    pixels = np.asarray(frame.getFrame())
    wanted = np.uint8 if bits <= 8 else np.uint16
    if pixels.ndim != 2 or pixels.dtype != wanted:
        raise DriverError(f"frame {frame.getSequenceNum()} gives {pixels.shape} "
                          f"{pixels.dtype} pixels; accepted: (H, W) {np.dtype(wanted)}")
    return pixels


def exposure_host_time_s(frame: dai.ImgFrame) -> float:
    """The exposure mid-time of ``frame`` on the host's monotonic clock, seconds."""
    return float(frame.getTimestamp(dai.CameraExposureOffset.MIDDLE).total_seconds())


def to_sub_frame(frame: dai.ImgFrame, host_time_s: float, chip: int | None = None) -> SubFrame:
    """One ``dai.ImgFrame`` as a SubFrame.

    ``device_time_s`` is the exposure mid-time on the device clock, ``exposure_us`` comes
    from ``getExposureTime``; ``host_time_s`` is the exposure time on the host clock
    (:func:`exposure_host_time_s`).
    """
    bits = frame_bits(frame)
    device_time = frame.getTimestampDevice(dai.CameraExposureOffset.MIDDLE)  # type: ignore[call-arg]
    return SubFrame(pixels=frame_pixels(frame, bits), sequence=int(frame.getSequenceNum()),
                    device_time_s=device_time.total_seconds(), host_time_s=host_time_s,
                    exposure_us=frame.getExposureTime().total_seconds() * 1e6, bits=bits,
                    chip=chip)


class FrameReader:
    """Reads SubFrames from a queue of ImgFrames and tracks dropped sequence numbers.

    ``read`` raises CameraLostError when no frame arrives within the timeout, when the
    queue is closed, or when depthai reports an X_LINK error (wrapped with ``from``).
    """

    def __init__(self, queue: FrameQueue, chip_for: Callable[[int], int | None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.queue = queue
        self.chip_for = chip_for
        self.clock = clock
        self.dropped = 0
        self.last_sequence: int | None = None

    def _get(self, timeout_s: float) -> Any:
        try:
            message = self.queue.get(datetime.timedelta(seconds=timeout_s))
        except (dai.XLinkError, dai.MessageQueue.QueueException, RuntimeError) as exc:
            raise CameraLostError(f"camera link lost: {exc}") from exc
        if message is None:
            raise CameraLostError(f"no sub-frame from the camera within {timeout_s} s")
        if not isinstance(message, dai.ImgFrame):
            raise DriverError(f"camera queue gave a {type(message).__name__}, not an ImgFrame")
        return message

    def _track(self, sequence: int) -> None:
        last = self.last_sequence
        if last is not None and sequence > last + 1:
            self.dropped += sequence - last - 1
            logger.debug("dropped sub-frames %d..%d", last + 1, sequence - 1)
        elif last is not None and sequence <= last:
            logger.warning("sequence went back from %d to %d (camera restarted?)", last, sequence)
        self.last_sequence = sequence

    def read(self, timeout_s: float = 1.0) -> SubFrame:
        """The next sub-frame, its chip from ``chip_for`` when given."""
        frame = self._get(timeout_s)
        host_time_s = exposure_host_time_s(frame)
        if host_time_s > self.clock() + FUTURE_TOLERANCE_S:
            logger.warning("sub-frame %d is stamped %.3f s in the future: device clock sync "
                           "is broken; its distances go out invalid", frame.getSequenceNum(),
                           host_time_s - self.clock())
        sequence = int(frame.getSequenceNum())
        self._track(sequence)
        chip = self.chip_for(sequence) if self.chip_for is not None else None
        return to_sub_frame(frame, host_time_s, chip)
