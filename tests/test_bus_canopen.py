"""CANopen mode: a canopen RemoteNode master from the shipped EDS against the device."""

from __future__ import annotations

import time

import canopen
import pytest
from canopen.sdo import SdoAbortedError
from canopen_pair import NODE_ID, RUNNING, Pair
from canopen_pair import measurement as _measurement
from canopen_pair import sync_and_read as _sync_and_read

from atris_node.bus.canopen.device import CanopenDevice, eds_path, eds_text
from atris_node.types import Measurement, SectorDistance, SectorState, UnitState, UnitStatus


def test_master_configures_starts_and_receives_tpdos(pair: Pair) -> None:
    pair.device.start()
    pair.master.nmt.wait_for_heartbeat(timeout=2.0)
    assert pair.master.nmt.state == "PRE-OPERATIONAL"
    pair.master.sdo["Configuration"]["SectorCount"].raw = 8
    pair.master.sdo["Configuration"]["MaxDataAge_ms"].raw = 500
    assert pair.config == [("SectorCount", 8), ("MaxDataAge_ms", 500)]
    assert pair.device.config("MaxDataAge_ms") == 500
    pair.master.tpdo.read(from_od=True)
    pair.master.nmt.state = "OPERATIONAL"
    time.sleep(0.05)
    pair.device.update(_measurement(), RUNNING)
    _sync_and_read(pair, 3)
    distances = [pair.master.tpdo[3][f"SectorDistance_mm.Sector{i}"].raw for i in range(4)]
    assert distances == [1000, 1500, 2000, 2500]
    assert pair.master.tpdo[4]["SectorDistance_mm.Sector7"].raw == 0xFFFE
    assert pair.master.tpdo[2]["Nearest.Distance_mm"].raw == 1000
    assert pair.master.tpdo[2]["Nearest.TimeToCollision_cs"].raw == 200
    assert pair.master.tpdo[1]["Status.State"].raw == int(UnitState.RUNNING)
    assert pair.master.tpdo[1]["Status.CodeRow"].raw == 3
    assert pair.master.sdo["Status"]["MeasurementCounter"].raw == 0


def test_values_only_in_operational(pair: Pair) -> None:
    pair.device.start()
    pair.master.tpdo.read(from_od=True)
    pair.device.update(_measurement(), RUNNING)
    pair.master_net.sync.transmit()
    assert pair.master.tpdo[3].wait_for_reception(timeout=0.2) is None
    pair.master.nmt.state = "OPERATIONAL"
    time.sleep(0.05)
    _sync_and_read(pair, 3)
    pair.master.nmt.state = "STOPPED"
    time.sleep(0.05)
    pair.master_net.sync.transmit()
    assert pair.master.tpdo[3].wait_for_reception(timeout=0.2) is None


@pytest.mark.parametrize(("name", "value", "code"), [
    ("SectorCount", 0, 0x06090032), ("SectorCount", 17, 0x06090031),
    ("CodeLength", 24, 0x06090030), ("PublishPeriod_ms", 5, 0x06090032),
    ("WarningDistance_mm", 1234, 0x08000020),
])
def test_sdo_writes_are_validated(pair: Pair, name: str, value: int, code: int) -> None:
    pair.device.start()
    with pytest.raises(SdoAbortedError) as info:
        pair.master.sdo["Configuration"][name].raw = value
    assert info.value.code == code
    assert pair.config == []


def test_config_is_refused_in_operational_and_values_are_read_only(pair: Pair) -> None:
    pair.device.start()
    pair.master.nmt.state = "OPERATIONAL"
    time.sleep(0.05)
    with pytest.raises(SdoAbortedError) as info:
        pair.master.sdo["Configuration"]["SectorCount"].raw = 4
    assert info.value.code == 0x08000022
    with pytest.raises(SdoAbortedError) as info:
        pair.master.sdo["Status"]["State"].raw = 1
    assert info.value.code == 0x06010002


def test_stale_data_goes_out_invalid(pair: Pair) -> None:
    pair.device.start()
    pair.master.tpdo.read(from_od=True)
    pair.master.nmt.state = "OPERATIONAL"
    time.sleep(0.05)
    old = _measurement()
    stale = Measurement(old.counter, old.sectors, old.newest_time_s - 5.0, 0, old.nearest)
    pair.device.update(stale, RUNNING)
    _sync_and_read(pair, 3)
    assert pair.master.tpdo[3]["SectorDistance_mm.Sector0"].raw == 0xFFFF
    assert pair.master.sdo["Nearest"]["Valid"].raw == 0


def test_event_timer_after_pdo_reconfiguration(pair: Pair) -> None:
    pair.device.start()
    pair.master.sdo[0x1802][2].raw = 254
    pair.master.sdo[0x1802][5].raw = 20
    pair.master.tpdo.read(from_od=True)
    pair.master.nmt.state = "OPERATIONAL"
    pair.device.update(_measurement(), RUNNING)
    times = [pair.master.tpdo[3].wait_for_reception(timeout=0.5) for _ in range(4)]
    assert all(t is not None for t in times)
    assert pair.master.tpdo[3]["SectorDistance_mm.Sector1"].raw == 1500


def test_emcy_and_error_register(pair: Pair) -> None:
    pair.device.start()
    pair.device.emcy_camera_lost()
    error = pair.master.emcy.wait(0xFF01, timeout=1.0)
    assert error is not None and error.register & 0x80
    pair.device.emcy_bus_off_recovered()
    assert pair.master.emcy.wait(0x8140, timeout=1.0) is not None
    assert pair.master.sdo[0x1001].raw == 0x91
    pair.device.emcy_reset()
    assert pair.master.sdo[0x1001].raw == 0


def test_heartbeat_period_follows_0x1017(pair: Pair) -> None:
    pair.device.start()
    pair.master.sdo[0x1017].raw = 20
    pair.master.nmt.wait_for_heartbeat(timeout=1.0)
    start = time.monotonic()
    for _ in range(5):
        pair.master.nmt.wait_for_heartbeat(timeout=1.0)
    assert time.monotonic() - start < 0.5


def test_shipped_eds_has_the_standard_objects() -> None:
    od = canopen.import_od(str(eds_path()), NODE_ID)
    for index in (0x1000, 0x1001, 0x1017, 0x1018, 0x1800, 0x1A00, 0x2000, 0x2100, 0x2120):
        assert index in od
    assert od[0x1800][1].default == 0x4000_0000 | 0x180 + NODE_ID  # no RTR
    assert "[FileInfo]" in eds_text()


def test_atris_eds_prints_the_shipped_file(capsys: pytest.CaptureFixture[str]) -> None:
    from atris_node.cli import main

    assert main(["eds"]) == 0
    assert capsys.readouterr().out == eds_text()


def test_fuzz_update_never_fails() -> None:
    """Any measurement and status fit the object dictionary's types."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from atris_node.types import FaultBits

    device = CanopenDevice(canopen.Network(), NODE_ID)
    floats = st.floats(allow_nan=True, allow_infinity=True)
    sector = st.builds(SectorDistance, st.integers(-1, 20), floats,
                       st.sampled_from(list(SectorState)), floats, floats)

    @settings(max_examples=60, deadline=None)
    @given(st.lists(sector, min_size=1, max_size=16), floats, st.integers(-5, 300), floats,
           st.one_of(st.none(), floats))
    def check(sectors: list[SectorDistance], newest: float, row: int, rate: float,
              ttc: float | None) -> None:
        measurement = Measurement(1, tuple(sectors), newest, 0, sectors[0], rate, ttc)
        status = UnitStatus(UnitState.RUNNING, row, row, rate, row, FaultBits(row & 0xFF),
                            rate, rate, rate, row)
        device.update(measurement, status)
        assert 0 <= device.node.sdo["Nearest"]["Distance_mm"].raw <= 0xFFFF

    check()
