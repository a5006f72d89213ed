"""Byte-exact unit frames, a cantools round trip with the shipped DBC, decoder fuzzing."""

from __future__ import annotations

import math
import subprocess
import sys

import cantools
import pytest
from hypothesis import given
from hypothesis import strategies as st

from atris_node.bus.can import e2e, payloads
from atris_node.bus.can.dbc import unit_cycle_ms
from atris_node.bus.can.frames import FrameCodec, dbc_text, e2e_data_id, load_database
from atris_node.bus.can.ids import FrameKind, frame_id, message_name, unit_of
from atris_node.errors import ConfigError, FrameDecodeError
from atris_node.types import (
    FaultBits,
    Measurement,
    SectorDistance,
    SectorState,
    UnitState,
    UnitStatus,
)

STATUS = UnitStatus(UnitState.RUNNING, code_row=3, code_length=16, chip_rate_hz=480.0,
                    measurement_counter=0x1234, ambient_level=0.25, saturated_fraction=0.01,
                    foreign_code_energy=0.5, dropped_sub_frames=3)


def _protected(data_id: int, body: str) -> bytes:
    """Expected frame: bytes 1..7 given in hex, byte 0 the Profile 1 CRC."""
    data = bytes.fromhex("00" + body)
    return bytes([e2e.profile1_crc(data_id, data)]) + data[1:]


def test_ids_blocks_do_not_overlap() -> None:
    ids = {frame_id(u, k) for u in range(16) for k in FrameKind}
    assert len(ids) == 64 and min(ids) == 0x680 and max(ids) == 0x6BF
    assert unit_of(0x68E) == (3, FrameKind.NEAREST)
    assert unit_of(0x67F) is None and unit_of(0x6C0) is None
    with pytest.raises(ConfigError, match=r"0\.\.15"):
        frame_id(16, FrameKind.STATUS)


def test_dbc_lists_every_unit_with_the_same_layout() -> None:
    db = load_database()
    for unit in range(16):
        for kind in FrameKind:
            message = db.get_message_by_name(message_name(unit, kind))
            reference = db.get_message_by_name(message_name(0, kind))
            assert message.frame_id == frame_id(unit, kind)
            assert e2e_data_id(message) == message.frame_id
            assert message.cycle_time == unit_cycle_ms(kind) and message.length == 8
            layout = [(s.name, s.start, s.length, s.scale, s.is_signed) for s in message.signals]
            assert layout == [(s.name, s.start, s.length, s.scale, s.is_signed)
                              for s in reference.signals]
    assert "Negotiation frames" in dbc_text()


def test_status_frame_bytes() -> None:
    faults = FaultBits.CAMERA_LOST | FaultBits.BUS_ERROR
    signals = payloads.status_signals(STATUS, faults, 0.05)
    msg = FrameCodec().encode("Atris2_Status", signals, counter=4, scaling=False)
    # State 2 | counter 4, faults 0x05, row 3, N 16, 480.0 Hz = 4800 = 0x12C0, age 5
    assert msg.arbitration_id == 0x688 and not msg.is_extended_id
    assert bytes(msg.data) == _protected(0x688, "24 05 03 10 C0 12 05")


def test_quality_frame_bytes() -> None:
    signals = payloads.quality_signals(STATUS, 8)
    msg = FrameCodec().encode("Atris2_Quality", signals, counter=0, scaling=False)
    # SectorCount-1 = 7, counter 0x1234, ambient 25 % = 50, 1 % = 2, 50 %, 3
    assert bytes(msg.data) == _protected(0x689, "70 34 12 32 02 32 03")


def test_sectors_frame_bytes() -> None:
    sectors = (SectorDistance(0, 0.0, SectorState.VALID, 1.234, 0.8),
               SectorDistance(1, 0.0, SectorState.NO_RETURN, 0.0, 0.5),
               SectorDistance(2, 0.0, SectorState.INVALID))
    frames = payloads.sectors_signals(sectors, 3, usable=True)
    codec = FrameCodec()
    data = [bytes(codec.encode("Atris0_Sectors", f, i, scaling=False).data)
            for i, f in enumerate(frames)]
    assert data[0] == _protected(0x683, "00 D2 04 A0 FE FF 64")
    assert data[1] == _protected(0x683, "21 FF FF 00 FD FF 00")


def test_nearest_frame_bytes() -> None:
    nearest = SectorDistance(4, math.radians(-12.5), SectorState.VALID, 2.5, 0.9)
    measurement = Measurement(1, (nearest,), 0.0, 0, nearest=nearest,
                              closing_speed_mps=2.0, time_to_collision_s=None)
    signals = payloads.nearest_signals(measurement, usable=True)
    msg = FrameCodec().encode("Atris1_Nearest", signals, counter=14, scaling=False)
    # valid, 2500 mm, -1250 (0xFB1E), 10 = 2.0 m/s, TTC not available
    assert bytes(msg.data) == _protected(0x686, "1E C4 09 1E FB 0A FF")


def test_unusable_data_is_invalid_never_a_distance() -> None:
    sector = SectorDistance(0, 0.0, SectorState.VALID, 1.0, 1.0)
    frames = payloads.sectors_signals((sector,), 2, usable=False)
    assert frames[0]["Distance0"] == payloads.DISTANCE_INVALID
    nan = SectorDistance(0, 0.0, SectorState.VALID, float("nan"), float("nan"))
    assert payloads.distance_raw(nan) == payloads.DISTANCE_INVALID
    assert payloads.confidence_raw(nan) == 0
    assert payloads.data_age_raw(None) == 255 and payloads.data_age_raw(99.0) == 254


def test_round_trip_through_cantools_with_the_shipped_dbc() -> None:
    """A plain cantools user decodes our frames from the DBC alone."""
    db = cantools.database.load_string(dbc_text(), database_format="dbc")
    status = payloads.status_signals(STATUS, FaultBits.FOREIGN_CODE, 0.12)
    msg = FrameCodec().encode("Atris9_Status", status, counter=9, scaling=False)
    decoded = db.decode_message(msg.arbitration_id, bytes(msg.data))
    assert decoded["State"] == "RUNNING" and decoded["Counter"] == 9
    assert decoded["ChipRate"] == pytest.approx(480.0) and decoded["DataAge"] == 0.12
    assert decoded["Fault_ForeignCode"] == 1 and decoded["Fault_CameraLost"] == 0
    data_id = db.get_message_by_name("Atris9_Status").dbc.attributes["E2EDataID"].value
    assert decoded["CRC"] == e2e.profile1_crc(data_id, bytes(msg.data))


def test_physical_round_trip_through_codec() -> None:
    codec = FrameCodec()
    values = {"Valid": 1, "Distance": 12.345, "Bearing": -33.5, "ClosingSpeed": -1.0,
              "TimeToCollision": "not_available"}
    decoded = codec.decode_message(codec.encode("Atris15_Nearest", values, counter=3))
    assert decoded.crc_ok and decoded.name == "Atris15_Nearest"
    assert decoded.signals | {"CRC": 0} == values | {"CRC": 0, "Counter": 3}


def test_strict_encoding_rejects_out_of_range() -> None:
    with pytest.raises(FrameDecodeError, match="Atris0_Nearest"):
        FrameCodec().encode("Atris0_Nearest", {"Valid": 1, "Distance": 70.0, "Bearing": 0,
                                               "ClosingSpeed": 0, "TimeToCollision": 0})
    with pytest.raises(FrameDecodeError, match="no message"):
        FrameCodec().message("Atris16_Status")


def test_decoder_rejections() -> None:
    codec = FrameCodec()
    with pytest.raises(FrameDecodeError, match="0x7FF is not in the CAN database"):
        codec.decode(0x7FF, bytes(8))
    with pytest.raises(FrameDecodeError, match="5 data bytes"):
        codec.decode(0x680, bytes(5))
    assert codec.decode(0x680, bytes(8)).crc_ok is False


@given(st.integers(0, 0x1FFFFFFF), st.binary(max_size=64), st.booleans())
def test_fuzz_decode_never_crashes(arbitration_id: int, data: bytes, extended: bool) -> None:
    try:
        frame = FrameCodec().decode(arbitration_id, data, extended)
    except FrameDecodeError:
        return
    assert all(not isinstance(v, float) or math.isfinite(v) for v in frame.signals.values())


@given(st.sampled_from([frame_id(u, k) for u in range(16) for k in FrameKind]),
       st.binary(min_size=8, max_size=8))
def test_fuzz_decode_unit_frames(arbitration_id: int, data: bytes) -> None:
    frame = FrameCodec().decode(arbitration_id, data)
    assert frame.crc_ok == (data[0] == e2e.profile1_crc(arbitration_id, data))


def test_atris_dbc_prints_the_shipped_file() -> None:
    out = subprocess.run([sys.executable, "-m", "atris_node", "dbc"], capture_output=True,
                         text=True, check=True).stdout
    assert out == dbc_text() and "BO_ 1664 Atris0_Status: 8 Atris0" in out


floats = st.floats(allow_nan=True, allow_infinity=True)
sector_states = st.sampled_from(list(SectorState))


@st.composite
def measurements(draw: st.DrawFn) -> Measurement:
    count = draw(st.integers(1, 16))
    sectors = tuple(SectorDistance(draw(st.integers(-2, 20)), draw(floats), draw(sector_states),
                                   draw(floats), draw(floats)) for _ in range(count))
    nearest = draw(st.one_of(st.none(), st.sampled_from(sectors)))
    return Measurement(draw(st.integers(-10, 2**40)), sectors, draw(floats), 0, nearest,
                       draw(st.one_of(st.none(), floats)), draw(st.one_of(st.none(), floats)))


@st.composite
def statuses(draw: st.DrawFn) -> UnitStatus:
    ints = st.integers(-1000, 100000)
    return UnitStatus(draw(st.sampled_from(list(UnitState))), draw(ints), draw(ints),
                      draw(floats), draw(ints), FaultBits(draw(st.integers(0, 255))),
                      draw(floats), draw(floats), draw(floats), draw(ints), draw(floats))


@given(measurements(), statuses(), floats)
def test_fuzz_any_measurement_encodes_strictly(measurement: Measurement, status: UnitStatus,
                                               now: float) -> None:
    """Whatever the pipeline hands over, the cycle encodes (strict) and decodes cleanly."""
    import can

    from atris_node.bus.can.publisher import Publisher

    with can.Bus(interface="virtual", channel="fuzz") as bus:
        frames = Publisher(bus, 1).compose(measurement, status, now)
    codec = FrameCodec()
    for msg in frames:
        decoded = codec.decode_message(msg)
        assert decoded.crc_ok
        assert all(not isinstance(v, float) or math.isfinite(v)
                   for v in decoded.signals.values())


@given(st.lists(st.tuples(st.sampled_from([frame_id(u, k) for u in (0, 5) for k in FrameKind]
                                          + [0x7FF, 0x18FF0000]),
                          st.binary(min_size=0, max_size=8), st.booleans()), max_size=40))
def test_fuzz_monitor_never_crashes(frames: list[tuple[int, bytes, bool]]) -> None:
    import can

    from atris_node.bus.can.monitor import BusMonitor, render_table

    monitor = BusMonitor()
    for i, (arbitration_id, payload, error) in enumerate(frames):
        data = payload
        if unit_of(arbitration_id) and len(data) == 8 and data[1] & 0x0F < 15:
            data = e2e.protect(data, arbitration_id, data[1] & 0x0F)  # passes E2E: kept
        monitor.feed(can.Message(arbitration_id=arbitration_id, data=data, timestamp=0.01 * i,
                                 is_extended_id=arbitration_id > 0x7FF, is_error_frame=error))
    assert isinstance(render_table(monitor.snapshot()), str)


def test_dbc_documents_free_and_unknown_sector_states() -> None:
    """A plain cantools user tells free (NO_RETURN) from unknown (INVALID) in a Sectors
    frame from the DBC's value table alone, for every unit and every sector slot."""
    db = cantools.database.load_string(dbc_text(), database_format="dbc")
    sectors = (SectorDistance(0, 0.0, SectorState.NO_RETURN, 0.0, 0.5),
               SectorDistance(1, 0.0, SectorState.INVALID),
               SectorDistance(2, 0.0, SectorState.VALID, 1.5, 0.9))
    frames = payloads.sectors_signals(sectors, 3, usable=True)
    decoded = [db.decode_message(m.arbitration_id, bytes(m.data)) for m in (
        FrameCodec().encode("Atris4_Sectors", signals, i, scaling=False)
        for i, signals in enumerate(frames))]
    assert str(decoded[0]["Distance0"]) == "no_return"  # sector 0
    assert str(decoded[0]["Distance1"]) == "invalid"  # sector 1
    assert decoded[1]["SectorIndex"] == 2 and decoded[1]["Distance0"] == pytest.approx(1.5)
    for message in db.messages:
        for signal in message.signals:
            if signal.name.startswith("Distance"):
                names = {str(v) for v in (signal.choices or {}).values()}
                assert {"no_return", "invalid"} <= names, (message.name, signal.name)
