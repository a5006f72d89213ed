"""Every writable entry of 0x2000 is applied by the device or refused with its CiA 301
abort code, checked from a canopen master on a virtual bus.

The device runs on a clock the test moves by hand, so data ages are exact.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import canopen
import pytest
from canopen.sdo import SdoAbortedError
from canopen_pair import NODE_ID, RUNNING, FakeClock, Pair, measurement, sync_and_read

from atris_node.bus.canopen.configuration import power_on_values
from atris_node.bus.canopen.device import CanopenDevice, eds_path
from atris_node.bus.canopen.values import rebin
from atris_node.errors import ConfigError
from atris_node.types import SectorDistance, SectorState

TPDO3, INVALID, NO_RETURN = 0x380 + NODE_ID, 0xFFFF, 0xFFFE


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def pair(clock: FakeClock) -> Iterator[Pair]:
    p = Pair(clock=clock, watch=(TPDO3,))
    try:
        yield p
    finally:
        p.close()


def _write(pair: Pair, name: str, value: int) -> None:
    pair.master.sdo["Configuration"][name].raw = value


def _abort(pair: Pair, name: str, value: int) -> int:
    with pytest.raises(SdoAbortedError) as info:
        _write(pair, name, value)
    return info.value.code


def test_max_data_age_takes_effect_on_the_next_sync(pair: Pair, clock: FakeClock) -> None:
    """After MaxDataAge = 30 ms is written in OPERATIONAL, no TPDO carries data older than
    30 ms as valid, from the very next SYNC on; younger data stays valid (read
    MaxDataAge once at start instead of per transmission and this fails). SDO reads of
    the values are aged at the read (skip the composing in _on_sdo_request and the
    last one reads valid)."""
    pair.device.start()
    pair.operational()
    newest = clock.now
    pair.device.update(measurement(newest), RUNNING)
    clock.now = newest + 0.1
    pair.device.heartbeat()
    sync_and_read(pair, 3)
    assert pair.master.tpdo[3]["SectorDistance_mm.Sector0"].raw == 1000  # 100 ms < 200
    _write(pair, "MaxDataAge_ms", 30)
    for age_ms in (100, 0, 10, 29, 30, 31, 45, 60, 29):
        clock.now = newest + age_ms / 1000.0
        pair.device.heartbeat()
        sync_and_read(pair, 3)
        # TPDO2 goes out before TPDO3 on the same SYNC: it has arrived too
        sector_valid = pair.master.tpdo[3]["SectorDistance_mm.Sector0"].raw != INVALID
        nearest_valid = pair.master.tpdo[2]["Nearest.Distance_mm"].raw != INVALID
        assert sector_valid == nearest_valid == (age_ms <= 30), age_ms
    clock.now = newest + 0.029
    pair.device.heartbeat()
    sync_and_read(pair, 3)
    clock.now = newest + 0.031  # no SYNC since: an SDO read is aged all the same
    assert pair.master.sdo["Nearest"]["Valid"].raw == 0
    assert pair.master.sdo["SectorDistance_mm"]["Sector0"].raw == INVALID


def test_min_confidence_makes_less_confident_sectors_invalid(pair: Pair,
                                                             clock: FakeClock) -> None:
    """Sectors at 50 % confidence go out invalid once MinConfidence is 60 %, and the
    nearest obstacle with them; 40 % lets them through (skip values.confident in
    _write_values and this fails)."""
    pair.device.start()
    pair.operational()
    pair.device.update(measurement(clock.now, confidence=0.5), RUNNING)
    sync_and_read(pair, 3)
    assert pair.master.tpdo[3]["SectorDistance_mm.Sector0"].raw == 1000
    _write(pair, "MinConfidence_pct", 60)
    sync_and_read(pair, 3)
    assert pair.master.tpdo[3]["SectorDistance_mm.Sector0"].raw == INVALID
    assert pair.master.sdo["Nearest"]["Valid"].raw == 0
    _write(pair, "MinConfidence_pct", 40)
    sync_and_read(pair, 3)
    assert pair.master.tpdo[3]["SectorDistance_mm.Sector0"].raw == 1000
    assert pair.master.sdo["Nearest"]["Valid"].raw == 1


def test_warning_distance_sets_the_warning_object(pair: Pair, clock: FakeClock) -> None:
    """0x2110 sub 6 Warning: 1 for the nearest obstacle (1000 mm) within 2000 mm, 0 once
    WarningDistance is 900 mm, 1 again without usable data (ignore the entry in
    values.warning and this fails)."""
    pair.device.start()
    pair.operational()
    pair.device.update(measurement(clock.now), RUNNING)
    assert pair.master.sdo["Nearest"]["Warning"].raw == 1
    _write(pair, "WarningDistance_mm", 900)
    sync_and_read(pair, 2)
    assert pair.master.sdo["Nearest"]["Warning"].raw == 0
    pair.device.update(None, RUNNING)
    assert pair.master.sdo["Nearest"]["Warning"].raw == 1


def test_sector_count_re_bins_the_measured_sectors(pair: Pair, clock: FakeClock) -> None:
    """SectorCount 4 of the 8 measured sectors: each published sector is the nearest of
    two, none is dropped (without values.rebin the device publishes sectors 0-3 only:
    1000, 1500...)."""
    pair.device.start()
    _write(pair, "SectorCount", 4)
    pair.operational()
    pair.device.update(measurement(clock.now), RUNNING)
    sync_and_read(pair, 4)
    distances = [pair.master.tpdo[3][f"SectorDistance_mm.Sector{i}"].raw for i in range(4)]
    assert distances == [1000, 2000, 3000, 4000]
    assert pair.master.tpdo[4]["SectorDistance_mm.Sector4"].raw == INVALID


@pytest.mark.parametrize(("value", "code"), [(3, 0x06090030), (16, 0x06090031),
                                             (0, 0x06090032), (17, 0x06090031)])
def test_sector_count_the_unit_cannot_honour_is_refused(pair: Pair, value: int,
                                                        code: int) -> None:
    """8 measured sectors re-bin into 1, 2, 4 or 8 only (drop the divisor check in
    configuration.check_value and 3 is accepted)."""
    pair.device.start()
    assert _abort(pair, "SectorCount", value) == code
    assert pair.master.sdo["Configuration"]["SectorCount"].raw == 8
    assert pair.config == []


def test_publish_period_times_event_driven_tpdos_without_a_timer(
        pair: Pair, clock: FakeClock) -> None:
    """TPDO3 event-driven (254) with event timer 0 goes out every PublishPeriod_ms; a
    new period written in OPERATIONAL counts from the next event (a fixed 50 ms in place
    of PublishPeriod_ms and this fails)."""
    pair.device.start()
    pair.master.sdo[0x1802][2].raw = 254
    pair.operational()
    pair.device.update(measurement(clock.now), RUNNING)
    sent = len(pair.wait_frames(TPDO3, 1))
    clock.now += 0.049  # PublishPeriod_ms is 50
    time.sleep(0.1)
    assert len(pair.frames[TPDO3]) == sent
    clock.now += 0.002
    sent = len(pair.wait_frames(TPDO3, sent + 1))
    _write(pair, "PublishPeriod_ms", 200)
    clock.now += 0.1
    time.sleep(0.1)
    assert len(pair.frames[TPDO3]) == sent
    clock.now += 0.101
    pair.wait_frames(TPDO3, sent + 1)


def test_code_length_goes_to_the_node_in_pre_operational(pair: Pair) -> None:
    """CodeLength: a power of two reaches ``on_config``; 24 is refused with 0x06090030
    (drop the power-of-two check and it is accepted), in OPERATIONAL with 0x08000022
    (see test_canopen_nmt)."""
    pair.device.start()
    _write(pair, "CodeLength", 8)
    assert _abort(pair, "CodeLength", 24) == 0x06090030
    assert pair.config == [("CodeLength", 8)]
    assert pair.device.config("CodeLength") == 8


def test_entries_applied_live_are_writable_in_operational(pair: Pair) -> None:
    """PublishPeriod, MaxDataAge, MinConfidence and WarningDistance are taken in
    OPERATIONAL (make one PRE-OPERATIONAL only and this fails); a value the node refuses
    still aborts with 0x08000020."""
    pair.device.start()
    pair.operational()
    for name, value in (("PublishPeriod_ms", 20), ("MaxDataAge_ms", 100),
                        ("MinConfidence_pct", 10), ("WarningDistance_mm", 500)):
        _write(pair, name, value)
        assert pair.device.config(name) == value
    assert _abort(pair, "WarningDistance_mm", 1234) == 0x08000020
    assert pair.device.config("WarningDistance_mm") == 500


def test_power_on_values_are_the_node_settings() -> None:
    """The node's settings replace the EDS defaults; names and values are checked."""
    record = canopen.import_od(str(eds_path()), NODE_ID)[0x2000]
    values = power_on_values(record, {"SectorCount": 16, "MaxDataAge_ms": 250})
    assert values["SectorCount"] == 16 and values["MaxDataAge_ms"] == 250
    assert values["CodeLength"] == 16  # EDS default
    with pytest.raises(ConfigError, match="no such entry"):
        power_on_values(record, {"Sectors": 4})
    with pytest.raises(ConfigError, match="CodeLength = 12"):
        power_on_values(record, {"CodeLength": 12})
    with pytest.raises(ConfigError, match="MinConfidence_pct = 101"):
        CanopenDevice(canopen.Network(), NODE_ID, settings={"SectorCount": 8,
                                                            "MinConfidence_pct": 101})


def test_rebin_keeps_the_nearest_and_is_safe() -> None:
    """Merged sectors: the nearest valid distance, INVALID when any part is invalid,
    NO_RETURN only when every part is; counts that do not divide leave them as they are."""
    s = [SectorDistance(0, -0.3, SectorState.VALID, 2.0, 0.9),
         SectorDistance(1, -0.1, SectorState.VALID, 1.0, 0.4),
         SectorDistance(2, 0.1, SectorState.NO_RETURN),
         SectorDistance(3, 0.3, SectorState.INVALID),
         SectorDistance(4, 0.5, SectorState.NO_RETURN),
         SectorDistance(5, 0.7, SectorState.NO_RETURN)]
    merged = rebin(s, 3)
    assert [m.state for m in merged] == [SectorState.VALID, SectorState.INVALID,
                                         SectorState.NO_RETURN]
    assert merged[0].distance_m == 1.0 and merged[0].confidence == 0.4
    assert merged[0].bearing_rad == pytest.approx(-0.2)
    assert rebin(s, 4) == tuple(s)
    assert rebin(s, 6) == tuple(s)
