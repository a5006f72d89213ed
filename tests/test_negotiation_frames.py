"""Negotiation frames byte by byte, and their agreement with the shipped DBC: a fleet's
log decodes with plain cantools, and the struct layouts equal cantools' encoding."""

from __future__ import annotations

import collections
import functools
import itertools
import struct

import can
import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atris_node.bus.can.dbc import negotiation_name
from atris_node.bus.can.frames import FrameCodec, dbc_text
from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.fleet import Fleet
from atris_node.bus.negotiation.plan import Plan
from atris_node.errors import CodeError, ConfigError, FrameDecodeError

NAME = 0x155


def test_claim_frame_bytes():
    frame = nf.encode_claim(NAME, unit_id=3, code_row=5)
    assert frame.can_id == 0x1F000000 | 1 << 21 | 5 << 14 | 3 == 0x1F214003
    assert frame.data == bytes([0x55, 0x01, 0, 0, 0, 0, 0, 0])


def test_request_and_cannot_claim_frame_bytes():
    assert nf.encode_request(NAME, 0).can_id == 0x1F000000
    leaving = nf.encode_cannot_claim(2**64 - 1, 15, leaving=True)
    assert leaving.can_id == 0x1F400000 | 1 << 14 | 15
    assert leaving.data == b"\xff" * 8


def test_plan_frame_bytes():
    announcement = nf.PlanAnnouncement(Plan(16, 480.0, "sync"), proposal=False, conflict=True,
                                       nonce=0x5A, established=True)
    frame = nf.encode_plan(NAME, 2, announcement)
    assert frame.can_id == 0x1F600002
    assert frame.data == bytes([16, 1, 0x06, 0x5A]) + (480_000).to_bytes(4, "little")
    assert nf.decode_plan(frame.data) == announcement
    grown = nf.encode_plan(NAME, 2, nf.PlanAnnouncement(Plan(32, 480.0), False, False, 1,
                                                         established=True, grown=True))
    assert grown.data[2] == 0x0C and nf.decode_plan(grown.data).grown


def test_sync_frame_bytes():
    frame = nf.encode_sync(NAME, 4, 0x11234, Plan(16, 480.0))
    assert frame.can_id == 0x1F800004
    assert frame.data == bytes([0x34, 0x12, 16, 0]) + (33_333).to_bytes(4, "little")
    assert nf.decode_sync(frame.data) == (0x1234, 16, 33_333)


def test_simultaneous_claims_of_one_row_never_share_an_identifier():
    """Units (unique unit_ids) claiming one row at once send different identifiers; the
    same unit_id with another NAME is the same identity (a duplicate, seen as a clash)."""
    ids = {nf.encode_claim(0x10 + unit_id, unit_id, 2).can_id for unit_id in range(16)}
    assert len(ids) == 16
    assert nf.identity_of(0x10, 3) == nf.identity_of(0x20, 3)


def test_identifiers_round_trip_and_foreign_traffic_is_not_negotiation():
    header = nf.parse_id(nf.encode_claim(0xDEADBEEF, 9, 17).can_id)
    assert header == nf.Header(nf.FrameKind.CLAIM, 17, nf.identity_of(0xDEADBEEF, 9))
    for foreign in (0x500, 0x18EEFF00, 0x0CF00400, 0x1CECFF00, 0x18FEF100, 0x1FE00000,
                    0x1F214013):  # the last: a CLAIM with a reserved bit set
        assert nf.parse_id(foreign) is None  # unit frames, J1939 address claim, EEC1, TP.CM


def test_bad_values_are_refused_with_what_is_accepted():
    with pytest.raises(CodeError, match=r"2\.\.127"):
        nf.encode_claim(NAME, 0, 1)
    with pytest.raises(ConfigError, match=r"0\.\.15"):
        nf.encode_request(NAME, 16)
    with pytest.raises(ConfigError, match="64-bit"):
        nf.encode_request(2**64, 0)
    with pytest.raises(FrameDecodeError, match="8 bytes"):
        nf.decode_name(b"\x01")
    with pytest.raises(FrameDecodeError, match="not a valid plan"):
        nf.decode_plan(bytes([12, 0, 0, 0]) + (480_000).to_bytes(4, "little"))
    with pytest.raises(FrameDecodeError, match="flags"):
        nf.decode_plan(bytes([16, 0, 0x80, 0]) + (480_000).to_bytes(4, "little"))


@functools.cache
def _database() -> cantools.database.can.Database:
    """The shipped DBC as plain cantools reads it (once: 2160 messages)."""
    db = cantools.database.load_string(dbc_text(), database_format="dbc")
    assert isinstance(db, cantools.database.can.Database)
    return db


def _fleet_log() -> list[can.Message]:
    """Every frame of two simulated fleets on virtual buses: eight async units for seven
    codes (one waits: CANNOT_CLAIM), one of them stopping (leaving), and three sync units
    (SYNC)."""
    log: list[can.Message] = []
    names = [0x7A, 0x13, 0x5C, 0x21, 0x9E, 0x44, 0x38, 0x66]
    for mode, count, channel in (("async", 8, "dbc-log-async"), ("sync", 3, "dbc-log-sync")):
        fleet = Fleet(channel, Plan(128 if mode == "async" else 16, 480.0, mode),
                      names[:count])
        try:
            fleet.start_all(spread_s=0.01)
            if mode == "sync":
                fleet.run_cycles(0.0)
            fleet.stop(1, 2.5)
            fleet.run_until(3.5)
            log += [msg for bus in fleet.buses for _, msg in bus.sent]
        finally:
            fleet.close()
    return log


def test_feature_a_fleet_log_decodes_with_plain_cantools():
    """Every frame a simulated fleet sends has its own message in the shipped DBC: plain
    ``db.decode_message(frame_id, data)`` decodes all of them, none unknown, and the
    message is the one of the frame's unit, kind and field.

    Checked to fail: the same fleet run with the previous layout and DBC (one message per
    kind, matched through a private IdMask attribute) sent 215 frames on 30 identifiers,
    and plain cantools knew none of them."""
    db, log = _database(), _fleet_log()
    unknown, kinds = [], collections.Counter()
    for msg in log:
        try:
            db.decode_message(msg.arbitration_id, bytes(msg.data))
        except KeyError:
            unknown.append(hex(msg.arbitration_id))
            continue
        header = nf.parse_id(msg.arbitration_id)
        assert header is not None
        kinds[header.kind] += 1
        name = negotiation_name(header.identity.unit_id, header.kind, header.field)
        assert db.get_message_by_frame_id(msg.arbitration_id).name == name
    assert unknown == [] and len(log) > 100
    assert set(kinds) == set(nf.FrameKind)
    leaving = nf.encode_cannot_claim(0x13, 1, leaving=True).can_id  # unit 1 stopped
    assert leaving in {m.arbitration_id for m in log}


def test_feature_every_identifier_a_unit_can_send_is_one_message():
    """The DBC holds one message per unit_id, kind and field value the units send
    (131 per unit), and the codec decodes each by its exact identifier.

    Checked to fail: with row 127 left out of frames.FIELDS."""
    db, codec = _database(), FrameCodec()
    expected = {nf.make_id(kind, nf.Identity(unit_id), field)
                for unit_id in range(16) for kind, fields in nf.FIELDS.items()
                for field in fields}
    listed = {m.frame_id for m in db.messages if m.is_extended_frame}
    assert listed == expected and len(expected) == 16 * 131
    frame = nf.encode_claim(0x0123456789ABCDEF, 12, 127)
    decoded = codec.decode(frame.can_id, frame.data, is_extended_id=True)
    assert decoded.name == "Negotiation12_Claim127"
    assert decoded.signals == {"Name": 0x0123456789ABCDEF}


#: raw field order of each payload struct -> the DBC signals (None: a reserved byte)
STRUCT_SIGNALS = {
    nf.FrameKind.REQUEST: (nf.NAME_STRUCT, ("Name",)),
    nf.FrameKind.CLAIM: (nf.NAME_STRUCT, ("Name",)),
    nf.FrameKind.CANNOT_CLAIM: (nf.NAME_STRUCT, ("Name",)),
    nf.FrameKind.PLAN: (nf.PLAN_STRUCT, ("CodeLength", "Mode", None, "Nonce", "ChipRate")),
    nf.FrameKind.SYNC: (nf.SYNC_STRUCT, ("Counter", "CodeLength", None, "CodePeriod")),
}
PLAN_FLAGS = (("Flag_Proposal", nf.PLAN_FLAG_PROPOSAL), ("Flag_Conflict", nf.PLAN_FLAG_CONFLICT),
              ("Flag_Established", nf.PLAN_FLAG_ESTABLISHED), ("Flag_Grown", nf.PLAN_FLAG_GROWN))


def _raw_signals(kind: nf.FrameKind, fields: tuple[int, ...]) -> dict[str, int]:
    """The DBC's raw signal values for the struct ``fields`` of a ``kind`` payload."""
    _, names = STRUCT_SIGNALS[kind]
    raw = {name: value for name, value in zip(names, fields, strict=True) if name}
    if kind is nf.FrameKind.PLAN:
        raw.update({name: int(bool(fields[2] & bit)) for name, bit in PLAN_FLAGS})
    return raw


def _extremes(kind: nf.FrameKind) -> list[tuple[int, ...]]:
    """Every combination of each field's minimum, a value with distinct bytes (0x0201...,
    so a byte-order error shows) and its maximum; the PLAN flags byte takes none, one and
    all flags, SYNC's reserved byte 0."""
    layout, names = STRUCT_SIGNALS[kind]
    sizes = [struct.calcsize("<" + code) for code in layout.format[1:]]
    reserved = (0, nf.PLAN_FLAG_CONFLICT, nf.PLAN_FLAGS) if kind is nf.FrameKind.PLAN else (0,)
    return list(itertools.product(*[
        (0, int.from_bytes(bytes(range(1, size + 1)), "little"), (1 << 8 * size) - 1)
        if name else reserved for name, size in zip(names, sizes, strict=True)]))


@pytest.mark.parametrize("kind", list(nf.FrameKind))
def test_feature_struct_codec_equals_cantools_at_every_extreme(kind):
    """For every payload field at its minimum, middle and maximum raw value (including
    values no plan can have, such as mode 255 or N 0), the struct bytes equal cantools'
    raw encoding with the DBC message, and cantools decodes them to the same fields.

    Checked to fail: with PLAN's Nonce signed in the frame table (DBC regenerated), and
    with SYNC_STRUCT big-endian (which the former middle value 0x5555... hid)."""
    layout, _ = STRUCT_SIGNALS[kind]
    can_id = nf.make_id(kind, nf.Identity(7), nf.FIELDS[kind][0])
    message = _database().get_message_by_frame_id(can_id)
    for fields in _extremes(kind):
        data = layout.pack(*fields)
        raw = _raw_signals(kind, fields)
        assert message.encode(raw, scaling=False, strict=False) == data
        assert message.decode(data, scaling=False, decode_choices=False) == raw


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=8, max_size=8))
def test_feature_plan_decoder_accepts_only_what_the_dbc_ranges_allow(data):
    """Any 8 bytes: cantools and the struct decoder read the same PLAN fields, and a
    payload ``decode_plan`` accepts has every signal inside its DBC range.

    Checked to fail: without decode_plan's mode check (mode 2..255 then raised
    IndexError, not FrameDecodeError)."""
    message = _database().get_message_by_frame_id(nf.make_id(nf.FrameKind.PLAN, nf.Identity(0)))
    raw = message.decode(data, scaling=False, decode_choices=False)
    assert raw == _raw_signals(nf.FrameKind.PLAN, nf.PLAN_STRUCT.unpack(data))
    try:
        nf.decode_plan(data)
    except FrameDecodeError:
        return
    physical = message.decode(data, decode_choices=False)
    for signal in message.signals:
        assert signal.minimum <= physical[signal.name] <= signal.maximum, signal.name
