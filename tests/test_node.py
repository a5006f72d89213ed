"""The node: lifecycle, laser safety, faults and recovery, on a real virtual bus with the
simulator as camera and projector."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import can
import pytest
from listened_bus import listened_bus
from strobe_audit import AuditedProjector, audited, unpermitted_light

from atris_node import config as cfg
from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.can.ids import FrameKind, unit_of
from atris_node.errors import FrameDecodeError
from atris_node.node.status import negotiated_status
from atris_node.node.unit import Lifecycle, Unit
from atris_node.testing.faultcamera import CameraFaults, FaultyCamera
from atris_node.types import FaultBits, Measurement, SectorState, UnitState, UnitStatus
from drivers import Camera, Projector
from drivers import open_backend as open_registry_backend

BASE = ["code.length=8", "negotiation.window_s=0.1", "negotiation.reannounce_s=0.5",
        "negotiation.silence_timeout_s=1.5"]


class Frames(can.Listener):
    """Decoded frames of unit 0 as they arrive."""

    def __init__(self) -> None:
        self.codec = FrameCodec()
        self.frames: list[tuple[float, str, dict[str, Any]]] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_extended_id or unit_of(msg.arbitration_id) is None:
            return
        try:
            decoded = self.codec.decode_message(msg)
        except FrameDecodeError:
            return
        kind = unit_of(msg.arbitration_id)[1]  # type: ignore[index]
        self.frames.append((time.monotonic(), kind.suffix, decoded.signals))

    def on_error(self, exc: Exception) -> None:
        raise exc

    def sectors(self, since: float = 0.0) -> list[Any]:
        return [s for t, k, s in self.frames if k == FrameKind.SECTORS.suffix and t >= since]


@pytest.fixture
def bus_pair(request: pytest.FixtureRequest) -> Iterator[tuple[can.BusABC, Frames]]:
    frames = Frames()
    with listened_bus(f"node-{request.node.name}", frames) as tx:
        yield tx, frames


def make_unit(bus: can.BusABC, *extra: str, opener: Any = None) -> Unit:
    return Unit(cfg.load(environ={}, overrides=[*BASE, *extra]), bus, open_backend=opener)


def run_until(unit: Unit, done: Any, timeout_s: float = 20.0) -> None:
    """Step ``unit`` until ``done()`` is true; fail after ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < end, "timed out"
        unit.step()
        unit.check()


def run_steps(unit: Unit, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        unit.step()
        unit.check()


def test_laser_stays_off_until_code_is_owned_then_valid_distances(
        bus_pair: tuple[can.BusABC, Frames]) -> None:
    bus, frames = bus_pair
    """The projector is told to light only while the negotiator's timeline permits it:
    checked on an independent record of the projector calls (``AuditedProjector``), not on
    the node's own counter. Checked by strobing whenever a row is known (``Unit.step``
    taking the chips without asking ``may_strobe``): chips = 1 were told during the claim
    window and the unpermitted-light assert failed."""
    measurements: list[Measurement] = []
    projectors: list[AuditedProjector] = []
    unit = make_unit(bus, opener=audited(open_registry_backend, projectors))
    unit.on_measurement = measurements.append
    unit.configure()
    assert unit.projector is not None and not unit.projector.is_lit
    unit.activate(threaded=False)
    run_until(unit, lambda: len(measurements) >= 10)
    run_steps(unit, 0.3)
    unit.shutdown()
    history = unit.stats.history
    first_lit = next(i for i, (_, lit, _) in enumerate(history) if lit)
    assert first_lit > 0, "the laser was lit before the claim stood its window"
    assert unpermitted_light(projectors, unit.negotiator.timeline) == []
    assert any(chip == 1 for p in projectors for _, chip, _ in p.calls)
    assert measurements, "no measurement after the code was owned"
    # every valid distance in range, and some (one map alone may hold none: noise)
    valid = [s for m in measurements for s in m.sectors if s.state is SectorState.VALID]
    assert valid and all(0.3 <= s.distance_m <= 10.0 for s in valid)
    assert any(isinstance(s["Distance0"], float) for s in frames.sectors())


def test_shutdown_switches_laser_off_and_is_idempotent(
        bus_pair: tuple[can.BusABC, Frames]) -> None:
    bus, _ = bus_pair
    unit = make_unit(bus)
    unit.configure()
    unit.activate(threaded=True)
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline and not (unit.projector and unit.projector.is_lit):
        time.sleep(0.02)
    assert unit.projector is not None and unit.projector.is_lit
    unit.deactivate()
    assert not unit.projector.is_lit and unit.lifecycle == Lifecycle.INACTIVE
    unit.shutdown()
    unit.shutdown()
    assert unit.lifecycle == Lifecycle.FINALIZED and not unit.projector.is_lit


def faulty_opener(faults: CameraFaults, opened: list[Camera]) -> Any:
    """Open the sim backend; the first camera gets ``faults``, reconnects are healthy."""

    def opener(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = open_registry_backend(name, **settings)
        wrapped: Camera = FaultyCamera(camera, faults) if not opened else camera
        opened.append(wrapped)
        return wrapped, projector

    return opener


def test_camera_loss_goes_invalid_laser_off_then_recovers(
        bus_pair: tuple[can.BusABC, Frames]) -> None:
    bus, frames = bus_pair
    opened: list[Camera] = []
    faults = CameraFaults(disconnect_at=400, disconnect_reads=10**6)
    measurements: list[Measurement] = []
    unit = make_unit(bus, opener=faulty_opener(faults, opened))
    unit.on_measurement = measurements.append
    unit.configure()
    unit.activate(threaded=False)
    while unit.stats.camera_faults == 0:
        unit.step()
    assert unit.projector is not None and not unit.projector.is_lit
    assert unit.status().state is UnitState.FAULT
    assert unit.status().faults & FaultBits.CAMERA_LOST
    lost_at = time.monotonic()
    count_before = len(measurements)
    run_until(unit, lambda: len(measurements) > count_before + 5)
    run_steps(unit, 0.3)
    unit.shutdown()
    assert unit.stats.reconnects == 1 and len(opened) == 2
    assert len(measurements) > count_before, "no measurement after reconnection"
    period = float(unit.config["publish.period_s"])
    after_loss = frames.sectors(since=lost_at + period * 1.5)
    assert after_loss and all(not isinstance(v, float) for v in _distances(after_loss[0]))
    assert any(isinstance(v, float) for s in after_loss for v in _distances(s)), (
        "valid distances did not come back after the camera returned")


def _distances(signals: dict[str, Any]) -> list[Any]:
    return [signals["Distance0"], signals["Distance1"]]


@pytest.mark.parametrize("fault", ["wrong_size_at", "wrong_dtype_at"])
def test_bad_sub_frames_are_dropped_not_fatal(bus_pair: tuple[can.BusABC, Frames],
                                               fault: str) -> None:
    """Two bad sub-frames in a row and a third later, once the unit measures (the claim
    window runs on the wall clock, so how many sub-frames it takes depends on the
    machine's speed: the faults are placed after the first measurement)."""
    bus, _ = bus_pair
    faults = CameraFaults()
    opened: list[Camera] = []
    measurements: list[Measurement] = []
    unit = make_unit(bus, opener=faulty_opener(faults, opened))
    unit.on_measurement = measurements.append
    unit.configure()
    unit.activate(threaded=False)
    run_until(unit, lambda: bool(measurements))
    camera = opened[0]
    assert isinstance(camera, FaultyCamera)
    first = camera.reads + 20
    setattr(faults, fault, {first, first + 1, first + 120})
    run_until(unit, lambda: camera.reads > first + 300)
    unit.shutdown()
    assert unit.stats.bad_sub_frames == 3
    last = [e.sequence for e in camera.injected][-1]
    assert last is not None and measurements[-1].newest_sequence > last


class NegotiationView:
    """What ``negotiated_status`` reads of a negotiator."""

    def __init__(self, may_strobe: bool, row: int | None, state: str = "OWNED",
                 code_length: int = 16) -> None:
        self.may_strobe, self.code_row = may_strobe, row
        self.state = type("State", (), {"name": state})()
        self.plan = type("Plan", (), {"code_length": code_length})()


@pytest.mark.parametrize(("view", "state", "row"), [
    (NegotiationView(True, 3), UnitState.RUNNING, 3),  # still owned: as handed over
    (NegotiationView(False, 3, "CLAIMING"), UnitState.NEGOTIATING, 0),  # lost, re-claiming
    (NegotiationView(False, None, "NO_CODE"), UnitState.NO_CODE, 0),  # every code taken
    (NegotiationView(False, None, "CONFLICT"), UnitState.NO_CODE, 0),  # plans disagree
    (NegotiationView(True, 5), UnitState.NEGOTIATING, 0),  # another row, not measured on
    (NegotiationView(True, 3, code_length=32), UnitState.NEGOTIATING, 0),  # another plan
])
def test_a_running_status_goes_out_only_on_the_code_still_owned(
        view: NegotiationView, state: UnitState, row: int) -> None:
    handed = UnitStatus(UnitState.RUNNING, code_row=3, code_length=16, chip_rate_hz=480.0,
                        measurement_counter=7)
    sent = negotiated_status(handed, view)
    assert (sent.state, sent.code_row) == (state, row)
    assert sent.measurement_counter == 7


def test_a_status_that_is_not_running_goes_out_as_handed_over() -> None:
    handed = UnitStatus(UnitState.FAULT, code_row=0, code_length=16, chip_rate_hz=480.0,
                        measurement_counter=0, faults=FaultBits.CAMERA_LOST)
    assert negotiated_status(handed, NegotiationView(False, None, "CLAIMING")) == handed
