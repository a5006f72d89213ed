"""Open a python-can bus from configuration, and watch its health.

Settings are python-can's own (``interface``, ``channel``, ``bitrate``, ``fd``, and any
other keyword of the interface), taken key by key from the first source that has them,
in python-can's order (``can.util.load_config``):

1. the arguments: what the command line or the node's own configuration gives;
2. ``can.rc``, then the environment: ``CAN_INTERFACE``, ``CAN_CHANNEL``, ``CAN_BITRATE``,
   over the JSON object in ``CAN_CONFIG``;
3. python-can's config files, section ``[default]`` (on Linux ``~/can.conf``,
   ``/etc/can.conf``, ``~/.can``, ``~/.canrc``, the later ones winning);
4. the defaults: interface ``virtual``, on channel ``atris``; another interface gets a
   bit rate of 500 kbit/s and its backend's own default channel.

The bus is then opened with exactly these settings (``ignore_config=True``): python-can
does not add more of its own.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import can

from atris_node.errors import BusError

logger = logging.getLogger(__name__)

DEFAULT_INTERFACE = "virtual"
DEFAULT_CHANNEL = "atris"
DEFAULT_BITRATE = 500_000
#: interfaces without a bit rate: the default one is not passed to them
NO_BITRATE = ("virtual", "udp_multicast")
#: socketcan error class bits (linux/can/error.h), in the error frame's arbitration ID
CAN_ERR_CRTL = 0x04
CAN_ERR_BUSOFF = 0x40
CAN_ERR_RESTARTED = 0x100


@dataclass(frozen=True)
class BusConfig:
    """python-can bus settings given as arguments; None means "not given"."""

    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None
    fd: bool | None = None

    def given(self) -> dict[str, Any]:
        """The settings that were given, as python-can keyword arguments."""
        return {k: v for k, v in vars(self).items() if v is not None}


def python_can_sources() -> list[dict[str, Any]]:
    """python-can's own settings below the arguments, highest first: ``can.rc``, the
    environment, the config files (read now, as python-can reads them)."""
    try:
        environment = can.util.load_environment_config()
    except json.JSONDecodeError as exc:
        raise BusError(f"CAN_CONFIG is not a JSON object: {exc}") from exc
    return [dict(can.rc), dict(environment), dict(can.util.load_file_config())]


def defaults_for(interface: str | None) -> dict[str, Any]:
    """The lowest level: ``virtual`` on ``atris`` when nothing names an interface, else
    ``atris`` for a virtual bus and 500 kbit/s for an interface with a bit rate."""
    interface = interface or DEFAULT_INTERFACE
    if interface == DEFAULT_INTERFACE:
        return {"interface": interface, "channel": DEFAULT_CHANNEL}
    return {} if interface in NO_BITRATE else {"bitrate": DEFAULT_BITRATE}


def _without_bustype(source: Mapping[str, Any]) -> dict[str, Any]:
    """python-can's legacy ``bustype`` key as ``interface``, as load_config reads it."""
    settings = dict(source)
    bustype = settings.pop("bustype", None)
    if bustype and not settings.get("interface"):
        settings["interface"] = bustype
    return settings


def merge(*sources: Mapping[str, Any]) -> dict[str, Any]:
    """Key by key, the first source that has a key wins."""
    merged: dict[str, Any] = {}
    for source in sources:
        for key, value in _without_bustype(source).items():
            merged.setdefault(key, value)
    return merged


def resolve(config: BusConfig) -> dict[str, Any]:
    """Keyword arguments for :class:`can.Bus`: arguments > python-can's sources > defaults,
    checked and typed by python-can (strings from files become numbers)."""
    found = merge(config.given(), *python_can_sources())
    settings = merge(found, defaults_for(found.get("interface")))
    try:
        return dict(can.util.load_config(config=settings))
    except (can.CanInterfaceNotImplementedError, ValueError, TypeError) as exc:
        raise BusError(f"bus settings {settings} not accepted: {exc}; accepted interfaces: "
                       f"{', '.join(sorted(can.VALID_INTERFACES))}") from exc


def open_bus(config: BusConfig | None = None, **extra: Any) -> can.BusABC:
    """Open the bus ``config`` and python-can's sources describe (:func:`resolve`), with
    ``extra`` keywords over them; BusError when the interface cannot be opened."""
    kwargs = {**resolve(config or BusConfig()), **extra}
    logger.info("opening CAN bus %s", kwargs)
    try:
        return can.Bus(ignore_config=True, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError, TypeError) as exc:
        raise BusError(f"cannot open CAN bus {kwargs}: {exc}; accepted interfaces: "
                       f"{', '.join(sorted(can.VALID_INTERFACES))}") from exc


def admit_error_frames(bus: can.BusABC) -> None:
    """Let error frames through ``bus``'s receive filters wherever python-can applies them
    in software, so that :class:`BusHealth` hears them whatever the filters are.

    A filter matches identifiers, and an error frame's identifier is its error class
    (0x40 bus-off, 0x04 controller...), so an id filter drops it. SocketCAN filters in the
    kernel and delivers error frames by their own mask (``CAN_RAW_ERR_FILTER``, all
    classes, set by python-can when the bus opens), beside the id filters; python-can's
    ``recv`` then skips its software check and nothing here applies. Where the interface
    does not filter (virtual, ``FaultyBus``, a kernel that refused the filters), python-can
    checks every frame with ``BusABC._matches_filters``: this bus's check is replaced by
    one that passes error frames and asks the original for every other frame. Idempotent;
    the filters themselves may be set again later (``set_filters``).
    """
    matches = bus._matches_filters
    if getattr(matches, "admits_error_frames", False):
        return

    def error_frame_or_match(msg: can.Message) -> bool:
        return msg.is_error_frame or matches(msg)

    error_frame_or_match.admits_error_frames = True  # type: ignore[attr-defined]
    bus._matches_filters = error_frame_or_match  # type: ignore[method-assign]


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
