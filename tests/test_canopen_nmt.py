"""The CiA 301 NMT state machine of the device, driven by a canopen master on a virtual bus.

The master's frames on 0x700 + node ID (boot-up 0x00, heartbeats with the state byte) are
recorded; the checks are on what was sent, never on when.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError
from canopen_pair import NODE_ID, RUNNING, Pair, measurement, sync_and_read

HEARTBEAT = 0x700 + NODE_ID
BOOT_UP, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0x00, 0x04, 0x05, 0x7F


@pytest.fixture
def pair() -> Iterator[Pair]:
    p = Pair(watch=(HEARTBEAT,))
    try:
        yield p
    finally:
        p.close()


def test_boot_up_once_then_pre_operational_heartbeats(pair: Pair) -> None:
    """One boot-up, then the heartbeat says PRE-OPERATIONAL (a device that stayed
    INITIALISING sent 0x00 every period: remove ``self.state = PRE_OPERATIONAL`` in
    NmtSlave.boot and this fails)."""
    pair.device.start()
    pair.master.sdo[0x1017].raw = 10
    states = [data[0] for data in pair.wait_frames(HEARTBEAT, 6)]
    assert states[0] == BOOT_UP
    assert set(states[1:]) == {PRE_OPERATIONAL}
    assert pair.device.nmt_state == "PRE-OPERATIONAL"


@pytest.mark.parametrize("command", ["RESET", "RESET COMMUNICATION"])
def test_reset_boots_once_into_pre_operational(pair: Pair, command: str) -> None:
    """Reset node and reset communication from OPERATIONAL: exactly one more boot-up,
    heartbeats PRE-OPERATIONAL again, no TPDO on SYNC (the old device stayed INITIALISING
    and sent a boot-up every period: leaving NmtSlave.boot in INITIALISING after a
    reset makes this fail)."""
    pair.device.start()
    pair.master.sdo[0x1017].raw = 10
    pair.operational()
    before = len(pair.wait_frames(HEARTBEAT, 3))
    pair.nmt(command)
    pair.master.sdo[0x1017].raw = 10  # the reset restored 1000 ms
    states = [data[0] for data in pair.wait_frames(HEARTBEAT, before + 5)][before:]
    boot = states.index(BOOT_UP)
    assert set(states[:boot]) <= {OPERATIONAL}
    assert set(states[boot + 1:]) == {PRE_OPERATIONAL}
    pair.device.update(measurement(), RUNNING)
    pair.master_net.sync.transmit()
    assert pair.master.tpdo[3].wait_for_reception(timeout=0.2) is None


def test_reset_communication_restores_the_communication_area_only(pair: Pair) -> None:
    """0x1017 and the TPDO parameters back to the EDS values, 0x2000 kept (remove the
    ``_restore(COMMUNICATION_AREA)`` call and the heartbeat time stays 10 ms)."""
    pair.device.start()
    pair.master.sdo[0x1017].raw = 10
    pair.master.sdo[0x1802][2].raw = 5
    pair.master.sdo["Configuration"]["MaxDataAge_ms"].raw = 30
    pair.nmt("RESET COMMUNICATION")
    assert pair.master.sdo[0x1017].raw == 1000
    assert pair.master.sdo[0x1802][2].raw == 1
    assert pair.master.sdo["Configuration"]["MaxDataAge_ms"].raw == 30
    assert pair.config == [("MaxDataAge_ms", 30)]


def test_reset_node_restores_the_power_on_configuration() -> None:
    """Reset node: 0x2000 back to the node's own settings (not the EDS defaults) and
    ``on_config`` hears of each entry that changed back (remove ``_restore(APPLICATION_AREA)``
    / ``_store_power_on()`` in _reset_application and this fails)."""
    p = Pair(settings={"MaxDataAge_ms": 250, "SectorCount": 8})
    try:
        p.device.start()
        assert p.master.sdo["Configuration"]["MaxDataAge_ms"].raw == 250
        p.master.sdo["Configuration"]["MaxDataAge_ms"].raw = 30
        p.master.sdo["Configuration"]["SectorCount"].raw = 4
        p.master.sdo[0x1017].raw = 500
        p.nmt("RESET")
        assert p.master.sdo["Configuration"]["MaxDataAge_ms"].raw == 250
        assert p.master.sdo["Configuration"]["SectorCount"].raw == 8
        assert p.master.sdo[0x1017].raw == 1000
        assert sorted(p.config[2:]) == [("MaxDataAge_ms", 250), ("SectorCount", 8)]
    finally:
        p.close()


def test_stopped_heartbeats_but_answers_no_sdo_and_sends_no_tpdo(pair: Pair) -> None:
    """STOPPED: heartbeat 0x04, SDO requests unanswered (CiA 301; remove the state check
    in _on_sdo_request and the read succeeds), no TPDO; start again and all work."""
    pair.device.start()
    pair.master.sdo[0x1017].raw = 10
    pair.operational()
    pair.device.update(measurement(), RUNNING)
    pair.nmt("STOPPED")
    before = len(pair.frames[HEARTBEAT])
    assert pair.wait_frames(HEARTBEAT, before + 2)[-1][0] == STOPPED
    timeout, pair.master.sdo.RESPONSE_TIMEOUT = pair.master.sdo.RESPONSE_TIMEOUT, 0.2
    with pytest.raises(SdoCommunicationError):
        _ = pair.master.sdo[0x1017].raw
    pair.master.sdo.RESPONSE_TIMEOUT = timeout
    pair.master_net.sync.transmit()
    assert pair.master.tpdo[3].wait_for_reception(timeout=0.2) is None
    pair.nmt("OPERATIONAL")
    pair.device.update(measurement(), RUNNING)
    sync_and_read(pair, 3)
    assert pair.master.sdo[0x1017].raw == 10


def test_commands_and_broadcast(pair: Pair) -> None:
    """Start, enter pre-operational, stop and start addressed to all nodes (node ID 0;
    accept only our own ID in NmtSlave.on_command and this fails); unknown command
    specifiers, other nodes' commands and short frames change nothing."""
    pair.device.start()
    for command, state in ((0x01, "OPERATIONAL"), (0x80, "PRE-OPERATIONAL"),
                           (0x02, "STOPPED"), (0x01, "OPERATIONAL")):
        pair.master_net.send_message(0x000, bytes([command, 0]))
        deadline = time.monotonic() + 2.0
        while pair.device.nmt_state != state:
            assert time.monotonic() < deadline, f"0x{command:02X}: {pair.device.nmt_state}"
            time.sleep(0.005)
    pair.master_net.send_message(0x000, bytes([0x7E, NODE_ID]))
    pair.master_net.send_message(0x000, bytes([0x80, NODE_ID + 1]))  # another node
    pair.master_net.send_message(0x000, bytes([0x02]))  # too short: ignored
    time.sleep(0.1)
    assert pair.device.nmt_state == "OPERATIONAL"
    assert pair.device.nmt.boot_ups == 1


def test_emcy_only_in_pre_operational_and_operational(pair: Pair) -> None:
    """No EMCY in STOPPED (CiA 301; remove the state check in EmcyService._send and this
    fails); the error register still records it."""
    pair.device.start()
    pair.nmt("STOPPED")
    pair.device.emcy_camera_lost()
    assert pair.master.emcy.wait(0xFF01, timeout=0.2) is None
    pair.nmt("PRE-OPERATIONAL")
    assert pair.master.sdo[0x1001].raw & 0x80
    pair.device.emcy_laser_fault()
    assert pair.master.emcy.wait(0xFF02, timeout=1.0) is not None


def test_code_length_is_refused_in_operational(pair: Pair) -> None:
    """A write in OPERATIONAL to an entry writable in PRE-OPERATIONAL only: 0x08000022
    (make CodeLength writable in LIVE states and this fails)."""
    pair.device.start()
    pair.operational()
    with pytest.raises(SdoAbortedError) as info:
        pair.master.sdo["Configuration"]["CodeLength"].raw = 8
    assert info.value.code == 0x08000022
