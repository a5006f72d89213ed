"""The CAN database generated from the frame table: the shipped file, its section order,
the unit ID layout against CANopen, cycle times and the E2E attributes."""

from __future__ import annotations

import itertools
import re
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest
from e2e.p01 import E2E_P01_DATAID_BOTH, e2e_p01_check, e2e_p01_protect

from atris_node.bus.can import dbc, e2e, ids
from atris_node.bus.can.frames import FrameCodec, dbc_text, load_database
from atris_node.bus.can.ids import FrameKind, check_base_id, frame_id, message_name
from atris_node.bus.can.publisher import Publisher
from atris_node.config import PARAMS, defaults
from atris_node.errors import ConfigError
from atris_node.types import Measurement, SectorDistance, SectorState, UnitState, UnitStatus

STATUS = UnitStatus(UnitState.RUNNING, code_row=3, code_length=16, chip_rate_hz=480.0,
                    measurement_counter=9)
#: the order of the sections after the messages, as DBC tools expect it
SECTION_ORDER = ("BO_", "CM_", "BA_DEF_", "BA_DEF_DEF_", "BA_", "VAL_")


def _measurement(now: float, count: int = 8) -> Measurement:
    sectors = tuple(SectorDistance(i, 0.0, SectorState.VALID, 1.0 + i, 0.9)
                    for i in range(count))
    return Measurement(5, sectors, now, 100, nearest=sectors[0], closing_speed_mps=0.4,
                       time_to_collision_s=2.5)


def _cycle(unit_id: int, base_id: int = ids.DEFAULT_BASE_ID, sectors: int = 8,
           cycles: int = 1) -> list[can.Message]:
    """The frames a publisher of ``unit_id`` sends in ``cycles`` cycles."""
    with can.Bus(interface="virtual", channel="dbc-test") as bus:
        publisher = Publisher(bus, unit_id, base_id=base_id, sector_count=sectors,
                              max_age_s=1.0)
        return [msg for i in range(cycles)
                for msg in publisher.compose(_measurement(float(i)), STATUS, float(i))]


def sections(text: str) -> list[str]:
    """Keyword of each top-level statement after the node list, in file order."""
    body = text.split("\nBU_:", 1)[1]
    return re.findall(r"^(BO_|CM_|BA_DEF_DEF_|BA_DEF_|BA_|VAL_)\s", body, flags=re.MULTILINE)


def test_smoke_shipped_dbc_is_the_generated_one() -> None:
    """The shipped atris.dbc is what the frame table generates for the default base.

    Checked to fail: with one SG_ line of the shipped file edited by hand, this failed."""
    assert dbc_text() == dbc.generate_text()


def test_smoke_atris_dbc_generates_and_prints_other_bases(tmp_path: Path) -> None:
    """``atris dbc --generate -o FILE`` writes the generated text (without ``-o`` it
    rewrites the shipped file), ``--base-id`` prints the database of another base, and
    ``--generate`` with another base is refused."""
    out = tmp_path / "atris.dbc"
    subprocess.run([sys.executable, "-m", "atris_node", "dbc", "--generate", "-o", str(out)],
                   check=True)
    assert out.read_text("utf-8") == dbc.generate_text()
    printed = subprocess.run([sys.executable, "-m", "atris_node", "dbc", "--base-id", "0x100"],
                             capture_output=True, text=True, check=True).stdout
    assert printed == dbc.generate_text(0x100) and "BO_ 256 Atris0_Status" in printed
    failed = subprocess.run([sys.executable, "-m", "atris_node", "dbc", "--generate",
                             "--base-id", "0x100"], capture_output=True, text=True, check=False)
    assert failed.returncode == 1 and "default base" in failed.stderr


def test_feature_sections_in_standard_order() -> None:
    """Every BO_ comes before the comments, attribute definitions, defaults, attribute
    values and value tables, in that order.

    Checked to fail: on the previous hand-written file (negotiation BO_ after VAL_)."""
    found = sections(dbc_text())
    first = [found.index(keyword) for keyword in SECTION_ORDER]
    assert first == sorted(first)
    for keyword, later in itertools.pairwise(SECTION_ORDER):
        last_of = max(i for i, k in enumerate(found) if k == keyword)
        assert last_of < found.index(later), f"a {keyword} after the first {later}"


def test_feature_sixteen_units_from_one_layout() -> None:
    """Each unit's four messages have the layout of the table, at base + 4 * unit + kind."""
    db = load_database()
    for unit in range(16):
        for kind, spec in dbc.UNIT_MESSAGES.items():
            message = db.get_message_by_name(message_name(unit, kind))
            assert message.frame_id == frame_id(unit, kind)
            assert [(s.name, s.start, s.length) for s in message.signals] == [
                (s.name, s.start, s.length) for s in spec.signals]


def test_feature_default_layout_is_outside_the_canopen_predefined_set() -> None:
    """No unit frame ID of the default layout is an ID of the CANopen predefined
    connection set.

    Checked to fail: with the former base 0x500 as default (RPDO4, SDO responses)."""
    used = {frame_id(u, k) for u in range(16) for k in FrameKind}
    predefined = {i for lo, hi, _ in ids.CANOPEN_PREDEFINED for i in range(lo, hi + 1)}
    assert used.isdisjoint(predefined) and max(used) <= 0x7FF
    assert ids.canopen_overlap(ids.DEFAULT_BASE_ID) is None


@pytest.mark.parametrize(("base_id", "message"), [
    (0x500, r"inside the CANopen predefined connection set \(RPDO4 0x501-0x57F\)"),
    (0x5E0, r"SDO responses 0x581-0x5FF, SDO requests 0x601-0x67F"),
    (0x7C1, r"\(bus\.base_id\) must be 0x000\.\.0x7C0 \(16 units x 4 IDs in 11 bits\), got 0x7C1"),
    (-1, r"must be 0x000\.\.0x7C0"),
])
def test_exception_base_id_out_of_bounds(base_id: int, message: str) -> None:
    """A base whose blocks leave 11 bits or hit CANopen IDs is refused, naming the clash.

    Checked to fail: without the overlap check in check_base_id, 0x500 and 0x5E0 passed."""
    with pytest.raises(ConfigError, match=message):
        check_base_id(base_id)


def _output(**settings: str) -> Publisher:
    """The publisher a unit with ``settings`` (text, as from a file) gets."""
    from atris_node.node.wiring import BusServices, make_output

    config = defaults().with_values(settings, "test", from_text=True)
    with can.Bus(interface="virtual", channel="dbc-node") as bus:
        services = BusServices(can.Notifier(bus, [], timeout=0.1))
        try:
            output = make_output(config, bus, services, lambda: 0.0)
        finally:
            services.stop()
    assert isinstance(output, Publisher)
    return output


def test_feature_base_id_setting_is_checked_with_its_allowance() -> None:
    """The node setting defaults to the shipped layout, accepts what check_base_id
    accepts, and a unit refuses CANopen IDs unless bus.allow_canopen_ids is set.

    Checked to fail: without the check in wiring.make_output (0x500 went through)."""
    param = next(p for p in PARAMS if p.key == "bus.base_id")
    assert param.default == ids.DEFAULT_BASE_ID
    assert param.check(ids.MAX_STANDARD_ID + 1 - ids.ID_SPAN) is None
    assert param.check(ids.MAX_STANDARD_ID + 2 - ids.ID_SPAN) is not None
    with pytest.raises(ConfigError, match=r"bus\.base_id\).*RPDO4.*bus\.allow_canopen_ids"):
        _output(**{"bus.base_id": "0x500"})
    allowed = _output(**{"bus.base_id": "0x500", "bus.allow_canopen_ids": "true"})
    assert allowed.compose(None, STATUS, 0.0)[0].arbitration_id == 0x500


def test_feature_other_base_sends_there_and_generated_dbc_decodes() -> None:
    """A publisher configured with another base sends in that block, and plain cantools
    with the DBC generated for that base decodes every frame (the shipped one does not)."""
    frames = _cycle(5, base_id=0x100)
    assert {m.arbitration_id for m in frames} == {0x114, 0x115, 0x116, 0x117}
    db = cantools.database.load_string(dbc.generate_text(0x100), database_format="dbc")
    decoded = [db.decode_message(m.arbitration_id, bytes(m.data)) for m in frames]
    assert decoded[0]["State"] == "RUNNING" and decoded[3]["Distance0"] == 1.0
    with pytest.raises(KeyError):
        load_database().get_message_by_frame_id(0x114)
    assert FrameCodec(base_id=0x100).decode_message(frames[0]).name == "Atris5_Status"


def test_feature_sectors_cycle_time_is_the_mean_frame_interval() -> None:
    """GenMsgCycleTime of Sectors is the period divided by the frames a default cycle has
    (8 sectors: four frames, 12 ms rounded down from 12.5); the other frames once per
    period.

    Checked to fail: with the former 50 ms for the Sectors of unit 2 in the shipped file."""
    frames = _cycle(2)
    sectors_id = frame_id(2, FrameKind.SECTORS)
    per_cycle = sum(m.arbitration_id == sectors_id for m in frames)
    db = load_database()
    assert per_cycle == 4
    assert db.get_message_by_frame_id(sectors_id).cycle_time == dbc.CYCLE_MS // per_cycle
    for kind in (FrameKind.STATUS, FrameKind.QUALITY, FrameKind.NEAREST):
        assert db.get_message_by_frame_id(frame_id(2, kind)).cycle_time == dbc.CYCLE_MS


def _e2e_config(message: cantools.database.can.Message) -> tuple[int, int, int]:
    """(data ID, data ID mode, byte offset of the E2E header) of ``message``, read from
    its DBC attributes alone as a receiver would."""
    attributes = message.dbc.attributes
    profile = dbc.DEFINITIONS["E2EProfile"].choices[attributes["E2EProfile"].value]
    assert profile == "Profile1"
    roles = {dbc.DEFINITIONS["E2ESignalRole"].choices[s.dbc.attributes["E2ESignalRole"].value]:
             s for s in message.signals if s.dbc and "E2ESignalRole" in s.dbc.attributes}
    crc, counter = roles["CRC"], roles["Counter"]
    assert (crc.length, counter.length, counter.start - crc.start) == (8, 4, 8)
    return attributes["E2EDataID"].value, attributes["E2EDataIDMode"].value, crc.start // 8


@pytest.mark.parametrize("base_id", [ids.DEFAULT_BASE_ID, 0x100])
def test_feature_autosar_e2e_accepts_what_the_node_sends(base_id: int) -> None:
    """The autosar-e2e package's Profile 1 check, configured from the DBC attributes (data
    ID, data ID mode, CRC and counter signals), accepts every frame the publisher sends
    over a full counter cycle, for two units; with the data ID of another frame it does
    not.

    Checked to fail: with E2EDataIDMode ALT for unit 0 in the shipped file, with ALT in
    the generator (other base), and with profile1_crc given the plain J1850 start 0xFF
    (which also fails the next test)."""
    text = dbc_text() if base_id == ids.DEFAULT_BASE_ID else dbc.generate_text(base_id)
    db = cantools.database.load_string(text, database_format="dbc")
    checked = 0
    for unit_id in (0, 13):
        for msg in _cycle(unit_id, base_id=base_id, cycles=16):
            data_id, mode, offset = _e2e_config(db.get_message_by_frame_id(msg.arbitration_id))
            assert e2e_p01_check(bytearray(msg.data), data_id, data_id_mode=mode, offset=offset)
            assert not e2e_p01_check(bytearray(msg.data), data_id ^ 1, data_id_mode=mode)
            checked += 1
    assert checked == 2 * 16 * 7


@pytest.mark.parametrize("data_id", [0x0000, 0x0123, 0x0680, 0x06BF, 0xFFFF])
def test_feature_protect_equals_autosar_e2e(data_id: int) -> None:
    """e2e.protect writes the same CRC as the autosar-e2e package for every counter value
    and a spread of payloads (the hand-written CRC is the library's)."""
    for counter in range(15):
        for fill in (0x00, 0x5A, 0xFF):
            body = bytes([0, 0xF0 & fill]) + bytes([fill ^ k for k in range(6)])
            ours = e2e.protect(body, data_id, counter)
            theirs = bytearray(body)
            theirs[1] = (theirs[1] & 0xF0) | counter
            e2e_p01_protect(theirs, data_id, data_id_mode=E2E_P01_DATAID_BOTH,
                            increment_counter=False)
            assert ours == bytes(theirs)


def test_feature_node_configured_with_another_base_sends_there() -> None:
    """A unit configured with ``bus.base_id = 0x020`` (outside the predefined set, so no
    allowance needed) gets a publisher whose frames lie in 0x020 + 4 * unit_id ... + 3,
    and plain cantools decodes them with ``atris dbc --base-id 0x020``'s database.

    Checked to fail: with make_output not passing bus.base_id (frames at 0x6A4...)."""
    publisher = _output(**{"bus.base_id": "0x020", "unit.unit_id": "9"})
    frames = publisher.compose(_measurement(0.0), STATUS, 0.0)
    assert {m.arbitration_id for m in frames} == {0x044, 0x045, 0x046, 0x047}
    db = cantools.database.load_string(dbc.generate_text(0x020), database_format="dbc")
    names = [db.get_message_by_frame_id(m.arbitration_id).name for m in frames]
    assert names[:3] == ["Atris9_Status", "Atris9_Quality", "Atris9_Nearest"]
    assert all(db.decode_message(m.arbitration_id, bytes(m.data)) for m in frames)
