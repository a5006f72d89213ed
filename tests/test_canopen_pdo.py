"""TPDO parameters, PDO mapping and the SYNC / EMCY COB-IDs written by a canopen master:
valid changes take effect, invalid ones are refused with the CiA 301 abort codes."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from canopen.sdo import SdoAbortedError, SdoVariable
from canopen_pair import NODE_ID, RUNNING, FakeClock, Pair, measurement, sync_and_read

from atris_node.types import UnitState

NOT_VALID, NO_RTR = 0x8000_0000, 0x4000_0000
TPDO3 = 0x380 + NODE_ID
MOVED_TPDO, MOVED_SYNC, MOVED_EMCY = 0x3C0 + NODE_ID, 0x081, 0x0A5
DEFAULT_TPDO3_MAP = [0x21000110, 0x21000210, 0x21000310, 0x21000410]


@pytest.fixture
def pair() -> Iterator[Pair]:
    p = Pair(watch=(TPDO3, MOVED_TPDO, MOVED_EMCY))
    try:
        yield p
    finally:
        p.close()


def _abort(pair: Pair, index: int, subindex: int, value: int) -> int:
    target = pair.master.sdo[index]
    if not isinstance(target, SdoVariable):
        target = target[subindex]
    with pytest.raises(SdoAbortedError) as info:
        target.raw = value
    return int(info.value.code)


def _unmap(pair: Pair) -> None:
    """CiA 301 steps 1 and 2 for TPDO3: not valid, no mapping in force."""
    pair.master.sdo[0x1802][1].raw = NOT_VALID | NO_RTR | TPDO3
    pair.master.sdo[0x1A02][0].raw = 0


def test_master_remaps_a_tpdo_with_the_canopen_pdo_api(pair: Pair) -> None:
    """canopen's ``PdoMap.save`` (the CiA 301 procedure) is accepted and TPDO3 carries
    the new mapping from the next SYNC."""
    pair.device.start()
    pair.master.tpdo.read(from_od=True)
    tpdo = pair.master.tpdo[3]
    tpdo.clear()
    tpdo.add_variable("Nearest", "Distance_mm")
    tpdo.add_variable("Status", "State")
    tpdo.add_variable("Nearest", "Warning")
    tpdo.trans_type, tpdo.enabled = 1, True
    tpdo.save()
    assert pair.master.sdo[0x1A02][0].raw == 3
    pair.nmt("OPERATIONAL")
    pair.device.update(measurement(), RUNNING)
    sync_and_read(pair, 3)
    assert pair.master.tpdo[3]["Nearest.Distance_mm"].raw == 1000
    assert pair.master.tpdo[3]["Status.State"].raw == int(UnitState.RUNNING)
    assert pair.master.tpdo[3]["Nearest.Warning"].raw == 1
    assert len(pair.frames[TPDO3][-1]) == 4


@pytest.mark.parametrize(("entry", "code"), [
    (0x21000100, 0x06040041),  # zero bits
    (0x21000108, 0x06040041),  # not the object's own length
    (0x20000108, 0x06040041),  # CodeLength: not mappable
    (0x22000010, 0x06020000),  # no such object
    (0x21001110, 0x06020000),  # no such sub-index (sector 16)
])
def test_invalid_mapping_entries_are_refused(pair: Pair, entry: int, code: int) -> None:
    """Each entry must name an existing mappable object with its own length (drop
    pdo.mapped_bits from check_map_write and every one is accepted)."""
    pair.device.start()
    _unmap(pair)
    assert _abort(pair, 0x1A02, 1, entry) == code


def test_mapping_over_64_bits_or_8_entries_is_refused(pair: Pair) -> None:
    """Five 16-bit objects are 80 bits: sub 0 = 5 gets 0x06040042, as does sub 0 = 9
    (drop the length sum in check_mapping and 5 is accepted); the TPDO keeps working
    with the mapping restored."""
    pair.device.start()
    _unmap(pair)
    for sub in range(1, 6):
        pair.master.sdo[0x1A02][sub].raw = 0x21000010 | sub << 8
    assert _abort(pair, 0x1A02, 0, 5) == 0x06040042
    assert _abort(pair, 0x1A02, 0, 9) == 0x06040042
    pair.master.sdo[0x1A02][0].raw = 4
    pair.master.sdo[0x1802][1].raw = NO_RTR | TPDO3
    pair.operational()
    pair.device.update(measurement(), RUNNING)
    sync_and_read(pair, 3)
    assert pair.master.tpdo[3]["SectorDistance_mm.Sector0"].raw == 1000


def test_mapping_changes_only_through_the_cia_301_procedure(pair: Pair) -> None:
    """Mapping writes while the TPDO is valid, or entries while sub 0 is not 0, get
    0x08000022 (drop the two state checks in check_map_write and they are accepted)."""
    pair.device.start()
    assert _abort(pair, 0x1A02, 0, 0) == 0x08000022
    assert _abort(pair, 0x1A02, 1, 0x21000510) == 0x08000022
    pair.master.sdo[0x1802][1].raw = NOT_VALID | NO_RTR | TPDO3
    assert _abort(pair, 0x1A02, 1, 0x21000510) == 0x08000022
    assert [pair.master.sdo[0x1A02][s].raw for s in range(1, 5)] == DEFAULT_TPDO3_MAP


@pytest.mark.parametrize(("value", "why"), [
    (NO_RTR | MOVED_TPDO, "CAN-ID changed while valid"),
    (NOT_VALID | NO_RTR | 0x2000_0000 | TPDO3, "29-bit"),
    (NOT_VALID | NO_RTR | 0x601, "restricted (SDO)"),
    (NO_RTR | 0x1000 | TPDO3, "bits above the 11-bit CAN-ID"),
    (TPDO3, "RTR allowed"),
])
def test_invalid_tpdo_cob_ids_are_refused(pair: Pair, value: int, why: str) -> None:
    """CiA 301 COB-ID rules for 0x180x sub 1 (drop pdo.check_cob_id and they pass)."""
    pair.device.start()
    assert _abort(pair, 0x1802, 1, value) == 0x06090030, why


def test_a_tpdo_moved_to_another_can_id_goes_out_there(pair: Pair) -> None:
    """Not valid, new CAN-ID, valid: TPDO3 on the new CAN-ID from the next SYNC (the
    canopen TPDO parameters re-read after the writes)."""
    pair.device.start()
    for value in (NOT_VALID | NO_RTR | TPDO3, NOT_VALID | NO_RTR | MOVED_TPDO,
                  NO_RTR | MOVED_TPDO):
        pair.master.sdo[0x1802][1].raw = value
    pair.nmt("OPERATIONAL")
    pair.device.update(measurement(), RUNNING)
    pair.master_net.sync.transmit()
    assert pair.wait_frames(MOVED_TPDO, 1)[0][:2] == (1000).to_bytes(2, "little")
    assert pair.frames[TPDO3] == []


@pytest.mark.parametrize("kind", [241, 251, 252, 253])
def test_unsupported_transmission_types_are_refused(pair: Pair, kind: int) -> None:
    """Reserved (241..251) and RTR-only (252/253) types: 0x06090030 (accept every
    type in pdo.TRANSMISSION_TYPES and this fails)."""
    pair.device.start()
    assert _abort(pair, 0x1802, 2, kind) == 0x06090030


def test_inhibit_time_changes_only_while_not_valid(pair: Pair) -> None:
    """0x180x sub 3 while the TPDO is valid: 0x06090030 (drop the sub 3 check in
    check_comm_write and it is taken); while not valid it is taken."""
    pair.device.start()
    assert _abort(pair, 0x1802, 3, 100) == 0x06090030
    pair.master.sdo[0x1802][1].raw = NOT_VALID | NO_RTR | TPDO3
    pair.master.sdo[0x1802][3].raw = 100
    assert pair.master.sdo[0x1802][3].raw == 100


def test_transmission_type_0_sends_on_sync_after_new_values_only(pair: Pair) -> None:
    """Acyclic synchronous: a SYNC after update() sends TPDO3, the next SYNC without new
    values does not (send on every SYNC for type 0 and this fails)."""
    pair.device.start()
    pair.master.sdo[0x1802][2].raw = 0
    pair.operational()
    pair.device.update(measurement(), RUNNING)
    sync_and_read(pair, 3)
    pair.master_net.sync.transmit()
    assert pair.master.tpdo[3].wait_for_reception(timeout=0.2) is None
    pair.device.update(measurement(), RUNNING)
    sync_and_read(pair, 3)


def test_sync_cob_id_0x1005_is_honoured(pair: Pair) -> None:
    """SYNC moved to 0x081: TPDOs answer SYNC there and no longer on 0x080 (ignore
    0x1005 as before and this fails); the device never produces SYNC (bit 30 refused)."""
    pair.device.start()
    assert _abort(pair, 0x1005, 0, 0x4000_0000 | MOVED_SYNC) == 0x06090030
    pair.master.sdo[0x1005].raw = MOVED_SYNC
    pair.operational()
    pair.device.update(measurement(), RUNNING)
    pair.master_net.sync.transmit()
    assert pair.master.tpdo[3].wait_for_reception(timeout=0.2) is None
    pair.master_net.send_message(MOVED_SYNC, b"")
    assert pair.master.tpdo[3].wait_for_reception(timeout=1.0) is not None


def test_emcy_cob_id_0x1014_is_honoured(pair: Pair) -> None:
    """EMCY not valid: none sent; moved to 0x0A5: sent there (ignore 0x1014 and this
    fails)."""
    pair.device.start()
    assert pair.master.sdo[0x1014].raw == 0x80 + NODE_ID
    pair.master.sdo[0x1014].raw = NOT_VALID | 0x80 + NODE_ID
    pair.device.emcy_camera_lost()
    assert pair.master.emcy.wait(0xFF01, timeout=0.2) is None
    pair.master.sdo[0x1014].raw = NOT_VALID | MOVED_EMCY
    pair.master.sdo[0x1014].raw = MOVED_EMCY
    pair.device.emcy_laser_fault()
    assert pair.wait_frames(MOVED_EMCY, 1)[0][:2] == (0xFF02).to_bytes(2, "little")
    assert _abort(pair, 0x1014, 0, 0x0A6) == 0x06090030  # moved while valid


def test_inhibit_time_bounds_the_event_period() -> None:
    """An event-driven TPDO with a 10 ms event timer and a 50 ms inhibit time goes out
    every 50 ms (ignore the inhibit time in TpdoService._event_period_s and a second
    frame comes after 20 ms)."""
    clock = FakeClock()
    p = Pair(clock=clock, watch=(TPDO3,))
    try:
        p.device.start()
        p.master.sdo[0x1802][1].raw = NOT_VALID | NO_RTR | TPDO3
        p.master.sdo[0x1802][2].raw = 254
        p.master.sdo[0x1802][3].raw = 500  # 100 us steps
        p.master.sdo[0x1802][5].raw = 10
        p.master.sdo[0x1802][1].raw = NO_RTR | TPDO3
        p.operational()
        sent = len(p.wait_frames(TPDO3, 1))
        clock.now += 0.02
        time.sleep(0.1)
        assert len(p.frames[TPDO3]) == sent
        clock.now += 0.031
        p.wait_frames(TPDO3, sent + 1)
    finally:
        p.close()
