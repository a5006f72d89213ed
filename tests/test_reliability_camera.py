"""Camera faults in a running node: dropped, repeated and exposure-changed sub-frames never
reach a published distance; a disconnect is invalid on the bus within one output period, the
laser is off, and valid distances come back with the camera.

The node runs with the simulator behind :class:`FaultyCamera` on a real virtual bus; the
frames a controller would read are decoded from a second bus on the same channel.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest
from cycle_frames import CycleFrames
from listened_bus import listened_bus

from atris_node import config as cfg
from atris_node.node.unit import Unit
from atris_node.testing.faultcamera import CameraFaults, FaultyCamera, InjectedFault
from atris_node.types import DistortionMap, Measurement
from drivers import Camera, Projector
from drivers import open_backend as open_registry_backend

CODE_LENGTH = 8
BASE = [f"code.length={CODE_LENGTH}", "negotiation.window_s=0.1",
        "negotiation.reannounce_s=0.5", "negotiation.silence_timeout_s=1.5"]


@pytest.fixture
def bus_pair(request: pytest.FixtureRequest) -> Iterator[tuple[can.BusABC, CycleFrames]]:
    frames = CycleFrames()
    with listened_bus(f"reliability-camera-{request.node.name}", frames, 0.01) as tx:
        yield tx, frames


def faulty_unit(bus: can.BusABC, faults: CameraFaults) -> tuple[Unit, list[FaultyCamera]]:
    """A unit whose first camera injects ``faults``; reconnects open a healthy camera."""
    opened: list[FaultyCamera] = []

    def opener(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = open_registry_backend(name, **settings)
        if opened:
            return camera, projector
        opened.append(FaultyCamera(camera, faults))
        return opened[0], projector

    unit = Unit(cfg.load(environ={}, overrides=BASE), bus, open_backend=opener)
    return unit, opened


def step_until(unit: Unit, done: Callable[[], bool], timeout_s: float = 30.0) -> None:
    end = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < end, "timed out"
        unit.step()
        unit.check()


def record_maps(unit: Unit) -> list[DistortionMap]:
    """The distortion map behind every published measurement, in order."""
    maps: list[DistortionMap] = []

    def keep(_: Measurement) -> None:
        assert unit.measure is not None and unit.measure.last_map is not None  # set first
        maps.append(unit.measure.last_map)

    unit.on_measurement = keep
    return maps


def spans(dmap: DistortionMap, fault: InjectedFault) -> bool:
    """True when the map's window holds sub-frames from both sides of ``fault``."""
    assert fault.sequence is not None
    return dmap.first_sequence < fault.sequence <= dmap.last_sequence


def test_dropped_repeated_and_exposure_changed_sub_frames_never_reach_a_distance(
        bus_pair: tuple[can.BusABC, CycleFrames]) -> None:
    """The faults are placed once the unit measures: the claim window runs on the wall
    clock, so the sub-frames it takes depend on the machine's speed (at fixed read
    indices, a faster renderer put the first drops before the unit owned its code)."""
    bus, _ = bus_pair
    faults = CameraFaults(exposure_factor=0.5)
    unit, cameras = faulty_unit(bus, faults)
    maps = record_maps(unit)
    unit.configure()
    unit.activate(threaded=False)
    step_until(unit, lambda: len(maps) >= 2)
    base = cameras[0].reads + 20
    faults.drop_at, faults.repeat_at = {base, base + 1, base + 77}, {base + 120, base + 133}
    faults.exposure_change_at = base + 250
    step_until(unit, lambda: cameras[0].reads > base + 400)
    unit.shutdown()
    injected = cameras[0].injected
    assert [f.kind for f in injected] == ["drop", "drop", "drop", "repeat", "repeat", "exposure"]
    assert [f.kind for f in injected if any(spans(m, f) for m in maps)] == []
    assert all(m.last_sequence - m.first_sequence == CODE_LENGTH - 1 for m in maps)
    assert unit.stats.dropped_sub_frames >= 3  # counted on the next map after each gap
    last_fault = max(f.sequence or 0 for f in injected)
    after = [m for m in maps if m.first_sequence >= last_fault]
    assert len(after) >= 10, "measuring did not resume after the faults"
    before = [m for m in maps if m.last_sequence < injected[0].sequence]  # type: ignore[operator]
    assert before, "no measurement before the first fault: the test proves nothing"


def test_disconnect_is_invalid_within_one_period_laser_off_and_recovers(
        bus_pair: tuple[can.BusABC, CycleFrames]) -> None:
    bus, frames = bus_pair
    faults = CameraFaults(disconnect_reads=10**6)
    unit, cameras = faulty_unit(bus, faults)
    measurements: list[Measurement] = []
    unit.on_measurement = measurements.append
    unit.configure()
    unit.activate(threaded=False)
    step_until(unit, lambda: len(measurements) >= 3)  # the loss comes once it measures
    faults.disconnect_at = cameras[0].reads + 20
    step_until(unit, lambda: unit.stats.camera_faults > 0)
    assert unit.projector is not None and not unit.projector.is_lit
    lost_at = cameras[0].injected[0].time_s
    count = len(measurements)
    step_until(unit, lambda: len(measurements) > count + 3)
    unit.shutdown()
    period_s = float(unit.config["publish.period_s"])
    cycles = frames.cycles
    assert any(c.valid for c in cycles if c.time_s < lost_at), (
        "no valid distance before the disconnect: the test proves nothing")
    first_fault = next(c for c in cycles if c.time_s >= lost_at and c.state != "RUNNING")
    latency_s = first_fault.time_s - lost_at
    print(f"\ndisconnect -> first FAULT cycle: {latency_s * 1e3:.1f} ms "
          f"(publish period {period_s * 1e3:.0f} ms)")
    assert latency_s <= period_s, f"invalid only {latency_s * 1e3:.1f} ms after the loss"
    after = cycles[cycles.index(first_fault):]
    back = next(c for c in after if c.valid)
    assert all(not c.valid for c in after[:after.index(back)])
    assert all(d == "invalid" for c in after[:after.index(back)] for d in c.distances)
    assert back.state == "RUNNING" and back.time_s - lost_at >= RECONNECT_MIN_S
    assert unit.stats.reconnects == 1 and len(measurements) > count
    print(f"disconnect -> valid distances again: {(back.time_s - lost_at) * 1e3:.0f} ms")


#: the first reconnection attempt waits this long, so valid data cannot return sooner
RECONNECT_MIN_S = 0.1
