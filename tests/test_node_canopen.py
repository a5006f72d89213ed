"""The node in CANopen mode: a canopen master from the shipped EDS starts it with NMT,
receives its TPDOs on SYNC, and gets an EMCY when the camera is lost."""

from __future__ import annotations

import time
import uuid
from typing import Any

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError

from atris_node import config as cfg
from atris_node.bus.canopen.device import eds_path
from atris_node.node.unit import Unit
from atris_node.testing.faultcamera import CameraFaults, FaultyCamera
from atris_node.types import UnitState
from drivers import Camera, Projector
from drivers import open_backend as open_registry_backend

NODE_ID = 0x22


def opener_with(faults: CameraFaults) -> Any:
    """The first camera gets ``faults``; reconnected ones are healthy."""
    opened: list[Camera] = []

    def opener(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = open_registry_backend(name, **settings)
        wrapped: Camera = camera if opened else FaultyCamera(camera, faults)
        opened.append(wrapped)
        return wrapped, projector
    return opener


def _sync_received(network: canopen.Network, master: canopen.RemoteNode) -> bool:
    network.sync.transmit()
    return master.tpdo[1].wait_for_reception(timeout=0.5) is not None


def step_until(unit: Unit, done: Any, timeout_s: float = 30.0) -> None:
    end = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < end, "timed out"
        unit.step()
        unit.check()


def test_master_starts_unit_and_reads_tpdos_then_emcy_on_camera_loss() -> None:
    channel = f"node-co-{uuid.uuid4().hex}"
    config = cfg.load(environ={}, overrides=[
        "bus.protocol=canopen", f"bus.node_id={NODE_ID}", "code.length=8",
        "negotiation.window_s=0.1"])
    emcy: list[int] = []
    master_net = canopen.Network()
    master_net.connect(interface="virtual", channel=channel)
    master = canopen.RemoteNode(NODE_ID, str(eds_path()))
    master_net.add_node(master)
    master.emcy.add_callback(lambda e: emcy.append(e.code))
    bus = can.Bus(interface="virtual", channel=channel)
    unit = Unit(config, bus, open_backend=opener_with(
        CameraFaults(disconnect_at=600, disconnect_reads=10**6)))
    try:
        unit.configure()
        unit.activate(threaded=False)
        master.nmt.wait_for_heartbeat(timeout=5.0)
        master.tpdo.read(from_od=True)
        master.nmt.state = "OPERATIONAL"
        step_until(unit, lambda: unit.stats.measurements >= 3)
        assert any(_sync_received(master_net, master) for _ in range(5))
        assert master.tpdo[1]["Status.State"].raw == int(UnitState.RUNNING)
        assert master.tpdo[1]["Status.CodeRow"].raw == 2
        step_until(unit, lambda: unit.stats.camera_faults > 0)
        deadline = time.monotonic() + 2.0
        while not emcy and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emcy and emcy[0] == 0xFF01
        assert unit.projector is not None and not unit.projector.is_lit
    finally:
        unit.shutdown()
        bus.shutdown()
        master_net.disconnect()


def test_node_settings_are_the_power_on_values_and_sdo_writes_reach_the_node() -> None:
    """The node's settings read back from 0x2000; a CodeLength written in PRE-OPERATIONAL
    becomes the unit's plan, one above code.max_length is refused with 0x08000020 (skip
    wiring.connect_output and the plan stays N = 8); SYNC moved to 0x081 over 0x1005
    reaches the unit through its bus filters (drop on_sync_id in wiring.make_output and
    no TPDO answers)."""
    channel = f"node-co-{uuid.uuid4().hex}"
    config = cfg.load(environ={}, overrides=[
        "bus.protocol=canopen", f"bus.node_id={NODE_ID}", "code.length=8",
        "code.max_length=16", "negotiation.window_s=0.1", "publish.max_age_s=0.3"])
    master_net = canopen.Network()
    master_net.connect(interface="virtual", channel=channel)
    master = canopen.RemoteNode(NODE_ID, str(eds_path()))
    master_net.add_node(master)
    bus = can.Bus(interface="virtual", channel=channel)
    unit = Unit(config, bus)
    try:
        unit.configure()
        unit.activate(threaded=False)
        master.nmt.wait_for_heartbeat(timeout=5.0)
        assert master.sdo["Configuration"]["CodeLength"].raw == 8
        assert master.sdo["Configuration"]["MaxDataAge_ms"].raw == 300
        assert master.sdo["Configuration"]["SectorCount"].raw == 8
        step_until(unit, lambda: unit.stats.measurements >= 1)
        with pytest.raises(SdoAbortedError) as info:
            master.sdo["Configuration"]["CodeLength"].raw = 32
        assert info.value.code == 0x08000020
        master.sdo["Configuration"]["CodeLength"].raw = 16
        step_until(unit, lambda: unit.negotiator.plan.code_length == 16)
        master.sdo[0x1005].raw = 0x081
        master.tpdo.read(from_od=True)
        master.nmt.state = "OPERATIONAL"
        step_until(unit, lambda: unit.stats.measurements >= 3)
        master_net.send_message(0x081, b"")
        assert master.tpdo[1].wait_for_reception(timeout=1.0) is not None
    finally:
        unit.shutdown()
        bus.shutdown()
        master_net.disconnect()
