"""Byte layouts and 29-bit identifiers of the code-negotiation frames.

Identifier (29 bits, extended frame)::

    bits 28..24  0b11111: J1939 priority 7 with EDP = DP = 1, the data page J1939 leaves
                 to ISO 15765-3, so no J1939 parameter group is mistaken for a claim
    bits 23..21  kind: REQUEST 0, CLAIM 1, CANNOT_CLAIM 2, PLAN 3, SYNC 4
    bits 20..14  field: the claimed 1-based Walsh row in CLAIM; 1 in a CANNOT_CLAIM sent
                 by a unit that stops (leaving); 0 otherwise
    bits 13..4   0 (reserved; an identifier with any of them set is no negotiation frame)
    bits  3..0   unit_id of the sender: its identity

unit_ids are unique per bus by configuration (the unit frames already require it), so two
units claiming at the same instant never send the same identifier (a real bus would turn
that into a bit error), and a second unit with our unit_id shows as a foreign frame with
our identity. With four identity bits every identifier a unit can send is one message of
the DBC (:data:`FIELDS`: 131 per unit, 2096 in all), so stock tools decode negotiation
frames by their identifier alone. Payloads are little-endian, as J1939 puts the NAME on
the wire.

Example:
    >>> frame = encode_claim(0x1122334455667788, unit_id=3, code_row=5)
    >>> hex(frame.can_id), frame.data.hex()
    ('0x1f214003', '8877665544332211')
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

from atris_node.bus.negotiation.plan import MODES, Plan
from atris_node.errors import CodeError, ConfigError, FrameDecodeError

PREFIX_BITS = 0x1F000000
PREFIX_MASK = 0x1F000000
KIND_SHIFT = 21
FIELD_SHIFT = 14
KIND_MASK = 0x1FE00000
FIELD_MASK = 0x001FC000
RESERVED_MASK = 0x00003FF0
IDENTITY_MASK = 0x0000000F
MAX_UNIT_ID = 15
MAX_FIELD = 0x7F
MAX_NAME = 2**64 - 1

#: REQUEST, CLAIM, CANNOT_CLAIM: the sender's 64-bit NAME
NAME_STRUCT = struct.Struct("<Q")
#: PLAN: code_length, mode (0 async, 1 sync), flags, nonce, chip rate in millihertz
PLAN_STRUCT = struct.Struct("<BBBBI")
#: SYNC: cycle counter, code_length, reserved (0), code period in microseconds
SYNC_STRUCT = struct.Struct("<HBBI")

#: field value of a CANNOT_CLAIM sent by a unit that stops
LEAVING = 1
PLAN_FLAG_PROPOSAL = 0x01  # a request for this plan, addressed to the lowest NAME
PLAN_FLAG_CONFLICT = 0x02  # the sender cannot adopt the winning plan
PLAN_FLAG_ESTABLISHED = 0x04  # the sender owns a code under this plan (a running fleet)
PLAN_FLAG_GROWN = 0x08  # the leader grew N to fit the units: shrink it when they are gone
PLAN_FLAGS = PLAN_FLAG_PROPOSAL | PLAN_FLAG_CONFLICT | PLAN_FLAG_ESTABLISHED | PLAN_FLAG_GROWN


class FrameKind(enum.IntEnum):
    """Kind bits of a negotiation identifier; DBC messages ``Negotiation<unit>_<Kind>...``."""

    REQUEST = 0
    CLAIM = 1
    CANNOT_CLAIM = 2
    PLAN = 3
    SYNC = 4

    @property
    def base_id(self) -> int:
        """Identifier with field and identity bits zero (the DBC message's ID)."""
        return PREFIX_BITS | (self.value << KIND_SHIFT)


@dataclass(frozen=True)
class RawFrame:
    """A frame as it goes on the bus: 29-bit ``can_id`` and up to 8 ``data`` bytes."""

    can_id: int
    data: bytes


#: the field values each kind is sent with: one identifier per unit and value
FIELDS: dict[FrameKind, tuple[int, ...]] = {
    FrameKind.REQUEST: (0,),
    FrameKind.CLAIM: tuple(range(2, MAX_FIELD + 1)),
    FrameKind.CANNOT_CLAIM: (0, LEAVING),
    FrameKind.PLAN: (0,),
    FrameKind.SYNC: (0,),
}


@dataclass(frozen=True)
class Identity:
    """Sender identity from the identifier's low 4 bits: its unit_id."""

    unit_id: int

    @property
    def bits(self) -> int:
        """The identity bits of the identifier."""
        return self.unit_id


@dataclass(frozen=True)
class PlanAnnouncement:
    """Decoded PLAN payload."""

    plan: Plan
    proposal: bool
    conflict: bool
    nonce: int
    established: bool = False
    grown: bool = False


@dataclass(frozen=True)
class Header:
    """Decoded identifier: kind, field (the claimed row in CLAIM) and sender identity."""

    kind: FrameKind
    field: int
    identity: Identity


def identity_of(name: int, unit_id: int) -> Identity:
    """The identity a unit puts in its identifiers; checks NAME and unit_id ranges."""
    if not 0 <= name <= MAX_NAME:
        raise ConfigError(f"NAME must be a 64-bit unsigned integer, got {name}")
    if not 0 <= unit_id <= MAX_UNIT_ID:
        raise ConfigError(f"unit_id must be 0..{MAX_UNIT_ID}, got {unit_id}")
    return Identity(unit_id)


def make_id(kind: FrameKind, identity: Identity, field: int = 0) -> int:
    """29-bit identifier of a negotiation frame."""
    if not 0 <= field <= MAX_FIELD:
        raise CodeError(f"identifier field must be 0..{MAX_FIELD}, got {field}")
    return kind.base_id | (field << FIELD_SHIFT) | identity.bits


def parse_id(can_id: int) -> Header | None:
    """Split a 29-bit identifier; None when it is not a negotiation frame."""
    if can_id & ~0x1FFFFFFF or can_id & PREFIX_MASK != PREFIX_BITS or can_id & RESERVED_MASK:
        return None
    kind_value = (can_id >> KIND_SHIFT) & 0x7
    if kind_value not in FrameKind._value2member_map_:
        return None
    identity = Identity(can_id & IDENTITY_MASK)
    return Header(FrameKind(kind_value), (can_id & FIELD_MASK) >> FIELD_SHIFT, identity)


def _name_frame(kind: FrameKind, name: int, unit_id: int, field: int = 0) -> RawFrame:
    identity = identity_of(name, unit_id)
    return RawFrame(make_id(kind, identity, field), NAME_STRUCT.pack(name))


def encode_request(name: int, unit_id: int) -> RawFrame:
    """Request for claims: everyone re-announces at once."""
    return _name_frame(FrameKind.REQUEST, name, unit_id)


def encode_claim(name: int, unit_id: int, code_row: int) -> RawFrame:
    """Claim of the 1-based Walsh row ``code_row`` (1 < row <= 127)."""
    if not 2 <= code_row <= MAX_FIELD:
        raise CodeError(f"claimed code row must be 2..{MAX_FIELD}, got {code_row}")
    return _name_frame(FrameKind.CLAIM, name, unit_id, code_row)


def encode_cannot_claim(name: int, unit_id: int, leaving: bool = False) -> RawFrame:
    """Cannot-claim: the sender has no code and keeps its laser off.

    With ``leaving`` (field 1) the sender also goes off the bus (stop): forget it at once.
    """
    return _name_frame(FrameKind.CANNOT_CLAIM, name, unit_id, LEAVING if leaving else 0)


def encode_plan(name: int, unit_id: int, announcement: PlanAnnouncement) -> RawFrame:
    """PLAN: the plan the sender uses (or, with the proposal flag, asks for)."""
    plan = announcement.plan
    flags = ((PLAN_FLAG_PROPOSAL if announcement.proposal else 0)
             | (PLAN_FLAG_CONFLICT if announcement.conflict else 0)
             | (PLAN_FLAG_ESTABLISHED if announcement.established else 0)
             | (PLAN_FLAG_GROWN if announcement.grown else 0))
    data = PLAN_STRUCT.pack(plan.code_length, MODES.index(plan.mode), flags,
                            announcement.nonce & 0xFF, plan.chip_rate_mhz)
    return RawFrame(make_id(FrameKind.PLAN, identity_of(name, unit_id)), data)


def encode_sync(name: int, unit_id: int, counter: int, plan: Plan) -> RawFrame:
    """SYNC, sent by the lowest NAME at the start of each of its code periods."""
    period_us = min(round(plan.cycle_s * 1e6), 2**32 - 1)
    data = SYNC_STRUCT.pack(counter & 0xFFFF, plan.code_length, 0, period_us)
    return RawFrame(make_id(FrameKind.SYNC, identity_of(name, unit_id)), data)


def _unpack(layout: struct.Struct, data: bytes, what: str) -> tuple[int, ...]:
    if len(data) != layout.size:
        raise FrameDecodeError(f"{what} payload must be {layout.size} bytes, got {len(data)}")
    return layout.unpack(data)


def decode_name(data: bytes) -> int:
    """NAME from a REQUEST, CLAIM or CANNOT_CLAIM payload."""
    return int(_unpack(NAME_STRUCT, data, "NAME")[0])


def decode_plan(data: bytes) -> PlanAnnouncement:
    """PLAN payload; raises :class:`FrameDecodeError` for values no plan can have."""
    code_length, mode, flags, nonce, rate_mhz = _unpack(PLAN_STRUCT, data, "PLAN")
    if mode >= len(MODES) or flags & ~PLAN_FLAGS:
        raise FrameDecodeError(f"PLAN mode {mode} or flags {flags:#x} not defined")
    try:
        plan = Plan(code_length, rate_mhz / 1000.0, MODES[mode])
    except (CodeError, ConfigError) as exc:
        raise FrameDecodeError(f"PLAN payload is not a valid plan: {exc}") from exc
    return PlanAnnouncement(plan, bool(flags & PLAN_FLAG_PROPOSAL),
                            bool(flags & PLAN_FLAG_CONFLICT), nonce,
                            bool(flags & PLAN_FLAG_ESTABLISHED), bool(flags & PLAN_FLAG_GROWN))


def decode_sync(data: bytes) -> tuple[int, int, int]:
    """SYNC payload: (counter, code_length, period_us)."""
    counter, code_length, _, period_us = _unpack(SYNC_STRUCT, data, "SYNC")
    return counter, code_length, period_us
