"""Open a python-can bus from configuration, and watch its health.

Settings are python-can's own: ``interface``, ``channel``, ``bitrate``, ``fd``. Values
given explicitly win; with ``python_can_sources=True`` the missing ones come from where
python-can reads them (``CAN_INTERFACE``, ``CAN_CHANNEL``, ``CAN_BITRATE``, ``CAN_CONFIG``
and the ``can.conf`` / ``.canrc`` files), and ``virtual`` on channel ``atris`` is the
embedded default when nothing names an interface.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import Any

import can

from atris_node.errors import BusError

logger = logging.getLogger(__name__)

DEFAULT_INTERFACE = "virtual"
DEFAULT_CHANNEL = "atris"
#: socketcan error class bits (linux/can/error.h), in the error frame's arbitration ID
CAN_ERR_CRTL = 0x04
CAN_ERR_BUSOFF = 0x40
CAN_ERR_RESTARTED = 0x100


@dataclass(frozen=True)
class BusConfig:
    """python-can bus settings; None means "not given"."""

    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None
    fd: bool | None = None

    def given(self) -> dict[str, Any]:
        """The settings that were given, as python-can keyword arguments."""
        return {k: v for k, v in vars(self).items() if v is not None}


def resolve(config: BusConfig, python_can_sources: bool = False) -> dict[str, Any]:
    """Keyword arguments for :class:`can.Bus`: given values, python-can's sources, default."""
    kwargs = config.given()
    if python_can_sources:
        try:
            kwargs = dict(can.util.load_config(config=kwargs))
        except can.CanInterfaceNotImplementedError as exc:
            raise BusError(f"unknown CAN interface: {exc}") from exc
    if not kwargs.get("interface"):
        kwargs["interface"] = DEFAULT_INTERFACE
        kwargs.setdefault("channel", DEFAULT_CHANNEL)
    if kwargs.get("channel") is None:
        kwargs["channel"] = DEFAULT_CHANNEL
    return kwargs


def open_bus(config: BusConfig | None = None, python_can_sources: bool = False,
             **extra: Any) -> can.BusABC:
    """Open the bus ``config`` describes; BusError when the interface cannot be opened."""
    kwargs = {**resolve(config or BusConfig(), python_can_sources), **extra}
    logger.info("opening CAN bus %s", kwargs)
    try:
        return can.Bus(**kwargs)
    except (can.CanError, OSError, ImportError, ValueError) as exc:
        raise BusError(f"cannot open CAN bus {kwargs}: {exc}; accepted interfaces: "
                       f"{', '.join(sorted(can.VALID_INTERFACES))}") from exc


class BusHealth(can.Listener):
    """Counts error frames and bus-off reports on a bus (add it to the bus's Notifier).

    ``take_error()`` answers True once after any error frame, so a status frame can
    carry FaultBits.BUS_ERROR for the cycle that followed it.
    """

    def __init__(self) -> None:
        self.error_frames = 0
        self.bus_off_count = 0
        self.restarts = 0
        self._pending = False
        self._lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        if not msg.is_error_frame:
            return
        with self._lock:
            self.error_frames += 1
            self._pending = True
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self.bus_off_count += 1
                logger.error("CAN bus-off reported (error class 0x%X)", msg.arbitration_id)
            elif msg.arbitration_id & CAN_ERR_RESTARTED:
                self.restarts += 1
                logger.warning("CAN controller restarted after bus-off")
            else:
                logger.warning("CAN error frame, class 0x%X", msg.arbitration_id)

    def on_error(self, exc: Exception) -> None:
        logger.error("CAN receive failed: %s", exc)
        with self._lock:
            self._pending = True

    def take_error(self) -> bool:
        """True if an error was seen since the last call."""
        with self._lock:
            pending, self._pending = self._pending, False
            return pending
