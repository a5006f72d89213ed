"""A canopen RemoteNode master (this process) and a unit in CANopen mode (another process).

They share vcan0 with a second unit publishing its DBC frames, as on a vehicle bus. The
master configures the slave over SDO in PRE-OPERATIONAL, starts it, sends SYNC, and reads
the TPDOs back with kernel timestamps; the other unit's frames must stay E2E-clean.
"""

from __future__ import annotations

import struct
from typing import Any

import can
import canopen
import cantools
import pytest
from canopen import SdoAbortedError
from e2e_reference import P01Receiver
from roles import sector_distance_m
from unit_frames import DBC_PATH, check_and_decode, listen
from vcan_support import REPO_ROOT, summary_ms

from atris_node.bus.can.ids import FrameKind, frame_id
from atris_node.types import UnitState

pytestmark = pytest.mark.vcan

EDS_PATH = REPO_ROOT / "atris_node" / "bus" / "canopen" / "atris.eds"
NODE_ID = 0x05
TPDO1, TPDO3, HEARTBEAT = 0x180 + NODE_ID, 0x380 + NODE_ID, 0x700 + NODE_ID
SYNC_PERIOD_S = 0.05
NMT_OPERATIONAL = 0x05
#: MaxDataAge_ms as the EDS sets it by default (the test does not write it)
MAX_DATA_AGE_MS = canopen.import_od(str(EDS_PATH))["Configuration"]["MaxDataAge_ms"].default
#: a distance not available
NOT_AVAILABLE = 0xFFFF


def configure(master: canopen.RemoteNode) -> None:
    """SDO writes in PRE-OPERATIONAL: one refused (N = 12 is no power of two), 4 sectors."""
    with pytest.raises(SdoAbortedError) as refused:
        master.sdo["Configuration"]["CodeLength"].raw = 12
    assert refused.value.code == 0x06090030
    master.sdo["Configuration"]["SectorCount"].raw = 4
    assert master.sdo["Configuration"]["SectorCount"].raw == 4
    assert master.sdo["Manufacturer device name"].raw == "ATRIS"


def tpdo_values(frames: list[can.Message]) -> list[tuple[int, bool, list[int]]]:
    """(measurement counter from TPDO1, whether TPDO1 says its data may be used: state
    RUNNING and data age within MaxDataAge_ms, and sector distances in mm from the next
    TPDO3). The two are composed together on one SYNC (bus/canopen/tpdo.py)."""
    out: list[tuple[int, bool, list[int]]] = []
    status: tuple[int, bool] | None = None
    for msg in frames:
        if msg.arbitration_id == TPDO1:
            state, counter, age_ms = msg.data[0], *struct.unpack_from("<HH", msg.data, 4)
            status = counter, state == UnitState.RUNNING and age_ms <= MAX_DATA_AGE_MS
        elif msg.arbitration_id == TPDO3 and status is not None:
            out.append((*status, list(struct.unpack("<4H", msg.data))))
    return out


def sync_to_tpdo_s(frames: list[can.Message]) -> list[float]:
    """Kernel receive time of each TPDO1 minus that of the SYNC before it, seconds."""
    out, sync_at = [], None
    for msg in frames:
        if msg.arbitration_id == 0x80:
            sync_at = msg.timestamp
        elif msg.arbitration_id == TPDO1 and sync_at is not None:
            out.append(msg.timestamp - sync_at)
            sync_at = None
    return out


def unanswered_tpdo1(frames: list[can.Message]) -> int:
    """TPDO1 frames beyond the count of SYNCs before them (0 for a synchronous PDO)."""
    syncs = tpdos = excess = 0
    for msg in frames:
        syncs += msg.arbitration_id == 0x80
        tpdos += msg.arbitration_id == TPDO1
        excess = max(excess, tpdos - syncs)
    return excess


def first_sync(frames: list[can.Message]) -> int:
    """Index of the first SYNC frame (len(frames) when there is none)."""
    return next((i for i, f in enumerate(frames) if f.arbitration_id == 0x80), len(frames))


def test_canopen_master_runs_a_unit_next_to_dbc_frames(spawn: Any, record_property: Any) -> None:
    slave = spawn("canopen_slave", "vcan0", str(NODE_ID), "0.05")
    unit = spawn("publisher", "vcan0", "3", "0.05", "0.1")
    slave.wait_for("ready")
    unit.wait_for("ready")
    network = canopen.Network()
    network.connect(interface="socketcan", channel="vcan0")
    try:
        master = canopen.RemoteNode(NODE_ID, str(EDS_PATH))
        master.sdo.RESPONSE_TIMEOUT = 5.0
        network.add_node(master)
        with can.Bus(interface="socketcan", channel="vcan0") as listener:
            configure(master)
            master.nmt.state = "OPERATIONAL"
            network.sync.start(SYNC_PERIOD_S)
            frames = listen(listener, 3.0)
            network.sync.stop()
    finally:
        network.disconnect()
    assert slave.stop()["nmt_state"] == "OPERATIONAL"
    unit.stop()
    check_canopen_frames(frames, record_property)
    db = cantools.database.load_file(DBC_PATH)
    receivers: dict[int, P01Receiver] = {}
    block = frame_id(3, FrameKind.STATUS), frame_id(3, FrameKind.SECTORS)
    dbc_frames = [f for f in frames if block[0] <= f.arbitration_id <= block[1]]
    assert len(check_and_decode(db, dbc_frames, receivers)) > 100
    record_property("dbc_unit_e2e_timeouts", sum(r.timeouts for r in receivers.values()))


def check_canopen_frames(frames: list[can.Message], record_property: Any) -> None:
    heartbeats = [f for f in frames if f.arbitration_id == HEARTBEAT]
    assert heartbeats and heartbeats[-1].data[0] == NMT_OPERATIONAL
    values = tpdo_values(frames)
    assert len(values) >= 20, f"only {len(values)} SYNC answers in 3 s"
    usable = [v for v in values[1:] if v[1]]
    # a starved slave whose measurements stop coming sends its distances invalid once
    # they are older than MaxDataAge_ms: never the stale numbers
    stale = [v for v in values[1:] if not v[1]]
    record_property("stale_tpdos", f"{len(stale)} of {len(values) - 1}")
    assert all(distances_mm == [NOT_AVAILABLE] * 4 for _, _, distances_mm in stale)
    assert usable, "no TPDO3 with usable data"
    for counter, _, distances_mm in usable:
        expected = [[round(sector_distance_m(i, k) * 1000) for i in range(4)]
                    for k in (counter, counter + 1)]
        assert distances_mm in expected
    # TPDO1 is synchronous: never more of them than SYNCs before them (how soon each
    # answers is the machine's figure: recorded, not asserted)
    assert unanswered_tpdo1(frames[first_sync(frames):]) == 0
    record_property("sync_to_tpdo1", summary_ms(sync_to_tpdo_s(frames)))
