"""A canopen master (RemoteNode from the shipped EDS) and the device on one virtual bus."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable, Mapping

import canopen

from atris_node.bus.canopen.device import CanopenDevice, eds_path
from atris_node.errors import ConfigError
from atris_node.types import Measurement, SectorDistance, SectorState, UnitState, UnitStatus

NODE_ID = 0x21
RUNNING = UnitStatus(UnitState.RUNNING, code_row=3, code_length=16, chip_rate_hz=480.0,
                     measurement_counter=0)


class FakeClock:
    """A monotonic clock the test moves by hand."""

    def __init__(self, now: float = 1000.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


class Pair:
    """A master network and a device network on one virtual channel; ``frames[can_id]``
    records the data of every frame the master hears on the subscribed ``watch`` IDs."""

    def __init__(self, *, clock: Callable[[], float] = time.monotonic,
                 settings: Mapping[str, int] | None = None, watch: tuple[int, ...] = ()) -> None:
        channel = f"co-{uuid.uuid4().hex}"
        self.master_net, self.device_net = canopen.Network(), canopen.Network()
        for network in (self.master_net, self.device_net):
            network.NOTIFIER_CYCLE = 0.02  # quick disconnect: the notifier polls faster
        self.master_net.connect(interface="virtual", channel=channel)
        self.device_net.connect(interface="virtual", channel=channel)
        self.config: list[tuple[str, int]] = []
        self.device = CanopenDevice(self.device_net, NODE_ID, on_config=self._on_config,
                                    clock=clock, settings=settings)
        self.master = canopen.RemoteNode(NODE_ID, str(eds_path()))
        self.master_net.add_node(self.master)
        self.frames: dict[int, list[bytes]] = {can_id: [] for can_id in watch}
        self._arrived = threading.Condition()
        for can_id in watch:
            self.master_net.subscribe(can_id, self._record)

    def _on_config(self, name: str, value: int) -> None:
        if name == "WarningDistance_mm" and value == 1234:
            raise ConfigError("1234 mm is refused by the node")
        self.config.append((name, value))

    def _record(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._arrived:
            self.frames[can_id].append(bytes(data))
            self._arrived.notify_all()

    def wait_frames(self, can_id: int, count: int, timeout: float = 2.0) -> list[bytes]:
        """The frames on ``can_id`` once there are at least ``count`` (AssertionError if
        they do not come)."""
        with self._arrived:
            assert self._arrived.wait_for(lambda: len(self.frames[can_id]) >= count, timeout), \
                f"{len(self.frames[can_id])} of {count} frames on 0x{can_id:X}"
            return list(self.frames[can_id])

    def nmt(self, state: str) -> None:
        """NMT command to the device; returns once the device is in the new state (after
        a reset: once it booted again)."""
        boot_ups = self.device.nmt.boot_ups
        self.master.nmt.state = state
        reset = state in ("RESET", "RESET COMMUNICATION")
        target = "PRE-OPERATIONAL" if reset else state
        deadline = time.monotonic() + 2.0
        while self.device.nmt_state != target or (reset and self.device.nmt.boot_ups == boot_ups):
            assert time.monotonic() < deadline, f"device stays {self.device.nmt_state}"
            time.sleep(0.005)

    def operational(self) -> None:
        """The master's TPDO maps from the EDS, the device OPERATIONAL."""
        self.master.tpdo.read(from_od=True)
        self.nmt("OPERATIONAL")

    def close(self) -> None:
        self.device.stop()
        self.master_net.disconnect()
        self.device_net.disconnect()


def measurement(newest_time_s: float | None = None, confidence: float = 0.5) -> Measurement:
    """Sectors 0..6 valid at 1.0 + 0.5 * i m, sector 7 without a return; nearest sector 0."""
    valid = [SectorDistance(i, 0.0, SectorState.VALID, 1.0 + 0.5 * i, confidence)
             for i in range(7)]
    sectors = (*valid, SectorDistance(7, 0.0, SectorState.NO_RETURN))
    newest = time.monotonic() if newest_time_s is None else newest_time_s
    return Measurement(42, sectors, newest, 9, nearest=sectors[0],
                       closing_speed_mps=0.5, time_to_collision_s=2.0)


def sync_and_read(pair: Pair, number: int, timeout: float = 1.0) -> None:
    """SYNC; TPDO ``number`` must arrive."""
    pair.master_net.sync.transmit()
    assert pair.master.tpdo[number].wait_for_reception(timeout=timeout) is not None
