"""Reading unit frames as a controller would: cantools with the shipped DBC file, and the
independent E2E Profile 1 model of ``e2e_reference``."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import can
import cantools
from e2e_reference import P01Receiver
from vcan_support import REPO_ROOT

from atris_node.bus.can.ids import FrameKind, frame_id

DBC_PATH = REPO_ROOT / "atris_node" / "bus" / "can" / "atris.dbc"


@dataclass
class Received:
    """One received unit frame: its message name, raw signals and kernel timestamp."""

    name: str
    signals: dict[str, Any]
    timestamp: float
    counter: int


def until_every_unit(bus: can.BusABC, unit_ids: Iterable[int], settled: Callable[[int], bool],
                     timeout_s: float) -> tuple[list[can.Message], float, set[int]]:
    """Every frame until each unit's Status frame has shown a State that ``settled``
    accepts (at most ``timeout_s``): the frames, the seconds that took and the units that
    got there (the caller's checks fail on them if one never did)."""
    db = cantools.database.load_file(DBC_PATH)
    status_ids = {frame_id(uid, FrameKind.STATUS): uid for uid in unit_ids}
    frames, heard, begin = list[can.Message](), set[int](), time.monotonic()
    while heard != set(status_ids.values()) and time.monotonic() - begin < timeout_s:
        msg = bus.recv(0.1)
        if msg is None:
            continue
        frames.append(msg)
        if msg.arbitration_id not in status_ids:
            continue
        signals = db.decode_message(msg.arbitration_id, bytes(msg.data), decode_choices=False)
        if settled(int(signals["State"])):
            heard.add(status_ids[msg.arbitration_id])
    return frames, time.monotonic() - begin, heard


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
