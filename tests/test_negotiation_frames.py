"""Negotiation frames byte by byte, and their agreement with the shipped DBC."""

from __future__ import annotations

import importlib.resources

import cantools
import pytest

from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.plan import Plan
from atris_node.errors import CodeError, ConfigError, FrameDecodeError

NAME = 0x155  # fits the 10 fold bits, so the fold is the NAME itself


def test_claim_frame_bytes():
    frame = nf.encode_claim(NAME, unit_id=3, code_row=5)
    assert frame.can_id == 0x1F000000 | 1 << 21 | 5 << 14 | 0x155 << 4 | 3 == 0x1F215553
    assert frame.data == bytes([0x55, 0x01, 0, 0, 0, 0, 0, 0])


def test_request_and_cannot_claim_frame_bytes():
    assert nf.encode_request(NAME, 0).can_id == 0x1F001550
    leaving = nf.encode_cannot_claim(2**64 - 1, 15, leaving=True)
    assert leaving.can_id == 0x1F400000 | 1 << 14 | nf.name_fold(2**64 - 1) << 4 | 15
    assert leaving.data == b"\xff" * 8


def test_plan_frame_bytes():
    announcement = nf.PlanAnnouncement(Plan(16, 480.0, "sync"), proposal=False, conflict=True,
                                       nonce=0x5A, established=True)
    frame = nf.encode_plan(NAME, 2, announcement)
    assert frame.can_id == 0x1F601552
    assert frame.data == bytes([16, 1, 0x06, 0x5A]) + (480_000).to_bytes(4, "little")
    assert nf.decode_plan(frame.data) == announcement


def test_sync_frame_bytes():
    frame = nf.encode_sync(NAME, 4, 0x11234, Plan(16, 480.0))
    assert frame.can_id == 0x1F801554
    assert frame.data == bytes([0x34, 0x12, 16, 0]) + (33_333).to_bytes(4, "little")
    assert nf.decode_sync(frame.data) == (0x1234, 16, 33_333)


def test_simultaneous_claims_of_one_row_never_share_an_identifier():
    ids = {nf.encode_claim(name, unit_id, 2).can_id
           for name, unit_id in [(0x10, 0), (0x20, 1), (0x10, 1), (0x20, 0)]}
    assert len(ids) == 4


def test_identifiers_round_trip_and_foreign_traffic_is_not_negotiation():
    header = nf.parse_id(nf.encode_claim(0xDEADBEEF, 9, 17).can_id)
    assert header == nf.Header(nf.FrameKind.CLAIM, 17, nf.identity_of(0xDEADBEEF, 9))
    for foreign in (0x500, 0x18EEFF00, 0x0CF00400, 0x1CECFF00, 0x18FEF100, 0x1FE00000):
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


def _database() -> cantools.database.can.Database:
    path = importlib.resources.files("atris_node.bus.can").joinpath("atris.dbc")
    with importlib.resources.as_file(path) as dbc:
        db = cantools.database.load_file(str(dbc))
    assert isinstance(db, cantools.database.can.Database)
    return db


def _frames() -> list[tuple[str, nf.RawFrame, dict[str, float]]]:
    plan = Plan(32, 479.5, "sync")
    announcement = nf.PlanAnnouncement(plan, True, False, 0xC3, True)
    name = 0x0123456789ABCDEF
    return [
        ("Negotiation_Request", nf.encode_request(name, 1), {"Name": name}),
        ("Negotiation_Claim", nf.encode_claim(name, 2, 9), {"Name": name}),
        ("Negotiation_CannotClaim", nf.encode_cannot_claim(name, 3), {"Name": name}),
        ("Negotiation_Plan", nf.encode_plan(name, 4, announcement),
         {"CodeLength": 32, "Mode": 1, "Flag_Proposal": 1, "Flag_Conflict": 0,
          "Flag_Established": 1, "Nonce": 0xC3, "ChipRate": 479.5}),
        ("Negotiation_Sync", nf.encode_sync(name, 5, 77, plan),
         {"Counter": 77, "CodeLength": 32, "CodePeriod": round(32 / 479.5 * 1e6)}),
    ]


@pytest.mark.parametrize(("message_name", "frame", "signals"), _frames())
def test_struct_layouts_and_the_dbc_agree(message_name, frame, signals):
    db = _database()
    message = db.get_message_by_name(message_name)
    kind = nf.parse_id(frame.can_id).kind  # type: ignore[union-attr]
    assert message.frame_id == kind.base_id and message.is_extended_frame
    assert message.length == len(frame.data)
    assert message.encode(signals, strict=True, scaling=True) == frame.data
    decoded = message.decode(frame.data, decode_choices=False)
    assert decoded == pytest.approx(signals)


def test_every_negotiation_kind_is_in_the_dbc_and_decodes_through_the_id_mask():
    codec = FrameCodec()
    names = {name for name, _, _ in _frames()}
    assert names == {m.name for m in _database().messages if m.name.startswith("Negotiation_")}
    assert len(names) == len(nf.FrameKind)
    for name, frame, _ in _frames():
        assert codec.decode(frame.can_id, frame.data, is_extended_id=True).name == name
