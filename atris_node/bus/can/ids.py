"""CAN identifiers of the unit frames: one block of sixteen 11-bit IDs per unit.

Unit ``unit_id`` (0..15) owns ``0x500 + 0x10 * unit_id`` … ``+ 0x0F`` (the ARS408 habit of
SensorID × 0x10), so two units never send the same ID. The offsets inside a block are
the :class:`FrameKind` values; offsets 4..15 are reserved.
"""

from __future__ import annotations

import enum

from atris_node.errors import ConfigError

BASE_ID = 0x500
UNIT_STRIDE = 0x10
MAX_UNIT_ID = 15
#: most sectors a unit can publish (SectorIndex is 4 bits)
MAX_SECTORS = 16
#: sectors carried by one Sectors frame
SECTORS_PER_FRAME = 2


class FrameKind(enum.IntEnum):
    """Offset of a frame inside its unit's ID block; the name is the DBC message suffix."""

    STATUS = 0x0
    QUALITY = 0x1
    NEAREST = 0x2
    SECTORS = 0x3

    @property
    def suffix(self) -> str:
        """Message name suffix in the DBC, e.g. ``Status``."""
        return self.name.capitalize()


def check_unit_id(unit_id: int) -> int:
    """Return ``unit_id`` if it is 0..15, else raise :class:`ConfigError`."""
    if not 0 <= unit_id <= MAX_UNIT_ID:
        raise ConfigError(f"unit_id must be 0..{MAX_UNIT_ID}, got {unit_id}")
    return unit_id


def frame_id(unit_id: int, kind: FrameKind) -> int:
    """11-bit arbitration ID of frame ``kind`` of unit ``unit_id``."""
    return BASE_ID + UNIT_STRIDE * check_unit_id(unit_id) + int(kind)


def message_name(unit_id: int, kind: FrameKind) -> str:
    """DBC message name of frame ``kind`` of unit ``unit_id``, e.g. ``Atris3_Status``."""
    return f"Atris{check_unit_id(unit_id)}_{kind.suffix}"


def unit_of(arbitration_id: int) -> tuple[int, FrameKind] | None:
    """``(unit_id, kind)`` of a unit frame ID, or None for any other ID."""
    offset = arbitration_id - BASE_ID
    if not 0 <= offset < UNIT_STRIDE * (MAX_UNIT_ID + 1):
        return None
    unit_id, kind = divmod(offset, UNIT_STRIDE)
    if kind not in FrameKind._value2member_map_:
        return None
    return unit_id, FrameKind(kind)
