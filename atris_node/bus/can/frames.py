"""Encode and decode frames through cantools with the CAN database, generic over messages.

The database of the default base ID is the shipped ``atris.dbc``; for another base
(the ``bus.base_id`` setting) it is generated from the same frame table
(:mod:`atris_node.bus.can.dbc`), so this codec is the one place that maps IDs to frames.

Messages are looked up by name (encode) or by exact arbitration ID (decode), as any DBC
tool does, so messages added to the frame table work without code here. A message with an
``E2EDataID`` attribute is E2E protected (:mod:`atris_node.bus.can.e2e`): its ``CRC`` and
``Counter`` signals are filled in by :meth:`FrameCodec.encode`.
"""

from __future__ import annotations

import functools
import importlib.resources
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import can
import cantools
from cantools.database.can import Database, Message

from atris_node.bus.can import e2e
from atris_node.bus.can.dbc import build_database
from atris_node.bus.can.ids import DEFAULT_BASE_ID, check_base_id
from atris_node.errors import FrameDecodeError

logger = logging.getLogger(__name__)

DBC_NAME = "atris.dbc"
E2E_ATTRIBUTE = "E2EDataID"
SignalValue = int | float | str


def dbc_path() -> Path:
    """Path of the shipped DBC (package data ``atris_node/bus/can/atris.dbc``)."""
    return Path(str(importlib.resources.files("atris_node.bus.can").joinpath(DBC_NAME)))


def dbc_text() -> str:
    """Text of the shipped DBC."""
    return dbc_path().read_text("utf-8")


@functools.cache
def load_database(base_id: int = DEFAULT_BASE_ID) -> Database:
    """The CAN database for unit frames from ``base_id``, made once per base from the frame
    table (strict: overlapping signals are an error). For the default base it is the
    shipped DBC (a test holds the file equal to the generated text); building the objects
    takes about a fifth of the time parsing the 2160-message text does."""
    return build_database(check_base_id(base_id, allow_canopen=True))


def _attribute(message: Message, name: str) -> int | None:
    attributes = message.dbc.attributes if message.dbc is not None else {}
    attribute = attributes.get(name)
    return None if attribute is None else int(attribute.value)


def e2e_data_id(message: Message) -> int | None:
    """E2E data ID of ``message`` from its DBC attribute, or None when unprotected."""
    return _attribute(message, E2E_ATTRIBUTE)


@dataclass(frozen=True)
class DecodedFrame:
    """One received frame, decoded with the DBC.

    ``signals`` holds physical values; raw values listed in a VAL_ table come out as
    their name (``"invalid"``, ``"no_return"``...). ``crc_ok`` is None for messages
    without E2E protection.
    """

    name: str
    arbitration_id: int
    is_extended_id: bool
    signals: dict[str, SignalValue]
    data_id: int | None = None
    crc_ok: bool | None = None


class FrameCodec:
    """Encoder/decoder over one cantools database: ``database``, else the one of
    ``base_id`` (:func:`load_database`; the shipped DBC for the default base)."""

    def __init__(self, database: Database | None = None,
                 base_id: int = DEFAULT_BASE_ID) -> None:
        self.database = database if database is not None else load_database(base_id)
        self._by_id = {(m.frame_id, m.is_extended_frame): m for m in self.database.messages}

    def message(self, name: str) -> Message:
        """The DBC message called ``name``; FrameDecodeError when there is none."""
        try:
            return self.database.get_message_by_name(name)
        except KeyError:
            raise FrameDecodeError(f"no message {name!r} in the CAN database") from None

    def encode(self, name: str, signals: Mapping[str, SignalValue], counter: int = 0,
               *, scaling: bool = True, fd: bool = False) -> can.Message:
        """Frame of message ``name`` from ``signals`` (physical, or raw if not ``scaling``).

        E2E protected messages get ``Counter = counter`` (0..14) and their CRC; others
        ignore ``counter``. Out-of-range values raise FrameDecodeError (strict).
        """
        message = self.message(name)
        data_id = e2e_data_id(message)
        values = dict(signals)
        if data_id is not None:
            values.update(CRC=0, Counter=counter)
        data = self._encode(message, values, scaling)
        if data_id is not None:
            data = e2e.protect(data, data_id, counter)
        return can.Message(arbitration_id=message.frame_id, data=data, is_fd=fd,
                           bitrate_switch=fd, is_extended_id=message.is_extended_frame)

    def decode(self, arbitration_id: int, data: bytes,
               is_extended_id: bool = False) -> DecodedFrame:
        """Decode one frame; FrameDecodeError for unknown IDs or malformed data."""
        message = self._lookup(arbitration_id, is_extended_id)
        if message is None:
            kind = "extended" if is_extended_id else "standard"
            raise FrameDecodeError(f"{kind} ID 0x{arbitration_id:X} is not in the CAN database")
        if len(data) != message.length:
            raise FrameDecodeError(f"{message.name}: {len(data)} data bytes, "
                                   f"the DBC says {message.length}")
        signals = self._decode(message, bytes(data))
        data_id = e2e_data_id(message)
        crc_ok = None if data_id is None else data[0] == e2e.profile1_crc(data_id, data)
        return DecodedFrame(message.name, arbitration_id, is_extended_id, signals,
                            data_id, crc_ok)

    def decode_message(self, msg: can.Message) -> DecodedFrame:
        """:meth:`decode` of a python-can message."""
        return self.decode(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)

    def _lookup(self, arbitration_id: int, is_extended_id: bool) -> Message | None:
        return self._by_id.get((arbitration_id, is_extended_id))

    @staticmethod
    def _encode(message: Message, values: dict[str, SignalValue], scaling: bool) -> bytes:
        try:
            return bytes(message.encode(values, scaling=scaling, strict=True))
        except (cantools.database.EncodeError, KeyError, ValueError, TypeError) as exc:
            raise FrameDecodeError(f"cannot encode {message.name}: {exc}") from exc

    @staticmethod
    def _decode(message: Message, data: bytes) -> dict[str, SignalValue]:
        try:
            decoded = message.decode(data, decode_choices=True, scaling=True)
        except (cantools.database.DecodeError, ValueError) as exc:
            raise FrameDecodeError(f"cannot decode {message.name}: {exc}") from exc
        assert isinstance(decoded, dict)
        return {k: v if isinstance(v, int | float) else str(v) for k, v in decoded.items()}
