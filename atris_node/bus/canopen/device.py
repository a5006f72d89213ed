"""CANopen mode: the same sector distances, nearest obstacle and status as a CANopen slave.

A canopen ``LocalNode`` built from the shipped ``atris.eds`` gives the SDO server, NMT
slave and EMCY producer. The heartbeat (period from 0x1017) is sent by this class's own
timer thread, not by canopen's ``send_periodic`` task, which dies on the first failed
send and lingers a period after stop. canopen does not send TPDOs by itself either, so
this class does: on each SYNC (transmission types 1..240, every n-th SYNC) and on
each TPDO's event timer (types 254/255), and only in OPERATIONAL. PDO parameters written
over SDO are re-read (``tpdo.read(from_od=False)``) before the next transmission. SDO
writes to the configuration (0x2000) are checked against the EDS limits and the rules
below, aborted with the CiA 301 codes, and handed to ``on_config(name, value)``.

The values a TPDO carries are composed when it is sent, from the newest measurement and
status the loop handed over: distances older than MaxDataAge (0x2000) go out invalid, and
when the loop has not reported progress (:meth:`CanopenDevice.update`,
:meth:`CanopenDevice.heartbeat`) for that long the status says FAULT with DEADLINE_MISS.
:meth:`CanopenDevice.stop` sends the enabled TPDOs once more with state STOPPED and
invalid distances.
"""

from __future__ import annotations

import importlib.resources
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError

from atris_node.bus.can import payloads
from atris_node.errors import AtrisError, NodeFaultError
from atris_node.types import Measurement, UnitState, UnitStatus

logger = logging.getLogger(__name__)

EDS_NAME = "atris.eds"
CONFIG_INDEX = 0x2000
SECTOR_DISTANCE_INDEX, SECTOR_CONFIDENCE_INDEX = 0x2100, 0x2101
NEAREST_INDEX, STATUS_INDEX = 0x2110, 0x2120
TPDO_COMM_INDEXES = range(0x1800, 0x1804)
TPDO_MAP_INDEXES = range(0x1A00, 0x1A04)
SYNC_COB_ID = 0x80
# CiA 301 SDO abort codes
ABORT_RANGE = 0x06090030
ABORT_TOO_HIGH = 0x06090031
ABORT_TOO_LOW = 0x06090032
ABORT_STATE = 0x08000022
ABORT_STORE = 0x08000020
# EMCY error codes: manufacturer-specific camera / laser, CiA 301 bus-off recovery
EMCY_CAMERA_LOST = 0xFF01
EMCY_LASER_FAULT = 0xFF02
EMCY_BUS_OFF_RECOVERED = 0x8140
ERROR_REGISTER_GENERIC, ERROR_REGISTER_COMMUNICATION = 0x01, 0x10
ERROR_REGISTER_MANUFACTURER = 0x80
NOT_AVAILABLE_I16, NOT_AVAILABLE_U16 = -32768, 0xFFFF
ConfigCallback = Callable[[str, int], None]
#: NMT state name -> heartbeat byte
NMT_STATE_CODES = {name: code for code, name in canopen.nmt.NMT_STATES.items()}


def eds_text() -> str:
    """Text of the shipped EDS (package data ``atris_node/bus/canopen/atris.eds``)."""
    return importlib.resources.files("atris_node.bus.canopen").joinpath(EDS_NAME).read_text("utf-8")


def eds_path() -> Path:
    """File system path of the shipped EDS (canopen's importer wants a file)."""
    return Path(str(importlib.resources.files("atris_node.bus.canopen").joinpath(EDS_NAME)))


def check_config_value(name: str, od: ODVariable, value: int) -> None:
    """Raise SdoAbortedError if ``value`` is outside the EDS limits or the rules of ``name``."""
    if od.min is not None and value < od.min:
        raise SdoAbortedError(ABORT_TOO_LOW)
    if od.max is not None and value > od.max:
        raise SdoAbortedError(ABORT_TOO_HIGH)
    if name == "CodeLength" and value & (value - 1):
        raise SdoAbortedError(ABORT_RANGE)  # code lengths are powers of two


class CanopenDevice:
    """The unit as a CANopen slave on ``network`` with node ID ``node_id`` (1..127).

    Args:
        network: a connected canopen Network (its bus and Notifier belong to the owner).
        node_id: CANopen node ID.
        on_config: called as ``on_config(name, value)`` for each accepted SDO write to
            the configuration object 0x2000 (e.g. ``("SectorCount", 8)``); an AtrisError
            raised there aborts the write with 0x08000020.
        clock: monotonic clock of ``Measurement.newest_time_s``, seconds.
    """

    def __init__(self, network: canopen.Network, node_id: int, *,
                 on_config: ConfigCallback | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.network, self.node_id, self.on_config, self.clock = network, node_id, on_config, clock
        self.node = canopen.LocalNode(node_id, str(eds_path()))
        # the heartbeat is ours (see the module docstring): drop canopen's 0x1017 handler
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_write_callback(self._on_write)
        self._last_heartbeat_s = -math.inf
        self._sync_count = 0
        self._pdo_dirty = True
        self._bus_trouble = False
        self._error_register = 0
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._timer: threading.Thread | None = None
        self._fatal: BaseException | None = None
        self._last_event_s: dict[int, float] = {}
        self.send_errors = 0  # TPDOs and heartbeats the bus refused
        self.frames_sent = 0  # and those it took
        self._measurement: Measurement | None = None
        self._status = UnitStatus(UnitState.INIT, 0, 0, 0.0, 0)
        self._progress_s: float | None = None  # the owner's loop last made progress

    # -- lifecycle -----------------------------------------------------------------------
    def start(self) -> None:
        """Join the network, send boot-up, enter PRE-OPERATIONAL with heartbeat."""
        if self._timer is not None:
            return
        self.network.add_node(self.node)
        self.network.subscribe(SYNC_COB_ID, self._on_sync)
        self.node.nmt.state = "INITIALISING"  # sends the boot-up message
        # enter PRE-OPERATIONAL without NmtSlave starting its own heartbeat task
        canopen.nmt.NmtBase.send_command(self.node.nmt, canopen.nmt.NMT_COMMANDS[
            "PRE-OPERATIONAL"])
        self._timer = threading.Thread(target=self._run_timer, daemon=True,
                                       name=f"atris-canopen-{self.node_id}")
        self._timer.start()

    def stop(self) -> None:
        """Stop the event timer and heartbeat, send the enabled TPDOs once with state
        STOPPED and invalid distances (in OPERATIONAL), and leave the network; idempotent."""
        self._stopping.set()
        if self._timer is None:
            return
        self._timer.join()
        self._timer = None
        with self._lock:
            self._measurement, self._progress_s = None, None
            self._status = replace(self._status, state=UnitState.STOPPED)
        if self.node.nmt.state == "OPERATIONAL":
            self._transmit(self._tpdos())
        self.network.unsubscribe(SYNC_COB_ID, self._on_sync)
        self.node.remove_network()
        self.network.nodes.pop(self.node_id, None)

    def check(self) -> None:
        """Re-raise, as NodeFaultError, an error that stopped the event-timer thread."""
        if self._fatal is not None:
            raise NodeFaultError(f"CANopen device {self.node_id} failed: "
                                 f"{self._fatal!r}") from self._fatal

    @property
    def nmt_state(self) -> str:
        """NMT state as canopen names it (``OPERATIONAL``, ``PRE-OPERATIONAL``...)."""
        return str(self.node.nmt.state)

    def config(self, name: str) -> int:
        """Current value of configuration entry ``name`` of object 0x2000."""
        od = self._od(CONFIG_INDEX, name)
        return int(od.decode_raw(self.node.get_data(CONFIG_INDEX, od.subindex)))

    # -- values --------------------------------------------------------------------------
    def update(self, measurement: Measurement | None, status: UnitStatus) -> None:
        """Hand over the newest values (the loop made progress); they are written into the
        object dictionary now and again, aged, before each TPDO is sent."""
        with self._lock:
            self._measurement, self._status = measurement, status
            self._progress_s = self.clock()
            self._write_values(self._progress_s)

    def heartbeat(self) -> None:
        """The owner's measurement loop made progress (a sub-frame handled) without new
        values; call it from that loop, never another thread."""
        self._progress_s = self.clock()

    def _write_values(self, now: float) -> None:
        """The newest values as they may go out at ``now`` into the object dictionary
        (the lock held): aged, invalid when stale, FAULT when the loop stopped reporting."""
        measurement = self._measurement
        max_age_s = self.config("MaxDataAge_ms") / 1000.0
        status = payloads.alive_status(self._status, self._progress_s, now, max_age_s)
        age = None if measurement is None else now - measurement.newest_time_s
        usable = payloads.data_usable(measurement, status, age, max_age_s)
        self._write_status(status, age)
        self._write_sectors(measurement, usable)
        self._write_nearest(measurement, usable)

    def _od(self, index: int, subindex: int | str) -> ODVariable:
        entry = self.node.object_dictionary[index]
        return entry if isinstance(entry, ODVariable) else entry[subindex]

    def _set(self, index: int, subindex: int, value: int) -> None:
        """Store ``value`` in the object dictionary (not an SDO write: no checks)."""
        od = self._od(index, subindex)
        self.node.data_store.setdefault(index, {})[od.subindex] = od.encode_raw(value)

    def _write_status(self, status: UnitStatus, age: float | None) -> None:
        age_ms = NOT_AVAILABLE_U16 if age is None or math.isnan(age) else payloads.scaled(
            max(age, 0.0), 0.001, 0, NOT_AVAILABLE_U16 - 1)
        values = [int(status.state), max(0, min(255, status.code_row)),
                  max(0, min(255, status.code_length)),
                  payloads.scaled(status.chip_rate_hz, 0.1, 0, 0xFFFF),
                  status.measurement_counter % 0x10000, int(status.faults) & 0xFF, age_ms,
                  max(0, min(255, status.dropped_sub_frames)),
                  payloads.scaled(status.ambient_level * 100.0, 0.5, 0, 200),
                  payloads.scaled(status.saturated_fraction * 100.0, 0.5, 0, 200),
                  payloads.scaled(status.foreign_code_energy * 100.0, 1.0, 0, 255)]
        for subindex, value in enumerate(values, 1):
            self._set(STATUS_INDEX, subindex, value)

    def _write_sectors(self, measurement: Measurement | None, usable: bool) -> None:
        count = self.config("SectorCount")
        sectors = measurement.sectors if measurement is not None else ()
        slots = payloads.sector_slots(sectors, count, usable) + [None] * (16 - count)
        for i, sector in enumerate(slots):
            self._set(SECTOR_DISTANCE_INDEX, i + 1, payloads.distance_raw(sector))
            self._set(SECTOR_CONFIDENCE_INDEX, i + 1, payloads.confidence_raw(sector))

    def _write_nearest(self, measurement: Measurement | None, usable: bool) -> None:
        raw = payloads.nearest_signals(measurement, usable)
        valid = bool(raw["Valid"]) and measurement is not None
        nearest = measurement.nearest if measurement is not None and valid else None
        values = [raw["Distance"], NOT_AVAILABLE_I16, NOT_AVAILABLE_I16, NOT_AVAILABLE_U16,
                  int(valid)]
        if nearest is not None and measurement is not None:
            values[1] = payloads.bearing_raw(nearest.bearing_rad)
            values[2] = _optional(measurement.closing_speed_mps, 0.01, -32767, 32767,
                                  NOT_AVAILABLE_I16)
            ttc = measurement.time_to_collision_s
            values[3] = _optional(ttc if ttc is None or ttc >= 0 else None, 0.01, 0, 0xFFFE,
                                  NOT_AVAILABLE_U16)
        for subindex, value in enumerate(values, 1):
            self._set(NEAREST_INDEX, subindex, value)

    # -- EMCY ----------------------------------------------------------------------------
    def emcy_camera_lost(self) -> None:
        """EMCY 0xFF01: the camera stopped delivering sub-frames."""
        self._emcy(EMCY_CAMERA_LOST, ERROR_REGISTER_GENERIC | ERROR_REGISTER_MANUFACTURER)

    def emcy_laser_fault(self) -> None:
        """EMCY 0xFF02: projector fault."""
        self._emcy(EMCY_LASER_FAULT, ERROR_REGISTER_GENERIC | ERROR_REGISTER_MANUFACTURER)

    def emcy_bus_off_recovered(self) -> None:
        """EMCY 0x8140: recovered from bus-off."""
        self._emcy(EMCY_BUS_OFF_RECOVERED, ERROR_REGISTER_COMMUNICATION)

    def emcy_reset(self) -> None:
        """EMCY 0x0000: all errors cleared."""
        self._error_register = 0
        self._set(0x1001, 0, 0)
        self.node.emcy.reset(0)

    def _emcy(self, code: int, register_bits: int) -> None:
        self._error_register |= register_bits
        self._set(0x1001, 0, self._error_register)
        logger.warning("CANopen EMCY 0x%04X (error register 0x%02X)", code, self._error_register)
        self.node.emcy.send(code, self._error_register)

    # -- SDO writes ----------------------------------------------------------------------
    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes,
                  **_: Any) -> None:
        if index in TPDO_COMM_INDEXES or index in TPDO_MAP_INDEXES:
            self._pdo_dirty = True
        if index != CONFIG_INDEX or subindex == 0:
            return
        if self.node.nmt.state == "OPERATIONAL":
            raise SdoAbortedError(ABORT_STATE)
        value = int(od.decode_raw(data))
        check_config_value(od.name, od, value)
        self._notify_config(od.name, value)

    def _notify_config(self, name: str, value: int) -> None:
        logger.info("CANopen configuration %s = %d", name, value)
        if self.on_config is None:
            return
        try:
            self.on_config(name, value)
        except AtrisError as exc:
            logger.error("configuration %s = %d refused: %s", name, value, exc)
            raise SdoAbortedError(ABORT_STORE) from exc

    # -- TPDO transmission -----------------------------------------------------------------
    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        try:
            self._sync_count += 1
            if self.node.nmt.state != "OPERATIONAL":
                return
            self._transmit([pdo for pdo in self._tpdos()
                            if pdo.trans_type and pdo.trans_type <= 240
                            and self._sync_count % pdo.trans_type == 0])
        except Exception:
            logger.exception("CANopen SYNC handling failed")

    def _tpdos(self) -> list[Any]:
        with self._lock:
            if self._pdo_dirty:
                self._pdo_dirty = False
                self.node.tpdo.read(from_od=False)
            maps: Any = self.node.tpdo.map
            return [pdo for pdo in maps.values() if pdo.enabled]

    def _transmit(self, pdos: list[Any]) -> None:
        """Send ``pdos`` in order, their values composed once, now (aged, see update)."""
        if not pdos:
            return
        with self._lock:
            self._write_values(self.clock())
            frames = []
            for pdo in pdos:
                for variable in pdo.map:
                    variable.set_data(self.node.get_data(variable.index, variable.subindex))
                frames.append((pdo.cob_id, bytes(pdo.data)))
        for cob_id, data in frames:
            self._send_tpdo(cob_id, data)

    def _send_tpdo(self, cob_id: int, data: bytes) -> None:
        try:
            self.network.send_message(cob_id, data)
        except can.CanError as exc:
            logger.error("TPDO 0x%X not sent: %s", cob_id, exc)
            self.send_errors += 1
            self._bus_trouble = True
            return
        self.frames_sent += 1
        if self._bus_trouble:
            self._bus_trouble = False
            self.emcy_bus_off_recovered()

    def _run_timer(self) -> None:
        try:
            while not self._stopping.wait(0.005):
                now = self.clock()
                self._heartbeat_tick(now)
                self._event_tick(now)
        except Exception as exc:
            logger.exception("CANopen event timer of node %d stopped", self.node_id)
            self._fatal = exc

    def _heartbeat_tick(self, now: float) -> None:
        period_ms = int.from_bytes(self.node.get_data(0x1017, 0), "little")
        if not period_ms or now - self._last_heartbeat_s < period_ms / 1000.0:
            return
        self._last_heartbeat_s = now
        try:
            self.network.send_message(0x700 + self.node_id, bytes([NMT_STATE_CODES.get(
                self.nmt_state, 0)]))
        except can.CanError as exc:
            logger.error("heartbeat of node %d not sent: %s", self.node_id, exc)
            self.send_errors += 1

    def _event_tick(self, now: float) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        due = []
        for pdo in self._tpdos():
            if pdo.trans_type is None or pdo.trans_type < 254 or not pdo.event_timer:
                continue
            last = self._last_event_s.get(pdo.cob_id, -math.inf)
            if now - last >= pdo.event_timer / 1000.0:
                self._last_event_s[pdo.cob_id] = now
                due.append(pdo)
        self._transmit(due)


def _optional(value: float | None, scale: float, lo: int, hi: int, missing: int) -> int:
    if value is None or math.isnan(value):
        return missing
    return payloads.scaled(value, scale, lo, hi)
