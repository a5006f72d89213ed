"""The two hardware roles: a camera that yields sub-frames and a projector strobed per chip.

A backend writes only the hardware-specific methods; the base classes do the generic
work (context manager, idempotent ``close()``), in the manner of python-can's ``BusABC``.
"""

from __future__ import annotations

import abc
from collections.abc import Iterator
from types import TracebackType
from typing import Self

from atris_node.calibration import Calibration
from atris_node.types import SubFrame


class _Closing:
    """Context manager over ``close()``, shared by both roles."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class Camera(_Closing, abc.ABC):
    """A source of sub-frames.

    ``read(timeout_s)`` returns the next sub-frame or raises
    :class:`atris_node.errors.CameraLostError` when none arrives in time.
    """

    _closed: bool = False
    #: sub-frame rate in Hz (the chip rate); 0.0 when the backend does not know it
    rate_hz: float = 0.0

    @abc.abstractmethod
    def _read(self, timeout_s: float) -> SubFrame:
        """Backend: block for at most ``timeout_s`` and return one sub-frame."""

    def read(self, timeout_s: float = 1.0) -> SubFrame:
        """Return the next sub-frame; raises CameraLostError on timeout or loss."""
        return self._read(timeout_s)

    def factory_calibration(self) -> Calibration | None:
        """Calibration the device itself knows (the simulator's truth), or None."""
        return None

    def set_exposure_us(self, exposure_us: float) -> None:
        """Request an exposure time; backends without exposure control ignore it."""

    def frames(self, timeout_s: float = 1.0) -> Iterator[SubFrame]:
        """Yield sub-frames until the camera is closed."""
        while not self._closed:
            yield self.read(timeout_s)

    def _close(self) -> None:
        """Backend: release the device."""

    def close(self) -> None:
        """Release the camera; safe to call more than once."""
        if not self._closed:
            self._closed = True
            self._close()


class Projector(_Closing, abc.ABC):
    """A pattern projector switched ON/OFF per sub-frame.

    The base keeps the safety rule: after ``off()`` or ``close()`` the projector is dark
    and ``is_lit`` is False.
    """

    _closed: bool = False
    _lit: bool = False

    @abc.abstractmethod
    def _strobe(self, chip: int, sequence: int) -> None:
        """Backend: set the chip (0 or 1) for the sub-frame with this sequence number."""

    @abc.abstractmethod
    def _off(self) -> None:
        """Backend: switch the emitter off now."""

    def strobe(self, chip: int, sequence: int) -> None:
        """Set the chip for a sub-frame. Raises ValueError for a chip other than 0 or 1."""
        if chip not in (0, 1):
            raise ValueError(f"chip must be 0 or 1, got {chip!r}")
        if self._closed:
            return
        self._strobe(chip, sequence)
        self._lit = True

    def off(self) -> None:
        """Switch the projector off; safe to call at any time and more than once."""
        self._off()
        self._lit = False

    def set_intensity(self, fraction: float) -> None:
        """Set emitter power as a fraction 0..1 of the maximum."""

    @property
    def is_lit(self) -> bool:
        """True while the projector may emit (strobing), False once switched off."""
        return self._lit

    def close(self) -> None:
        """Switch off and release; safe to call more than once."""
        if not self._closed:
            self.off()
            self._closed = True
