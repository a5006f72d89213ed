"""Has the receive path handled every frame the bus had received? (the window's premise)

A unit may strobe a code once its claim stood the contest window uncontested. That is only
true if every frame received during the window was *handled*: a receive thread that is
starved of CPU (a loaded vehicle computer, a slow VM) leaves a lower NAME's claim unread in
the socket while the clock says the window has passed. :class:`ReceiveBarrier` answers "is
anything received still unread?" before the negotiator promotes a claim or chooses a row.

For buses with a file descriptor (SocketCAN and others that implement ``fileno``) the socket
is polled without reading it. When frames wait, a barrier is set at the current bus time;
the question is answered yes once the socket is found empty or a frame stamped at or after
the barrier has been handled (frames are handled in order, so everything that waited before
it was handled too). Buses without a descriptor (python-can's in-process ``virtual``) hand
frames over synchronously enough that the check is skipped, and so is poll mode, where
:meth:`Negotiator.tick` drains the bus itself before deciding.
"""

from __future__ import annotations

import logging
import select
import time
from collections.abc import Callable

import can

logger = logging.getLogger(__name__)


def bus_descriptor(bus: can.BusABC) -> int | None:
    """The bus's pollable file descriptor, or None when it has none."""
    try:
        fd = bus.fileno()
    except (NotImplementedError, OSError, ValueError):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


class ReceiveBarrier:
    """Tells whether every frame received so far has been handled.

    Args:
        fd: the bus socket to poll (None: the check always passes).
        wall_clock: seconds on the clock of received frames' timestamps (python-can's
            SocketCAN stamps frames with the kernel's receive time, ``time.time`` based).
    """

    def __init__(self, fd: int | None, wall_clock: Callable[[], float] = time.time) -> None:
        self.fd = fd
        self._wall_clock = wall_clock
        self._barrier_s: float | None = None
        self._latest_s = float("-inf")
        self.deferrals = 0

    def handled(self, timestamp_s: float) -> None:
        """Record that a frame with bus timestamp ``timestamp_s`` was handled."""
        self._latest_s = max(self._latest_s, timestamp_s)

    def caught_up(self) -> bool:
        """True when no received frame waits unhandled; False sets (or keeps) a barrier."""
        if self.fd is None:
            return True
        if self._barrier_s is not None and self._latest_s >= self._barrier_s:
            self._barrier_s = None
            return True
        if not self._unread():
            self._barrier_s = None
            return True
        if self._barrier_s is None:
            self._barrier_s = self._wall_clock()
        self.deferrals += 1
        return False

    def _unread(self) -> bool:
        assert self.fd is not None
        try:
            readable, _, _ = select.select([self.fd], [], [], 0.0)
        except (OSError, ValueError) as exc:  # closed socket: nothing more will be handled
            logger.debug("receive check failed: %s", exc)
            return False
        return bool(readable)
