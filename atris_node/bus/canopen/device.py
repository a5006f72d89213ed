"""CANopen mode: the same sector distances, nearest obstacle and status as a CANopen slave.

A canopen ``LocalNode`` built from the shipped ``atris.eds`` gives the object dictionary,
the SDO server and the EMCY producer. The NMT state machine and the heartbeat are this
package's (:mod:`~atris_node.bus.canopen.nmt`); no SDO is answered in STOPPED. canopen
does not send TPDOs by itself, so this class does, only in OPERATIONAL: on each SYNC
(COB-ID from 0x1005; transmission type 0 when new values came since, 1..240 every n-th
SYNC) and on each event-driven TPDO's timer (254/255: 0x180x sub 5, else PublishPeriod_ms).
SDO writes are checked before they are stored (:mod:`~atris_node.bus.canopen.pdo`,
:mod:`~atris_node.bus.canopen.configuration`) and take effect at the next transmission.

The values a TPDO carries are composed when it is sent, from the newest measurement and
status the loop handed over: distances older than MaxDataAge (0x2000) go out invalid, and
when the loop has not reported progress (:meth:`CanopenDevice.update`,
:meth:`CanopenDevice.heartbeat`) for that long the status says FAULT with DEADLINE_MISS.
:meth:`CanopenDevice.stop` sends the enabled TPDOs once more with state STOPPED and
invalid distances.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.resources
import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import canopen
from canopen.objectdictionary import ODArray, ODVariable
from canopen.sdo import SdoAbortedError

from atris_node.bus.can import payloads
from atris_node.bus.canopen import configuration, nmt, pdo, values
from atris_node.bus.canopen.emcy import EmcyService
from atris_node.bus.canopen.objects import (
    ABORT_STORE,
    APPLICATION_AREA,
    COMMUNICATION_AREA,
    CONFIG_INDEX,
    EMCY_COB_ID_INDEX,
    HEARTBEAT_TIME,
    NEAREST_INDEX,
    SECTOR_CONFIDENCE_INDEX,
    SECTOR_DISTANCE_INDEX,
    STATUS_INDEX,
    SYNC_COB_ID_INDEX,
    TPDO_COMM_INDEXES,
    TPDO_MAP_INDEXES,
)
from atris_node.bus.canopen.tpdo import TpdoService
from atris_node.errors import AtrisError, NodeFaultError
from atris_node.types import Measurement, UnitState, UnitStatus

logger = logging.getLogger(__name__)

EDS_NAME = "atris.eds"
# EMCY error codes: manufacturer-specific camera / laser, CiA 301 bus-off recovery
EMCY_CAMERA_LOST = 0xFF01
EMCY_LASER_FAULT = 0xFF02
EMCY_BUS_OFF_RECOVERED = 0x8140
ERROR_REGISTER_GENERIC, ERROR_REGISTER_COMMUNICATION = 0x01, 0x10
ERROR_REGISTER_MANUFACTURER = 0x80
ABORT_NO_SUBINDEX = 0x06090011
SDO_INITIATE_UPLOAD = 0x40  # client command specifier 2, in bits 5..7
PROCESS_INDEXES = (SECTOR_DISTANCE_INDEX, SECTOR_CONFIDENCE_INDEX, NEAREST_INDEX, STATUS_INDEX)
ConfigCallback = Callable[[str, int], None]
SyncIdCallback = Callable[[int], None]


def eds_text() -> str:
    """Text of the shipped EDS (package data ``atris_node/bus/canopen/atris.eds``)."""
    return importlib.resources.files("atris_node.bus.canopen").joinpath(EDS_NAME).read_text("utf-8")


def eds_path() -> Path:
    """File system path of the shipped EDS (canopen's importer wants a file)."""
    return Path(str(importlib.resources.files("atris_node.bus.canopen").joinpath(EDS_NAME)))


class CanopenDevice:
    """The unit as a CANopen slave on ``network`` with node ID ``node_id`` (1..127).

    Args:
        network: a connected canopen Network (its bus and Notifier belong to the owner).
        node_id: CANopen node ID.
        settings: power-on values of configuration entries of 0x2000 by name (the node's
            own settings, e.g. ``{"SectorCount": 8}``); the others are the EDS defaults.
            SectorCount is the number of sectors the node measures.
        on_config: called as ``on_config(name, value)`` for each accepted SDO write to
            0x2000 and for each entry an NMT reset node changes back; an AtrisError
            raised there aborts the write with 0x08000020.
        on_sync_id: called with the new SYNC CAN-ID when 0x1005 changes (bus filters).
        clock: monotonic clock of ``Measurement.newest_time_s``, seconds.
    Raises:
        ConfigError: a setting that is no entry of 0x2000 or that it does not accept.
    """

    def __init__(self, network: canopen.Network, node_id: int, *,
                 settings: Mapping[str, int] | None = None,
                 on_config: ConfigCallback | None = None,
                 on_sync_id: SyncIdCallback | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.network, self.node_id, self.on_config, self.clock = network, node_id, on_config, clock
        self.on_sync_id = on_sync_id
        self.node = canopen.LocalNode(node_id, str(eds_path()))
        self.power_on = configuration.power_on_values(
            self.node.object_dictionary[CONFIG_INDEX], settings or {})
        self.nmt = nmt.NmtSlave(network, node_id, heartbeat_ms=self._heartbeat_ms,
                                reset_communication=self._reset_communication,
                                reset_application=self._reset_application)
        self._hook_services()
        self._lock = threading.RLock()
        self.tpdo = TpdoService(self.node, network, lock=self._lock,
                                compose=lambda: self._write_values(self.clock()),
                                publish_period_ms=lambda: self.config("PublishPeriod_ms"),
                                on_recovered=self.emcy_bus_off_recovered)
        self._sync_id: int | None = None
        self.emcy = EmcyService(self.node, lambda: self.nmt.state)
        self._stopping = threading.Event()
        self._timer: threading.Thread | None = None
        self._fatal: BaseException | None = None
        self._measurement: Measurement | None = None
        self._status = UnitStatus(UnitState.INIT, 0, 0, 0.0, 0)
        self._progress_s: float | None = None  # the owner's loop last made progress
        #: the owner's check of the handed status at send time (as ``Publisher``'s)
        self.status_at_send: Callable[[UnitStatus], UnitStatus] = payloads.unchanged
        self._store_power_on()

    def _hook_services(self) -> None:
        """Our NMT instead of canopen's NmtSlave (no heartbeat task of its own, which dies
        on the first failed send), SDO requests through the NMT gate, our write and read
        checks. Instance attributes, so ``LocalNode.associate_network`` subscribes them."""
        node: Any = self.node
        node._write_callbacks.remove(node.nmt.on_write)
        node.nmt.on_command = self.nmt.on_command
        node.sdo.on_request = functools.partial(self._on_sdo_request, node.sdo.on_request)
        node.add_write_callback(self._on_write)
        node.add_read_callback(self._on_read)

    # -- lifecycle -----------------------------------------------------------------------
    def start(self) -> None:
        """Join the network, boot (boot-up message), PRE-OPERATIONAL with heartbeat."""
        if self._timer is not None:
            return
        self._stopping.clear()
        self.network.add_node(self.node)
        self.nmt.boot()
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
        if self.nmt.state == nmt.OPERATIONAL:
            self.tpdo.transmit(self.tpdo.enabled())
        self._subscribe_sync(None)
        self.node.remove_network()
        self.network.nodes.pop(self.node_id, None)

    def check(self) -> None:
        """Re-raise, as NodeFaultError, an error that stopped the event-timer thread."""
        if self._fatal is not None:
            raise NodeFaultError(f"CANopen device {self.node_id} failed: "
                                 f"{self._fatal!r}") from self._fatal

    @property
    def send_errors(self) -> int:
        """TPDOs, heartbeats and EMCYs the bus refused."""
        return self.tpdo.send_errors + self.nmt.send_errors + self.emcy.send_errors

    @property
    def frames_sent(self) -> int:
        """TPDOs the bus took."""
        return self.tpdo.frames_sent

    @property
    def nmt_state(self) -> str:
        """NMT state as canopen names it (``OPERATIONAL``, ``PRE-OPERATIONAL``...)."""
        return self.nmt.state

    def config(self, name: str) -> int:
        """Current value of configuration entry ``name`` of object 0x2000."""
        return pdo.raw(self.node, CONFIG_INDEX, self._od(CONFIG_INDEX, name).subindex)

    # -- values --------------------------------------------------------------------------
    def update(self, measurement: Measurement | None, status: UnitStatus) -> None:
        """Hand over the newest values (the loop made progress); they are written into the
        object dictionary now and again, aged, before each TPDO is sent."""
        with self._lock:
            self._measurement, self._status = measurement, status
            self._progress_s = self.clock()
            self.tpdo.updates += 1
            self._write_values(self._progress_s)

    def heartbeat(self) -> None:
        """The owner's measurement loop made progress (a sub-frame handled) without new
        values; call it from that loop, never another thread."""
        self._progress_s = self.clock()

    def _write_values(self, now: float) -> None:
        """The newest values as they may go out at ``now`` into the object dictionary
        (the lock held): aged, invalid when stale, FAULT when the loop stopped reporting,
        the owner's check at send time (the code still owned), the configuration (0x2000)
        in force now applied."""
        max_age_s = self.config("MaxDataAge_ms") / 1000.0
        status = payloads.alive_status(self.status_at_send(self._status), self._progress_s,
                                       now, max_age_s)
        measurement = self._measurement
        if measurement is not None:
            measurement = values.confident(measurement, self.config("MinConfidence_pct"))
        age = None if measurement is None else now - measurement.newest_time_s
        usable = payloads.data_usable(measurement, status, age, max_age_s)
        self._set_all(STATUS_INDEX, values.status_values(status, age))
        distances, confidences = values.sector_values(measurement, usable,
                                                      self.config("SectorCount"))
        self._set_all(SECTOR_DISTANCE_INDEX, distances)
        self._set_all(SECTOR_CONFIDENCE_INDEX, confidences)
        self._set_all(NEAREST_INDEX, values.nearest_values(
            measurement, usable, self.config("WarningDistance_mm")))

    def _od(self, index: int, subindex: int | str) -> ODVariable:
        entry = self.node.object_dictionary[index]
        return entry if isinstance(entry, ODVariable) else entry[subindex]

    def _set(self, index: int, subindex: int, value: int) -> None:
        """Store ``value`` in the object dictionary (not an SDO write: no checks)."""
        od = self._od(index, subindex)
        self.node.data_store.setdefault(index, {})[od.subindex] = od.encode_raw(value)

    def _set_all(self, index: int, raw_values: list[int]) -> None:
        for subindex, value in enumerate(raw_values, 1):
            self._set(index, subindex, value)

    # -- EMCY ----------------------------------------------------------------------------
    def emcy_camera_lost(self) -> None:
        """EMCY 0xFF01: the camera stopped delivering sub-frames."""
        self.emcy.error(EMCY_CAMERA_LOST, ERROR_REGISTER_GENERIC | ERROR_REGISTER_MANUFACTURER)

    def emcy_laser_fault(self) -> None:
        """EMCY 0xFF02: projector fault."""
        self.emcy.error(EMCY_LASER_FAULT, ERROR_REGISTER_GENERIC | ERROR_REGISTER_MANUFACTURER)

    def emcy_bus_off_recovered(self) -> None:
        """EMCY 0x8140: recovered from bus-off."""
        self.emcy.error(EMCY_BUS_OFF_RECOVERED, ERROR_REGISTER_COMMUNICATION)

    def emcy_reset(self) -> None:
        """EMCY 0x0000: all errors cleared."""
        self.emcy.reset()

    # -- SDO -----------------------------------------------------------------------------
    def _on_sdo_request(self, serve: Callable[[int, bytearray, float], None], can_id: int,
                        data: bytearray, timestamp: float) -> None:
        """An SDO request, served unless STOPPED (CiA 301: no SDO there); an upload of a
        process value reads it as a TPDO sent now would carry it (aged)."""
        if self.nmt.state not in configuration.LIVE:
            return
        if len(data) >= 3 and data[0] & 0xE0 == SDO_INITIATE_UPLOAD and int.from_bytes(
                data[1:3], "little") in PROCESS_INDEXES:
            with self._lock:
                self._write_values(self.clock())
        serve(can_id, data, timestamp)

    def _on_read(self, index: int, subindex: int, od: ODVariable, **_: Any) -> None:
        """canopen's arrays answer any sub-index; ours serve only those in the EDS."""
        parent = self.node.object_dictionary[index]
        if isinstance(parent, ODArray) and subindex not in parent.subindices:
            raise SdoAbortedError(ABORT_NO_SUBINDEX)

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes,
                  **_: Any) -> None:
        """Check an SDO write before canopen stores it, and apply it (an abort stops it)."""
        self._on_read(index, subindex, od)
        value = int(od.decode_raw(data))
        if index in TPDO_COMM_INDEXES:
            pdo.check_comm_write(self.node, index, subindex, value)
        elif index in TPDO_MAP_INDEXES:
            pdo.check_map_write(self.node, index, subindex, value)
        elif index == SYNC_COB_ID_INDEX:
            pdo.check_sync_cob_id(value)
            self._subscribe_sync(value)
        elif index == EMCY_COB_ID_INDEX:
            pdo.check_cob_id(pdo.raw(self.node, index, 0), value, pdo.NOT_VALID)
            self.emcy.set_cob_id(value)
        elif index == CONFIG_INDEX and subindex:
            configuration.check_write(od, value, self.nmt.state, self.power_on)
            self._notify_config(od.name, value)
        self.tpdo.dirty = True

    def _notify_config(self, name: str, value: int) -> None:
        logger.info("CANopen configuration %s = %d", name, value)
        if self.on_config is None:
            return
        try:
            self.on_config(name, value)
        except AtrisError as exc:
            logger.error("configuration %s = %d refused: %s", name, value, exc)
            raise SdoAbortedError(ABORT_STORE) from exc

    def _subscribe_sync(self, cob_id: int | None) -> None:
        """Consume SYNC on ``cob_id`` (its CAN-ID) from now on; None: not at all."""
        can_id = None if cob_id is None else cob_id & pdo.CAN_ID_MASK
        if can_id == self._sync_id:
            return
        if self._sync_id is not None:
            self.network.unsubscribe(self._sync_id, self._on_sync)
        self._sync_id = can_id
        if can_id is not None:
            self.network.subscribe(can_id, self._on_sync)
            if self.on_sync_id is not None:
                self.on_sync_id(can_id)

    def _heartbeat_ms(self) -> int:
        return pdo.raw(self.node, HEARTBEAT_TIME, 0)

    # -- NMT resets ----------------------------------------------------------------------
    def _reset_communication(self) -> None:
        """The communication area (0x1000-0x1FFF) back to its power-on values."""
        with self._lock:
            self._restore(COMMUNICATION_AREA)
            self._subscribe_sync(pdo.raw(self.node, SYNC_COB_ID_INDEX, 0))
            self.emcy.set_cob_id(pdo.raw(self.node, EMCY_COB_ID_INDEX, 0))
            self.tpdo.reset()

    def _reset_application(self) -> None:
        """Configuration 0x2000 back to the power-on values; ``on_config`` hears of each
        entry that changes (its refusal is logged: the reset goes on)."""
        with self._lock:
            changed = {name: value for name, value in self.power_on.items()
                       if self.config(name) != value}
            self._restore(APPLICATION_AREA)
            self._store_power_on()
        for name, value in changed.items():
            with contextlib.suppress(SdoAbortedError):  # logged by _notify_config
                self._notify_config(name, value)

    def _store_power_on(self) -> None:
        for name, value in self.power_on.items():
            self._set(CONFIG_INDEX, self._od(CONFIG_INDEX, name).subindex, value)

    def _restore(self, area: range) -> None:
        """Forget what was written to the writable objects in ``area`` (the lock held)."""
        for index in [i for i in self.node.data_store if i in area]:
            stored = self.node.data_store[index]
            for subindex in [s for s in stored if self._od(index, s).writable]:
                del stored[subindex]

    # -- TPDO transmission -----------------------------------------------------------------
    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        try:
            if self.nmt.state == nmt.OPERATIONAL:
                self.tpdo.on_sync()
        except Exception:
            logger.exception("CANopen SYNC handling failed")

    def _run_timer(self) -> None:
        try:
            while not self._stopping.wait(0.005):
                now = self.clock()
                self.nmt.tick(now)
                if self.nmt.state == nmt.OPERATIONAL:
                    self.tpdo.on_time(now)
        except Exception as exc:
            logger.exception("CANopen event timer of node %d stopped", self.node_id)
            self._fatal = exc
