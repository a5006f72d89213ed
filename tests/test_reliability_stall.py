"""A loop stalled in a camera read: the laser goes dark, and a lost code darkens it at once.

The rule: the laser is off whenever the node is not demodulating, and a unit never strobes
a code it does not own. A hung camera driver blocks the loop inside ``read``; the loop
cannot switch anything off then, so the projector must (``drivers.guard``), and the
negotiation losing the code must reach the projector without the loop.

Each protection was removed once and the test watched fail, then put back (the
docstrings say which).
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest
from cycle_frames import CycleFrames
from strobe_audit import AuditedProjector, audited

from atris_node import config as cfg
from atris_node.bus.negotiation import frames as nf
from atris_node.errors import NodeFaultError
from atris_node.node import unit as unit_module
from atris_node.node.unit import Lifecycle, Unit
from atris_node.types import FaultBits, SubFrame, UnitState
from drivers import Camera, Projector
from drivers import open_backend as open_registry_backend
from drivers.guard import GuardedProjector

BASE = ["code.length=8", "negotiation.window_s=0.1", "negotiation.reannounce_s=0.5",
        "negotiation.silence_timeout_s=1.5"]


class HeldCamera(Camera):
    """Wraps a camera; once ``hold`` is set, the next read blocks until ``release`` (a hung
    driver: the read's timeout is ignored). ``on_hold`` runs as the read blocks."""

    def __init__(self, inner: Camera) -> None:
        self.inner = inner
        self.rate_hz = inner.rate_hz
        self.hold, self.held, self.release = (threading.Event(), threading.Event(),
                                              threading.Event())
        self.on_hold: Callable[[], None] = lambda: None
        self.delay_s = 0.0  # every read takes this long (a starved loop)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def factory_calibration(self) -> Any:
        return self.inner.factory_calibration()

    def _read(self, timeout_s: float) -> SubFrame:
        if self.delay_s:
            time.sleep(self.delay_s)
        if self.hold.is_set() and not self.release.is_set():
            self.on_hold()
            self.held.set()
            self.release.wait()
        return self.inner.read(timeout_s)

    def _close(self) -> None:
        self.release.set()
        self.inner.close()


class FreezableClock:
    """``time.monotonic`` until :meth:`freeze`; then it stands still (a lease on it cannot
    run out, so only an explicit off() can darken the projector)."""

    def __init__(self) -> None:
        self.frozen: float | None = None

    def __call__(self) -> float:
        return time.monotonic() if self.frozen is None else self.frozen

    def freeze(self) -> None:
        self.frozen = time.monotonic()


def wait_for(condition: Callable[[], bool], timeout_s: float = 20.0) -> bool:
    end = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < end:
        time.sleep(0.005)
    return condition()


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[Any]:
    """A threaded unit on a virtual channel with a held camera and an audited projector,
    a second bus object of the channel to forge frames with, and the unit's cycles as a
    controller decodes them (``cycles``)."""
    channel = f"stall-{request.node.name}-{uuid.uuid4().hex[:6]}"
    bus = can.Bus(interface="virtual", channel=channel)
    forger = can.Bus(interface="virtual", channel=channel)
    cycles = CycleFrames()
    notifier = can.Notifier(forger, [cycles], timeout=0.02)
    cameras: list[HeldCamera] = []
    projectors: list[AuditedProjector] = []

    def open_held(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = open_registry_backend(name, **settings)
        cameras.append(HeldCamera(camera))
        return cameras[-1], projector

    def start(*extra: str, clock: Callable[[], float] = time.monotonic) -> Unit:
        unit = Unit(cfg.load(environ={}, overrides=[*BASE, *extra]), bus,
                    open_backend=audited(open_held, projectors), clock=clock)
        units.append(unit)
        unit.configure()
        unit.activate(threaded=True)
        assert wait_for(lambda: unit.negotiator.may_strobe and bool(unit.projector.is_lit))
        return unit

    units: list[Unit] = []
    rig = type("Rig", (), {"start": staticmethod(start), "cameras": cameras,
                           "projectors": projectors, "forger": forger, "cycles": cycles})
    try:
        yield rig
    finally:
        for camera in cameras:
            camera.release.set()
        for unit in units:
            unit.shutdown()
        notifier.stop()
        forger.shutdown()
        bus.shutdown()


def test_projector_goes_dark_while_the_camera_read_is_blocked(rig: Any) -> None:
    """The loop blocks in a camera read with the laser commanded on: the projector goes
    dark by itself while the read is still blocked, and nothing lights it until the read
    returns. Checked to fail with the guard's lease removed (``GuardedProjector.expire``
    returning the time left without switching off): the laser stayed lit for as long as
    the read was blocked."""
    unit = rig.start()
    camera = rig.cameras[0]
    camera.hold.set()
    assert camera.held.wait(20.0)
    assert wait_for(lambda: not unit.projector.is_lit, 5.0), "lit during a blocked read"
    assert not camera.release.is_set() and unit.stats.sub_frames > 0
    audit = rig.projectors[0]
    assert audit.calls[-1][1] is None, "the last command to the emitter must be off"
    assert not audit.inner.is_lit
    camera.release.set()
    assert wait_for(lambda: unit.stats.strobe_lapses >= 1), "the window was not restarted"


def test_a_starved_loop_says_deadline_miss_until_a_window_completes(rig: Any) -> None:
    """Every camera read takes 0.2 s, past the projector's lease (a sub-frame period plus
    0.05 s): the strobe lapses on every sub-frame, every window restarts, the unit never
    measures and its laser is dark most of the time. Its status says DEADLINE_MISS all
    along (a controller must learn that the unit is starved, not see RUNNING or
    NEGOTIATING with no fault); once reads are fast again and a window completes, the bit
    clears. Checked to fail with the bit not set in ``Unit._strobe_lapsed`` (the status
    carried no fault while the strobe lapsed on every sub-frame)."""
    unit = rig.start()
    camera = rig.cameras[0]
    camera.delay_s = 0.2
    lapses = unit.stats.strobe_lapses
    assert wait_for(lambda: unit.stats.strobe_lapses >= lapses + 3), "no lapse"
    assert unit.status().faults & FaultBits.DEADLINE_MISS
    camera.delay_s = 0.0
    assert wait_for(lambda: not unit.status().faults & FaultBits.DEADLINE_MISS), (
        "the bit stayed after the loop kept its strobe again")


def test_projector_goes_dark_at_once_when_the_row_is_lost_during_a_stall(rig: Any) -> None:
    """A lower NAME claims our row while the loop is blocked in a camera read. The unit's
    clock stands still from the block on, so the lease cannot run out: only the
    negotiation's change can darken the projector, and it must, without the loop.
    Checked to fail with ``Unit._on_negotiation_change`` not switching the laser off:
    the projector stayed lit on the lost row."""
    clock = FreezableClock()
    unit = rig.start("driver.strobe_margin_s=1.0", clock=clock)
    camera = rig.cameras[0]
    camera.on_hold = clock.freeze
    camera.hold.set()
    assert camera.held.wait(20.0)
    row = unit.negotiator.code_row
    assert unit.projector.is_lit and unit.negotiator.may_strobe
    claim = nf.encode_claim(0x1, 9, row)
    rig.forger.send(can.Message(arbitration_id=claim.can_id, data=claim.data,
                                is_extended_id=True))
    assert wait_for(lambda: unit.negotiator.code_row != row, 5.0)
    assert wait_for(lambda: not unit.projector.is_lit, 5.0), "lit on a row it lost"
    assert not camera.release.is_set()
    assert unit.projector.lapses == 0, "darkened by the lease, not by the lost row"


def test_no_running_cycle_goes_out_on_a_row_lost_during_a_stall(rig: Any) -> None:
    """A lower NAME claims our row while the loop is blocked in a camera read (MaxDataAge
    2 s, so the hung loop is not yet FAULT and its last distances are still fresh; maps
    measured in the loop, so no map thread hands over a status meanwhile): the
    loop last handed over RUNNING with distances, yet every cycle after the loss says
    NEGOTIATING with CodeRow 0 and invalid distances; the state and row are the
    negotiation's at send time. Checked to fail with ``Unit.configure`` not setting the
    publisher's ``status_at_send`` (the status sent as the loop last handed it): the
    cycles after the loss said RUNNING with the lost row and numeric distances."""
    unit = rig.start("publish.max_age_s=2.0", "pipeline.worker=inline")
    assert wait_for(lambda: any(_valid(c) for c in rig.cycles.cycles))
    camera = rig.cameras[0]
    camera.hold.set()
    assert camera.held.wait(20.0)
    row = unit.negotiator.code_row
    claim = nf.encode_claim(0x1, 9, row)
    rig.forger.send(can.Message(arbitration_id=claim.can_id, data=claim.data,
                                is_extended_id=True))
    assert wait_for(lambda: unit.negotiator.code_row != row, 5.0)
    lost = len(rig.cycles.cycles)  # the cycle then on the way may be the last RUNNING one
    assert wait_for(lambda: len(rig.cycles.cycles) >= lost + 5, 5.0)
    assert not camera.release.is_set(), "the loop ran again: the test proves nothing"
    after = rig.cycles.cycles[lost + 1:]
    assert [c.state for c in after] == ["NEGOTIATING"] * len(after)
    assert all(c.status["CodeRow"] == 0 for c in after)
    assert all(d == "invalid" for c in after for d in c.distances)


def test_guard_refuses_a_strobe_that_is_not_permitted() -> None:
    """A strobe asked for after the permission went (the loop asked the negotiator just
    before it lost the code) leaves the emitter dark. Checked to fail with the permit
    check removed from ``GuardedProjector.strobe``."""
    camera, inner = open_registry_backend("sim", scene="indoor_lab")
    permitted = [True]
    guard = GuardedProjector(inner, lease_s=1.0, clock=lambda: 0.0,
                             permit=lambda: permitted[0])
    try:
        guard.strobe(1, 0)
        assert guard.is_lit and inner.is_lit
        permitted[0] = False
        guard.strobe(1, 1)
        assert not guard.is_lit and not inner.is_lit
    finally:
        guard.close()
        camera.close()


def test_a_reactivated_unit_publishes_again(rig: Any) -> None:
    """deactivate() then activate() (a lifecycle manager's cycle): the unit negotiates,
    strobes and publishes valid distances again. Checked to fail with ``Publisher.stop``
    keeping its thread (the thread attribute set, the stopping flag set, as before): after
    the second activate() the unit strobed but no cycle went out."""
    unit = rig.start()
    assert wait_for(lambda: any(c.state == "RUNNING" for c in rig.cycles.cycles))
    unit.deactivate()
    assert wait_for(lambda: rig.cycles.cycles[-1].state == "STOPPED")
    stopped = len(rig.cycles.cycles)
    unit.activate()
    assert wait_for(lambda: any(_valid(c) for c in rig.cycles.cycles[stopped:])), \
        "no valid distance published after the unit was activated again"


def _valid(cycle: Any) -> bool:
    return cycle.state == "RUNNING" and any(isinstance(d, float) for d in cycle.distances)


def test_activate_refuses_while_the_previous_loop_hangs(rig: Any,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The loop hangs in a camera read; deactivate() gives up waiting for it; activate()
    must not start a second loop beside it: it raises NodeFaultError, the laser stays off
    and FAULT goes out. Once the hung read returned and the old loop ended, activate()
    works, with one loop. Checked to fail with ``Unit._refuse_beside_old_loop`` returning
    at once: activate() started a second loop (no error raised)."""
    monkeypatch.setattr(unit_module, "LOOP_JOIN_TIMEOUT_S", 0.1)
    unit = rig.start()
    camera = rig.cameras[0]
    camera.hold.set()
    assert camera.held.wait(20.0)
    unit.deactivate()
    assert unit.lifecycle == Lifecycle.INACTIVE and not camera.release.is_set()
    with pytest.raises(NodeFaultError, match="has not ended"):
        unit.activate()
    assert unit.lifecycle == Lifecycle.INACTIVE and not unit.projector.is_lit
    assert unit.status().state is UnitState.FAULT
    assert wait_for(lambda: rig.cycles.cycles[-1].state == "FAULT")
    camera.release.set()
    assert wait_for(lambda: _loops(unit) == 0)
    unit.activate()
    assert wait_for(lambda: unit.negotiator.may_strobe and bool(unit.projector.is_lit))
    assert _loops(unit) == 1


def _loops(unit: Unit) -> int:
    return sum(t.name == f"atris-unit-{unit.label}" and t.is_alive()
               for t in threading.enumerate())
