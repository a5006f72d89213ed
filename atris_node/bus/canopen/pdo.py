"""Checks of SDO writes to the TPDO parameters and the COB-ID objects (CiA 301).

Communication parameters 0x1800-0x1803: sub 1 COB-ID (11-bit, bit 31 = not valid, bit 30
= no RTR, which must stay set; the CAN-ID changes only while not valid), sub 2
transmission type (0 acyclic on SYNC after new values, 1..240 every n-th SYNC, 254/255
event-driven; the RTR-only types 252/253 and the reserved 241..251 are refused), sub 3
inhibit time (changes only while not valid), sub 5 event timer. Mapping parameters
0x1A00-0x1A03 follow the CiA 301 procedure: the TPDO made not valid, sub 0 set to 0, the
entries written, sub 0 set to their number; each entry must name an existing, mappable
object with its own length in bits, and all of them fit 64 bits.
"""

from __future__ import annotations

import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError

from atris_node.bus.canopen.objects import (
    ABORT_NO_OBJECT,
    ABORT_NOT_MAPPABLE,
    ABORT_PDO_LENGTH,
    ABORT_RANGE,
    ABORT_STATE,
)

NOT_VALID, FRAME_29_BIT, SYNC_PRODUCER = 1 << 31, 1 << 29, 1 << 30
RTR_NOT_ALLOWED = 1 << 30  # in a PDO COB-ID
CAN_ID_MASK = 0x7FF
MAX_ENTRIES, MAX_PDO_BITS = 8, 64
#: CAN-IDs CiA 301 reserves for NMT, SYNC/EMCY of others, SDO, LSS and NMT error control
RESTRICTED_IDS = (range(0x000, 0x080), range(0x101, 0x181), range(0x581, 0x600),
                  range(0x601, 0x680), range(0x6E0, 0x700), range(0x701, 0x800))
TRANSMISSION_TYPES = frozenset({0, *range(1, 241), 254, 255})


def raw(node: canopen.LocalNode, index: int, subindex: int) -> int:
    """The value stored at ``index:subindex`` of ``node`` as an integer."""
    od = node.object_dictionary[index]
    variable = od if isinstance(od, ODVariable) else od[subindex]
    return int(variable.decode_raw(node.get_data(index, subindex)))


def check_can_id(cob_id: int) -> None:
    """Raise SdoAbortedError 0x06090030 unless ``cob_id`` is an 11-bit COB-ID outside the
    CAN-IDs CiA 301 restricts."""
    can_id = cob_id & CAN_ID_MASK
    if cob_id & FRAME_29_BIT or cob_id & 0x1FFFFFFF & ~CAN_ID_MASK:
        raise SdoAbortedError(ABORT_RANGE)
    if any(can_id in ids for ids in RESTRICTED_IDS):
        raise SdoAbortedError(ABORT_RANGE)


def check_cob_id(old: int, new: int, valid_bit: int) -> None:
    """:func:`check_can_id`, and the CAN-ID of ``new`` differs from ``old`` only if one
    of them has ``valid_bit`` set (the object does not exist while being moved)."""
    check_can_id(new)
    moved = (old & 0x1FFFFFFF) != (new & 0x1FFFFFFF)
    if moved and not (old & valid_bit or new & valid_bit):
        raise SdoAbortedError(ABORT_RANGE)


def check_sync_cob_id(new: int) -> None:
    """0x1005: the device consumes SYNC (on any allowed CAN-ID, changed at any time) and
    never produces it (bit 30 refused)."""
    if new & SYNC_PRODUCER:
        raise SdoAbortedError(ABORT_RANGE)
    check_can_id(new & ~NOT_VALID)


def check_comm_write(node: canopen.LocalNode, index: int, subindex: int, value: int) -> None:
    """A write of ``value`` to TPDO communication parameter ``index:subindex``."""
    cob_id = raw(node, index, 1)
    if subindex == 1:
        check_cob_id(cob_id, value, NOT_VALID)
        if not value & RTR_NOT_ALLOWED:
            raise SdoAbortedError(ABORT_RANGE)  # no remote requests for TPDOs
    if subindex == 2 and value not in TRANSMISSION_TYPES:
        raise SdoAbortedError(ABORT_RANGE)
    if subindex == 3 and not cob_id & NOT_VALID and value != raw(node, index, 3):
        raise SdoAbortedError(ABORT_RANGE)  # the inhibit time changes only while not valid


def check_map_write(node: canopen.LocalNode, index: int, subindex: int, value: int) -> None:
    """A write of ``value`` to TPDO mapping parameter ``index:subindex``."""
    if not raw(node, index - 0x200, 1) & NOT_VALID:
        raise SdoAbortedError(ABORT_STATE)  # the TPDO exists: make it not valid first
    if subindex == 0:
        check_mapping(node, [raw(node, index, sub) for sub in range(1, value + 1)]
                      if value <= MAX_ENTRIES else [0] * value)
    elif raw(node, index, 0):
        raise SdoAbortedError(ABORT_STATE)  # the mapping is in force: set sub 0 to 0 first
    elif value:
        mapped_bits(node, value)


def check_mapping(node: canopen.LocalNode, entries: list[int]) -> None:
    """Raise SdoAbortedError 0x06040042 when ``entries`` exceed 8 objects or 64 bits, or
    as :func:`mapped_bits` for an entry that maps nothing valid."""
    if len(entries) > MAX_ENTRIES:
        raise SdoAbortedError(ABORT_PDO_LENGTH)
    if sum(mapped_bits(node, entry) for entry in entries) > MAX_PDO_BITS:
        raise SdoAbortedError(ABORT_PDO_LENGTH)


def mapped_bits(node: canopen.LocalNode, entry: int) -> int:
    """The length of mapping ``entry`` (index << 16 | subindex << 8 | bits); SdoAbortedError
    0x06020000 when the object does not exist, 0x06040041 when it cannot be mapped or the
    length is not its own (zero included)."""
    index, subindex, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
    od = node.object_dictionary.get(index)
    if od is not None and not isinstance(od, ODVariable):
        od = od.subindices.get(subindex)
    if od is None:
        raise SdoAbortedError(ABORT_NO_OBJECT)
    if not od.pdo_mappable or bits != len(od):
        raise SdoAbortedError(ABORT_NOT_MAPPABLE)
    return bits
