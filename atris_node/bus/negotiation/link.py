"""The negotiator's side of the bus: frames in (a Notifier listener, or polled) and out.

Receiving never lets python-can's receive thread die: a frame that cannot be handled is
logged, a receive error is handed to the negotiator, which turns the laser off on its next
tick. Sending never blocks (``timeout=0``); a frame the bus refuses is counted and logged.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator

import can

from atris_node.bus.negotiation.frames import RawFrame
from atris_node.bus.negotiation.rx import ReceiveBarrier, bus_descriptor
from atris_node.errors import BusError

logger = logging.getLogger(__name__)

#: most frames one poll reads from the bus (poll mode)
MAX_FRAMES_PER_TICK = 512
#: sent frames kept for inspection
SENT_KEPT = 1000


class _Listener(can.Listener):
    """Feeds received frames to the negotiator; never lets the receive thread die."""

    def __init__(self, on_message: Callable[[can.Message], None],
                 on_error: Callable[[BaseException], None]) -> None:
        self._on_message, self._on_error = on_message, on_error

    def on_message_received(self, msg: can.Message) -> None:
        try:
            self._on_message(msg)
        except Exception:
            logger.exception("negotiation frame %#x could not be handled", msg.arbitration_id)

    def on_error(self, exc: Exception) -> None:
        logger.error("negotiation receive failed: %s", exc)
        self._on_error(exc)


class Link:
    """Receives the negotiation frames of ``bus`` and sends the queued ``outbox``.

    Args:
        bus: the unit's python-can bus.
        on_message: called for each received message (from the Notifier thread).
        on_error: called with a receive error (from the Notifier thread).
        notifier: a Notifier the node already runs on ``bus``; else :meth:`attach` makes one.
        poll: no Notifier: :meth:`received` reads the bus when asked.
    """

    def __init__(self, bus: can.BusABC, on_message: Callable[[can.Message], None],
                 on_error: Callable[[BaseException], None],
                 notifier: can.Notifier | None = None, poll: bool = False) -> None:
        self.bus = bus
        self.poll = poll
        self.receive = ReceiveBarrier(None if poll else bus_descriptor(bus))
        self.outbox: list[RawFrame] = []
        self.sent: list[tuple[float, RawFrame]] = []
        self.send_failures = 0
        self._notifier, self._own_notifier = notifier, False
        self._listener = _Listener(on_message, on_error)

    def attach(self) -> None:
        """Start receiving (nothing to do in poll mode).

        Raises:
            BusError: the bus already has an active Notifier that was not passed in.
        """
        if self.poll:
            return
        if self._notifier is None:
            try:
                self._notifier = can.Notifier(self.bus, [self._listener], timeout=0.1)
            except ValueError as exc:  # python-can allows one active Notifier per bus
                raise BusError(f"{exc}: pass the bus's Notifier as notifier=") from exc
            self._own_notifier = True
        else:
            self._notifier.add_listener(self._listener)

    def detach(self) -> None:
        """Stop receiving: stop our own Notifier, or leave the shared one."""
        notifier, self._notifier = self._notifier, (None if self._own_notifier else self._notifier)
        if notifier is None or self.poll:
            return
        if self._own_notifier:
            notifier.stop()
            self._own_notifier = False
        elif self._listener in notifier.listeners:
            notifier.remove_listener(self._listener)

    def received(self) -> Iterator[can.Message]:
        """The messages waiting on the bus, at most MAX_FRAMES_PER_TICK (poll mode).

        Raises:
            BusError: the bus could not be read.
        """
        for _ in range(MAX_FRAMES_PER_TICK):
            try:
                msg = self.bus.recv(timeout=0.0)
            except can.CanError as exc:
                raise BusError(f"negotiation could not read the bus: {exc}") from exc
            if msg is None:
                return
            yield msg

    def flush(self, now: float) -> tuple[list[RawFrame], int]:
        """Send the outbox in order: the frames the bus took and how many it refused (each
        counted, logged and dropped)."""
        outbox, self.outbox = self.outbox, []
        taken, refused = [], 0
        for frame in outbox:
            msg = can.Message(arbitration_id=frame.can_id, data=frame.data,
                              is_extended_id=True)
            try:
                self.bus.send(msg, timeout=0.0)
            except (can.CanError, OSError) as exc:
                self.send_failures += 1
                refused += 1
                logger.warning("negotiation frame %#x not sent: %s", frame.can_id, exc)
            else:
                taken.append(frame)
                self.sent.append((now, frame))
        del self.sent[:-SENT_KEPT]
        return taken, refused
