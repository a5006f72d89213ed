"""Reading unit frames as a controller would: cantools with the shipped DBC file, and the
independent E2E Profile 1 model of ``e2e_reference``."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import can
from e2e_reference import P01Receiver
from vcan_support import REPO_ROOT

DBC_PATH = REPO_ROOT / "atris_node" / "bus" / "can" / "atris.dbc"


@dataclass
class Received:
    """One received unit frame: its message name, raw signals and kernel timestamp."""

    name: str
    signals: dict[str, Any]
    timestamp: float
    counter: int


def listen(bus: can.BusABC, duration_s: float) -> list[can.Message]:
    """Every frame that arrives on ``bus`` during ``duration_s``."""
    frames, deadline = [], time.monotonic() + duration_s
    while time.monotonic() < deadline:
        msg = bus.recv(0.05)
        if msg is not None:
            frames.append(msg)
    return frames


#: the reference E2E verdicts of a frame that arrived intact and in order
IN_ORDER = ("ok", "initial")


def check_and_decode(db: Any, frames: list[can.Message], receivers: dict[int, P01Receiver],
                     accepted: tuple[str, ...] = IN_ORDER) -> list[Received]:
    """Decodes ``frames`` with the DBC; every one must pass the reference E2E check with
    one of the ``accepted`` verdicts."""
    out = []
    for msg in frames:
        message = db.get_message_by_frame_id(msg.arbitration_id)
        data_id = message.dbc.attributes["E2EDataID"].value
        receiver = receivers.setdefault(msg.arbitration_id, P01Receiver(data_id, timeout_s=1.0))
        verdict = receiver.check(bytes(msg.data), msg.timestamp)
        assert verdict in accepted, (message.name, verdict)
        signals = message.decode(bytes(msg.data), decode_choices=False, scaling=True)
        out.append(Received(message.name, signals, msg.timestamp, msg.data[1] & 0x0F))
    return out


def cycles(frames: list[Received]) -> list[list[Received]]:
    """Frames grouped into publish cycles, each starting with a Status frame."""
    groups: list[list[Received]] = []
    for frame in frames:
        if frame.name.endswith("_Status") or not groups:
            groups.append([])
        groups[-1].append(frame)
    return groups
