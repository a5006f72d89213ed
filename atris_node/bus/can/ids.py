"""CAN identifiers of the unit frames: one block of four 11-bit IDs per unit.

Unit ``unit_id`` (0..15) owns ``base_id + 4 * unit_id`` … ``+ 3``, one ID per
:class:`FrameKind`, so two units never send the same ID and the sixteen blocks take 64
IDs. The default base 0x680 puts them at 0x680..0x6BF, where the CANopen predefined
connection set (CiA 301) has nothing: above the SDO requests (0x601..0x67F), below the
heartbeats (0x701..0x77F) and below 0x6E0..0x6FF, which CiA 301 keeps out of use. A
different base is a node setting (``bus.base_id``), checked by :func:`check_base_id`.
"""

from __future__ import annotations

import enum

from atris_node.errors import ConfigError

DEFAULT_BASE_ID = 0x680
UNIT_STRIDE = 4
MAX_UNIT_ID = 15
#: IDs the sixteen blocks take from the base on
ID_SPAN = UNIT_STRIDE * (MAX_UNIT_ID + 1)
MAX_STANDARD_ID = 0x7FF
#: most sectors a unit can publish (SectorIndex is 4 bits)
MAX_SECTORS = 16
#: sectors carried by one Sectors frame
SECTORS_PER_FRAME = 2
#: the CANopen predefined connection set (CiA 301): (first ID, last ID, service)
CANOPEN_PREDEFINED = (
    (0x000, 0x000, "NMT"),
    (0x080, 0x080, "SYNC"),
    (0x081, 0x0FF, "EMCY"),
    (0x100, 0x100, "TIME"),
    (0x181, 0x1FF, "TPDO1"),
    (0x201, 0x27F, "RPDO1"),
    (0x281, 0x2FF, "TPDO2"),
    (0x301, 0x37F, "RPDO2"),
    (0x381, 0x3FF, "TPDO3"),
    (0x401, 0x47F, "RPDO3"),
    (0x481, 0x4FF, "TPDO4"),
    (0x501, 0x57F, "RPDO4"),
    (0x581, 0x5FF, "SDO responses"),
    (0x601, 0x67F, "SDO requests"),
    (0x701, 0x77F, "heartbeat"),
    (0x7E4, 0x7E5, "LSS"),
)


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


def canopen_overlap(base_id: int) -> str | None:
    """Services of the CANopen predefined connection set whose IDs the blocks from
    ``base_id`` would use, e.g. ``"RPDO4 0x501-0x57F"``; None when there are none."""
    last = base_id + ID_SPAN - 1
    hits = [f"{name} 0x{lo:03X}-0x{hi:03X}" for lo, hi, name in CANOPEN_PREDEFINED
            if lo <= last and base_id <= hi]
    return ", ".join(hits) or None


def check_base_id(base_id: int, allow_canopen: bool = False) -> int:
    """Return ``base_id`` if the sixteen blocks from it fit in 11 bits and, unless
    ``allow_canopen`` (a bus without CANopen devices), stay out of the CANopen predefined
    connection set; else raise :class:`ConfigError` saying which IDs clash."""
    if not 0 <= base_id <= MAX_STANDARD_ID + 1 - ID_SPAN:
        raise ConfigError(f"CAN base ID (bus.base_id) must be 0x000..0x"
                          f"{MAX_STANDARD_ID + 1 - ID_SPAN:03X} (16 units x {UNIT_STRIDE} IDs "
                          f"in 11 bits), got 0x{base_id:X}")
    overlap = canopen_overlap(base_id)
    if overlap is not None and not allow_canopen:
        raise ConfigError(
            f"CAN base ID 0x{base_id:03X} (bus.base_id) puts unit frames at "
            f"0x{base_id:03X}-0x{base_id + ID_SPAN - 1:03X}, inside the CANopen predefined "
            f"connection set ({overlap}); use e.g. 0x{DEFAULT_BASE_ID:03X}, or set "
            "bus.allow_canopen_ids on a bus without CANopen devices")
    return base_id


def frame_id(unit_id: int, kind: FrameKind, base_id: int = DEFAULT_BASE_ID) -> int:
    """11-bit arbitration ID of frame ``kind`` of unit ``unit_id``."""
    return base_id + UNIT_STRIDE * check_unit_id(unit_id) + int(kind)


def message_name(unit_id: int, kind: FrameKind) -> str:
    """DBC message name of frame ``kind`` of unit ``unit_id``, e.g. ``Atris3_Status``."""
    return f"Atris{check_unit_id(unit_id)}_{kind.suffix}"


def unit_of(arbitration_id: int,
            base_id: int = DEFAULT_BASE_ID) -> tuple[int, FrameKind] | None:
    """``(unit_id, kind)`` of a unit frame ID, or None for any other ID."""
    offset = arbitration_id - base_id
    if not 0 <= offset < ID_SPAN:
        return None
    unit_id, kind = divmod(offset, UNIT_STRIDE)
    return unit_id, FrameKind(kind)
