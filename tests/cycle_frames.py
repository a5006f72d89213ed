"""The publish cycles of one unit as a controller sees them, decoded from a listening bus."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import can

from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.can.ids import FrameKind, unit_of
from atris_node.errors import FrameDecodeError


@dataclass
class Cycle:
    """One publish cycle of a unit as a controller sees it: the arrival time, state and
    all signals of its status frame, and the distances of its sector frames (floats, or
    the strings of the invalid and no-return codes)."""

    time_s: float
    state: str
    distances: list[Any] = field(default_factory=list)
    status: dict[str, Any] = field(default_factory=dict)

    @property
    def valid(self) -> bool:
        """True when any sector carries a distance."""
        return any(isinstance(d, float) for d in self.distances)


class CycleFrames(can.Listener):
    """The cycles of unit ``unit_id``, in arrival order (a status frame opens a cycle)."""

    def __init__(self, unit_id: int = 0) -> None:
        self.codec = FrameCodec()
        self.unit_id = unit_id
        self.cycles: list[Cycle] = []

    def on_message_received(self, msg: can.Message) -> None:
        found = None if msg.is_extended_id else unit_of(msg.arbitration_id)
        if found is None or found[0] != self.unit_id:
            return
        try:
            signals = self.codec.decode_message(msg).signals
        except FrameDecodeError:
            return
        if found[1] is FrameKind.STATUS:
            self.cycles.append(Cycle(time.monotonic(), str(signals["State"]),
                                     status=dict(signals)))
        elif found[1] is FrameKind.SECTORS and self.cycles:
            self.cycles[-1].distances += [v for k, v in signals.items()
                                          if k.startswith("Distance")]

    def on_error(self, exc: Exception) -> None:
        raise exc
