"""A measurement loop that hangs or dies, and a unit that stops: what goes out on the bus.

The promise: a distance on the bus is fresh, or it is invalid; the state says RUNNING only
while the measurement loop itself reports progress. The loop hangs in a camera read that
never returns (a hung driver) or dies of an unexpected error; a controller on a second bus
object of the channel decodes every cycle (DBC mode), or a canopen master receives the
TPDOs on SYNC (CANopen mode).

Each protection was removed once and the test watched fail, then put back:
- ``payloads.alive_status`` returning ``status`` unchanged: the hung loop's cycles stayed
  RUNNING (DBC test) and the TPDO status stayed RUNNING (CANopen test);
- ``CanopenDevice._transmit`` not re-composing the values (the old cache): the TPDOs
  carried the last distances as valid 0.3 s after they went stale;
- ``Unit._publish_fault`` not called: the first FAULT cycle after the loop died came
  only after MaxDataAge (~0.3 s), not at once;
- ``Publisher.stop`` / ``CanopenDevice.stop`` without the final cycle: the last status
  said RUNNING;
- ``data_usable`` accepting a negative age: the future-stamped measurement was valid.
"""

from __future__ import annotations

import itertools
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import can
import canopen
import pytest
from cycle_frames import Cycle, CycleFrames
from listened_bus import listened_bus

from atris_node import config as cfg
from atris_node.bus.can import payloads
from atris_node.bus.can.config import CAN_ERR_BUSOFF, CAN_ERR_CRTL
from atris_node.bus.canopen.device import CanopenDevice, eds_path
from atris_node.errors import DriverError, NodeFaultError
from atris_node.node.unit import Unit
from atris_node.testing.faultbus import CAN_ERR_FLAG, Faults, FaultyBus
from atris_node.testing.faultcamera import CameraFaults, FaultyCamera
from atris_node.types import (
    FaultBits,
    Measurement,
    SectorDistance,
    SectorState,
    SubFrame,
    UnitState,
    UnitStatus,
)
from drivers import Camera, Projector
from drivers import open_backend as open_registry_backend

BASE = ["code.length=8", "negotiation.window_s=0.1", "negotiation.reannounce_s=0.5",
        "negotiation.silence_timeout_s=1.5"]
NODE_ID = 0x23
#: data[1] of a controller error frame: receive and transmit error-passive (linux/can/error.h)
CAN_ERR_CRTL_PASSIVE = 0x10 | 0x20


class StallingCamera(FaultyCamera):
    """A healthy camera until ``stall`` is set; then a read blocks until ``release`` (a
    hung driver), or raises ``error`` when one is given. ``stalled_at_s`` is the
    ``time.monotonic()`` of the first stalled read."""

    def __init__(self, inner: Camera) -> None:
        super().__init__(inner, CameraFaults())
        self.stall, self.release = threading.Event(), threading.Event()
        self.error: Exception | None = None
        self.stalled_at_s: float | None = None

    def _read(self, timeout_s: float) -> SubFrame:
        if self.stall.is_set():
            if self.stalled_at_s is None:
                self.stalled_at_s = time.monotonic()
            if self.error is not None:
                raise self.error
            self.release.wait()
        return super()._read(timeout_s)


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[tuple[Unit, StallingCamera, CycleFrames]]:
    """A threaded unit with a :class:`StallingCamera` that has published valid distances."""
    frames = CycleFrames()
    cameras: list[StallingCamera] = []

    def opener(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = open_registry_backend(name, **settings)
        cameras.append(StallingCamera(camera))
        return cameras[-1], projector

    with listened_bus(f"reliability-loop-{request.node.name}", frames, 0.01) as bus:
        unit = Unit(cfg.load(environ={}, overrides=BASE), bus, open_backend=opener)
        unit.configure()
        unit.activate(threaded=True)
        try:
            wait_for(lambda: any(c.valid for c in frames.cycles), 60.0)
            yield unit, cameras[0], frames
        finally:
            cameras[0].release.set()
            unit.shutdown()


def wait_for(done: Callable[[], bool], timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


def cycles_after(frames: CycleFrames, start_s: float) -> list[Cycle]:
    return [c for c in list(frames.cycles) if c.time_s > start_s]


def test_a_hung_loop_goes_out_as_fault_with_invalid_distances(
        rig: tuple[Unit, StallingCamera, CycleFrames]) -> None:
    unit, camera, frames = rig
    camera.stall.set()
    wait_for(lambda: camera.stalled_at_s is not None, 5.0)
    assert camera.stalled_at_s is not None
    max_age_s = float(unit.config["publish.max_age_s"])
    period_s = float(unit.config["publish.period_s"])
    time.sleep(max_age_s + 0.6)
    # the last progress was before the stalled read: FAULT within max_age + one cycle
    bound_s = camera.stalled_at_s + max_age_s + 2 * period_s + 0.05
    late = cycles_after(frames, bound_s)
    assert len(late) >= 5
    assert all(c.state == "FAULT" for c in late), [c.state for c in late]
    assert all(c.status["Fault_DeadlineMiss"] == 1 for c in late)
    assert all(d == "invalid" for c in late for d in c.distances)
    first = next(c for c in cycles_after(frames, camera.stalled_at_s) if c.state == "FAULT")
    print(f"\nloop hung -> first FAULT cycle {1e3 * (first.time_s - camera.stalled_at_s):.0f} ms"
          f" (max age {1e3 * max_age_s:.0f} ms)")


def test_a_dead_loop_is_fault_on_the_bus_at_once_and_stays_dark(
        rig: tuple[Unit, StallingCamera, CycleFrames]) -> None:
    unit, camera, frames = rig
    camera.error = RuntimeError("injected driver bug")
    camera.stall.set()
    wait_for(lambda: camera.stalled_at_s is not None, 5.0)
    assert camera.stalled_at_s is not None
    max_age_s = float(unit.config["publish.max_age_s"])
    time.sleep(max_age_s + 0.3)
    after = cycles_after(frames, camera.stalled_at_s)
    first = next(c for c in after if c.state == "FAULT")
    latency_s = first.time_s - camera.stalled_at_s
    print(f"\nloop died -> first FAULT cycle {latency_s * 1e3:.1f} ms")
    assert latency_s < max_age_s / 2
    assert all(c.state == "FAULT" for c in after[after.index(first):])
    assert all(d == "invalid" for c in after[after.index(first):] for d in c.distances)
    assert unit.projector is not None and not unit.projector.is_lit
    with pytest.raises(NodeFaultError, match="injected driver bug"):
        unit.check()


def test_shutdown_ends_with_a_stopped_cycle_of_invalid_distances(
        rig: tuple[Unit, StallingCamera, CycleFrames]) -> None:
    unit, _, frames = rig
    unit.shutdown()
    time.sleep(0.1)
    last = frames.cycles[-1]
    assert last.state == "STOPPED"
    assert last.distances and all(d == "invalid" for d in last.distances)
    assert unit.projector is not None and not unit.projector.is_lit


# ----------------------------------------------------------------------------- CANopen
RUNNING = UnitStatus(UnitState.RUNNING, 3, 16, 480.0, 9)


class CanopenPair:
    """A canopen master and the device on one virtual channel, device OPERATIONAL."""

    def __init__(self, max_age_ms: int) -> None:
        channel = f"co-loop-{uuid.uuid4().hex}"
        self.master_net, self.device_net = canopen.Network(), canopen.Network()
        self.master_net.connect(interface="virtual", channel=channel)
        self.device_net.connect(interface="virtual", channel=channel)
        self.device = CanopenDevice(self.device_net, NODE_ID)
        self.master = canopen.RemoteNode(NODE_ID, str(eds_path()))
        self.master_net.add_node(self.master)
        self.device.start()
        self.master.nmt.wait_for_heartbeat(timeout=2.0)
        self.master.sdo["Configuration"]["MaxDataAge_ms"].raw = max_age_ms
        self.master.tpdo.read(from_od=True)
        self.master.nmt.state = "OPERATIONAL"
        time.sleep(0.05)

    def sync(self) -> tuple[int, int, int]:
        """SYNC; the (state, sector 0 distance, nearest distance) raw values the TPDOs
        carried (0xFFFF: invalid)."""
        before = [self.master.tpdo[n].timestamp for n in (1, 2, 3)]
        self.master_net.sync.transmit()
        wait_for(lambda: all(self.master.tpdo[n].timestamp != t
                             for n, t in zip((1, 2, 3), before, strict=True)), 1.0)
        return (self.master.tpdo[1]["Status.State"].raw,
                self.master.tpdo[3]["SectorDistance_mm.Sector0"].raw,
                self.master.tpdo[2]["Nearest.Distance_mm"].raw)

    def close(self) -> None:
        self.device.stop()
        self.master_net.disconnect()
        self.device_net.disconnect()


@pytest.fixture
def canopen_pair() -> Iterator[CanopenPair]:
    pair = CanopenPair(max_age_ms=100)
    try:
        yield pair
    finally:
        pair.close()


def _measurement() -> Measurement:
    sectors = tuple(SectorDistance(i, 0.0, SectorState.VALID, 1.0 + 0.5 * i, 0.5)
                    for i in range(8))
    return Measurement(42, sectors, time.monotonic(), 9, nearest=sectors[0])


def test_canopen_tpdos_go_invalid_and_fault_when_the_loop_stops_reporting(
        canopen_pair: CanopenPair) -> None:
    canopen_pair.device.update(_measurement(), RUNNING)
    assert canopen_pair.sync() == (int(UnitState.RUNNING), 1000, 1000)
    time.sleep(0.3)  # no update, no heartbeat: the loop hangs, the data ages past 100 ms
    assert canopen_pair.sync() == (int(UnitState.FAULT), 0xFFFF, 0xFFFF)
    faults = canopen_pair.master.sdo["Status"]["Faults"].raw
    assert faults & int(FaultBits.DEADLINE_MISS)


def test_canopen_heartbeat_keeps_running_but_stale_data_is_invalid(
        canopen_pair: CanopenPair) -> None:
    canopen_pair.device.update(_measurement(), RUNNING)
    end = time.monotonic() + 0.3
    while time.monotonic() < end:  # the loop is alive, but brings no new measurement
        canopen_pair.device.heartbeat()
        time.sleep(0.02)
    assert canopen_pair.sync() == (int(UnitState.RUNNING), 0xFFFF, 0xFFFF)


def test_canopen_stop_sends_the_tpdos_once_more_as_stopped_and_invalid(
        canopen_pair: CanopenPair) -> None:
    canopen_pair.device.update(_measurement(), RUNNING)
    assert canopen_pair.sync()[0] == int(UnitState.RUNNING)
    before = canopen_pair.master.tpdo[3].timestamp
    canopen_pair.device.stop()
    wait_for(lambda: canopen_pair.master.tpdo[3].timestamp != before, 1.0)
    assert canopen_pair.master.tpdo[1]["Status.State"].raw == int(UnitState.STOPPED)
    assert canopen_pair.master.tpdo[3]["SectorDistance_mm.Sector0"].raw == 0xFFFF


@pytest.mark.parametrize(("age_s", "usable"), [
    (-0.001, False), (-6.0, False), (0.0, True), (0.1, True), (0.25, True), (0.2501, False),
    (float("nan"), False), (float("inf"), False), (float("-inf"), False)])
def test_a_distance_is_usable_only_when_fresh_and_not_from_the_future(
        age_s: float, usable: bool) -> None:
    assert payloads.data_usable(_measurement(), RUNNING, age_s, 0.25) is usable


# ----------------------------------------------------------------------------- transmit
def test_a_unit_whose_distance_frames_are_refused_goes_dark_within_a_publish_period(
        request: pytest.FixtureRequest) -> None:
    """The bus stops taking the unit's frames (bus-off): the laser goes off
    REFUSED_GRACE_S (0.1 s) after the publisher's first refused frame, not after the
    negotiation's next re-announcement (0.5 s here), and the unit strobes again only
    after it re-claimed on the bus.

    The negotiation re-announces every 2 s here, so without the distance frames' report
    the unit would stay lit until its next refused re-announcement.

    Checked by removing ``Unit._watch_output``: dark only 0.45 s after the bus-off with
    re-announcements every 0.5 s (the negotiator's own refused re-announcement plus the
    grace), 1.2-2.1 s with every 2 s; the 0.5 s assert failed.
    """
    inner = can.Bus(interface="virtual", channel=f"reliability-tx-{request.node.name}")
    bus = FaultyBus(inner, Faults())
    unit = Unit(cfg.load(environ={}, overrides=[
        *BASE, "negotiation.reannounce_s=2.0", "negotiation.silence_timeout_s=6.0"]), bus)
    try:
        unit.configure()
        unit.activate(threaded=False)
        end = time.monotonic() + 30.0
        while unit.stats.measurements < 3:
            assert time.monotonic() < end, "timed out"
            unit.step()
        assert unit.negotiator.may_strobe
        bus.faults.bus_off = True
        off_at = time.monotonic()
        lit_after: list[float] = []
        while time.monotonic() < off_at + 2.5:
            unit.step()
            if unit.negotiator.may_strobe or (unit.projector and unit.projector.is_lit):
                lit_after.append(time.monotonic() - off_at)
        assert bus.counts.failed_sends > 0
        print(f"\nbus-off -> laser dark after {max(lit_after, default=0.0) * 1e3:.0f} ms")
        assert max(lit_after, default=0.0) < 0.5
        bus.faults.bus_off = False
        while not unit.negotiator.may_strobe:
            assert time.monotonic() < off_at + 10.0, "never strobed again"
            unit.step()
    finally:
        unit.shutdown()
        bus.shutdown()


# ----------------------------------------------------------------------------- status bits
def test_the_pipelines_low_signal_verdict_reaches_the_status_frame(
        request: pytest.FixtureRequest) -> None:
    """In strong sun most maps show no line (the pipeline's LOW_SIGNAL); the status frames
    that follow such a map carry Fault_LowSignal, those after a map with lines (when
    there is one) do not.

    Checked by leaving the pipeline's verdict (``Measurer.map_faults``) out of
    ``Unit._measure_faults`` (as before): no status frame ever carried the bit and the
    first assert failed.
    """
    frames = CycleFrames()
    verdicts: list[tuple[float, bool]] = []
    with listened_bus(f"reliability-bits-{request.node.name}", frames, 0.01) as bus:
        unit = Unit(cfg.load(environ={}, overrides=[*BASE, "driver.scene=outdoor_strong_sun"]),
                    bus)
        unit.configure()
        unit.activate(threaded=False)
        try:
            end = time.monotonic() + 60.0
            while len(verdicts) < 20:
                assert time.monotonic() < end, "timed out"
                count = unit.stats.measurements
                unit.step()
                if unit.stats.measurements > count:
                    low = bool(unit.last_result.faults & FaultBits.LOW_SIGNAL)
                    verdicts.append((time.monotonic(), low))
            time.sleep(0.1)
        finally:
            unit.shutdown()
    assert any(low for _, low in verdicts), "no map without lines: the test proves nothing"
    running = [c for c in frames.cycles if c.state == "RUNNING"]
    flagged = [c.status["Fault_LowSignal"] == 1 for c in running]
    assert any(flagged), "no status frame carried the pipeline's LOW_SIGNAL"
    margin_s = 0.01  # a map's cycle goes out inside the step that ends at its verdict time
    for (t0, low), (t1, _) in itertools.pairwise(verdicts):
        between = [c for c in running if t0 + margin_s < c.time_s < t1 - margin_s]
        assert all((c.status["Fault_LowSignal"] == 1) == low for c in between)


class RefusingProjector(Projector):
    """Wraps ``inner``; while ``refuse`` is set every strobe raises DriverError (a
    projector that does not take commands: a broken link to the laser driver)."""

    def __init__(self, inner: Projector) -> None:
        self.inner = inner
        self.refuse = False

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def _strobe(self, chip: int, sequence: int) -> None:
        if self.refuse:
            raise DriverError("injected: the laser driver does not answer")
        self.inner.strobe(chip, sequence)

    def _off(self) -> None:
        self.inner.off()


def run_listened(request: pytest.FixtureRequest, opener: Any,
                 fault_on: Callable[[], None], fault_off: Callable[[], None]
                 ) -> tuple[Unit, list[Cycle], list[Cycle], list[Cycle]]:
    """Step a unit until it publishes valid distances, then 0.6 s with the fault, then
    until valid again: the cycles (before, during, after) as the bus saw them."""
    frames = CycleFrames()
    with listened_bus(f"reliability-fault-{request.node.name}", frames, 0.01) as bus:
        unit = Unit(cfg.load(environ={}, overrides=BASE), bus, open_backend=opener)
        unit.configure()
        unit.activate(threaded=False)
        try:
            step_while(unit, lambda: not any(c.valid for c in frames.cycles))
            fault_on()
            start = time.monotonic()
            step_while(unit, lambda: time.monotonic() < start + 0.6)
            fault_off()
            end = time.monotonic()
            step_while(unit, lambda: not any(c.valid for c in cycles_after(frames, end)))
            time.sleep(0.05)
            unit.check()
        finally:
            unit.shutdown()
    during = [c for c in frames.cycles if start + 0.1 < c.time_s < end]
    return unit, cycles_after(frames, 0.0), during, cycles_after(frames, end)


def step_while(unit: Unit, going: Callable[[], bool], timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while going():
        assert time.monotonic() < deadline, "timed out"
        unit.step()


def test_a_projector_that_refuses_commands_is_laser_fault_and_invalid_not_a_dead_loop(
        request: pytest.FixtureRequest) -> None:
    """The projector stops taking commands for 0.6 s: the loop lives on, the laser is
    switched off, every cycle says FAULT with Fault_LaserFault and invalid distances;
    when it takes commands again the unit measures again and the bit clears.

    Checked by letting the projector's DriverError through ``Unit._strobe_next`` (as
    before): the loop died (``step`` raised) and the test failed; and without the
    LASER_FAULT bit (``_on_laser_fault`` not setting it): the during-fault cycles said
    RUNNING with the bit 0 and the state assert failed.
    """
    projectors: list[RefusingProjector] = []

    def opener(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = open_registry_backend(name, **settings)
        projectors.append(RefusingProjector(projector))
        return camera, projectors[-1]

    def refuse(on: bool) -> None:
        projectors[0].refuse = on

    unit, _, during, after = run_listened(request, opener, lambda: refuse(True),
                                          lambda: refuse(False))
    assert len(during) >= 5
    assert all(c.state == "FAULT" and c.status["Fault_LaserFault"] == 1 for c in during)
    assert all(d == "invalid" for c in during for d in c.distances)
    assert unit.stats.laser_faults > 0
    back = next(c for c in after if c.valid)
    assert back.state == "RUNNING" and back.status["Fault_LaserFault"] == 0


def test_sub_frames_that_do_not_fit_the_calibration_are_a_calibration_fault(
        request: pytest.FixtureRequest) -> None:
    """The camera delivers sub-frames of another size than the calibration's for 0.6 s:
    Fault_Calibration in every cycle meanwhile, distances invalid, cleared after.

    Checked by leaving CALIBRATION out of ``Unit._measure_faults``: the bit stayed 0 and
    the first assert on ``during`` failed.
    """
    cameras: list[FaultyCamera] = []
    faults = CameraFaults()

    def opener(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = open_registry_backend(name, **settings)
        cameras.append(FaultyCamera(camera, faults))
        return cameras[-1], projector

    def wrong_size(on: bool) -> None:
        reads = cameras[0].reads
        faults.wrong_size_at = set(range(reads, reads + 10**6)) if on else set()

    _, _, during, after = run_listened(request, opener, lambda: wrong_size(True),
                                       lambda: wrong_size(False))
    assert len(during) >= 5
    assert all(c.status["Fault_Calibration"] == 1 for c in during)
    assert all(d == "invalid" for c in during for d in c.distances)
    back = next(c for c in after if c.valid)
    assert back.status["Fault_Calibration"] == 0


def test_a_receive_error_turns_the_laser_off_and_the_unit_claims_again(
        request: pytest.FixtureRequest) -> None:
    """The negotiation's receive thread reports an error (a link that flapped): the laser
    goes off at once (the negotiator is CLAIMING), the loop goes on, and the unit owns its
    code again after the window.

    Checked by letting the BusError through ``Unit._tick_negotiation`` (as before): the
    step raised and the loop would have died.
    """
    with can.Bus(interface="virtual", channel=f"reliability-rx-{request.node.name}") as bus:
        unit = Unit(cfg.load(environ={}, overrides=BASE), bus)
        unit.configure()
        unit.activate(threaded=False)
        try:
            step_while(unit, lambda: not unit.negotiator.may_strobe)
            unit.negotiator.store_error(OSError("injected: receive failed"))
            unit.step()
            assert not unit.negotiator.may_strobe
            assert unit.projector is not None and not unit.projector.is_lit
            assert unit.stats.bus_errors == 1
            step_while(unit, lambda: not unit.negotiator.may_strobe)
            unit.check()
        finally:
            unit.shutdown()


def test_error_frames_from_the_bus_set_bus_error_in_the_status_frame(
        request: pytest.FixtureRequest) -> None:
    """A peer on the virtual bus reports bus-off and error-passive (error frames) while
    the unit publishes: its status frames carry Fault_BusError, its distances stay valid
    (its own frames reach the bus: an error frame alone does not spoil a measurement),
    and the bit clears once the reports stop.

    Checked to fail with ``admit_error_frames`` removed from ``wiring.make_bus_services``:
    the unit's receive filter (the negotiation frames) dropped every error frame in
    python-can's software filter, the health monitor counted none and the step loop
    timed out waiting for a flagged status frame.
    """
    frames = CycleFrames()
    channel = f"reliability-errors-{request.node.name}"
    reports = [can.Message(arbitration_id=CAN_ERR_FLAG | CAN_ERR_BUSOFF, is_error_frame=True,
                           is_extended_id=True, data=bytes(8)),
               can.Message(arbitration_id=CAN_ERR_CRTL, is_error_frame=True,
                           data=bytes([0, CAN_ERR_CRTL_PASSIVE, 0, 0, 0, 0, 0, 0]))]
    with listened_bus(channel, frames, 0.01) as bus, \
            can.Bus(interface="virtual", channel=channel) as peer:
        unit = Unit(cfg.load(environ={}, overrides=BASE), bus)
        unit.configure()
        unit.activate(threaded=False)
        try:
            step_while(unit, lambda: not any(c.valid for c in frames.cycles))
            first = len(frames.cycles)

            def unflagged() -> bool:
                for report in reports:
                    peer.send(report)
                return not any(c.status["Fault_BusError"] for c in frames.cycles[first:])

            step_while(unit, unflagged)
            step_while(unit, lambda: len(frames.cycles) < first + 10)
            during = frames.cycles[first:]
            last = len(frames.cycles)
            step_while(unit, lambda: not any(c.valid and not c.status["Fault_BusError"]
                                             for c in frames.cycles[last + 1:]))
            unit.check()
        finally:
            unit.shutdown()
    health = unit.publisher.health
    assert health.bus_off_count >= 1 and health.error_frames > health.bus_off_count
    flagged = [c for c in during if c.status["Fault_BusError"]]
    assert flagged and all(c.state == "RUNNING" for c in flagged)
    assert any(c.valid for c in flagged), "an error frame is no reason to drop distances"
