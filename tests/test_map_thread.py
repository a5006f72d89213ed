"""The map thread: maps measured beside the camera loop, and what may reach the bus.

The camera loop hands each complete map to the map thread and reads on. Promises:
- a measurement whose map was complete before the loop went invalid (a rejected
  sub-frame, the code lost, a camera fault) is never published after it;
- a map thread that hangs makes the output FAULT with invalid distances, as a hung loop
  does, although the loop itself still reads;
- a pipeline that raises on one map sends that map's distances invalid and goes on (the
  unit stays up and measures again); one that raises on ``PIPELINE_ERROR_LIMIT`` maps in
  a row is broken: the map thread dies and stops the loop: laser off, FAULT at once, the
  error re-raised by ``check()``;
- the newest map wins: a map waiting while another is measured is replaced, not queued.

The unit-level promises hold with both ``pipeline.worker = "thread"`` and ``"process"``
(the map thread then waits for the map process: tests/test_map_process.py).

Each protection was removed once and the test watched fail, then put back:
- the epoch comparison in ``Unit._publish`` (always publishing): the gated map was
  published after the loop had gone invalid, the first test failed;
- the loop's heartbeat given whether or not the map thread is idle: the hung map
  thread's cycles stayed RUNNING (invalid distances only by their age), the second test
  failed;
- ``self._stop.set()`` in ``Unit._on_map_thread_error``: the loop went on strobing after
  the map thread died (projector lit), the third test failed;
- the ``try`` around the measure in ``Unit._measure_map`` (one failed map ends the
  unit): the fourth test failed (FAULT, the projector dark, check() raising);
- ``self._publish(None)`` in ``Unit._on_pipeline_error``: the map before the failed one
  stayed valid on the bus through it, the fourth test failed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cycle_frames import CycleFrames
from listened_bus import listened_bus

from atris_node import config as cfg
from atris_node.errors import NodeFaultError
from atris_node.node.unit import PIPELINE_ERROR_LIMIT, Unit
from atris_node.node.worker import MapThread
from atris_node.testing.faultcamera import CameraFaults, FaultyCamera
from atris_node.types import DistortionMap, Measurement
from drivers import Camera, Projector
from drivers import open_backend as open_registry_backend

SCENES = Path(__file__).resolve().parents[1] / "launch" / "scenes"
BASE = ["code.length=8", "negotiation.window_s=0.1", "negotiation.reannounce_s=0.5",
        "negotiation.silence_timeout_s=1.5"]


@dataclass
class Gate:
    """Wraps the measurer's ``measure``: while ``hold`` is set, the next map waits in the
    map thread (``entered`` is set, its sequence kept) until ``release``; ``error``, when
    given, is raised there instead."""

    inner: Callable[..., Measurement]
    hold: threading.Event = field(default_factory=threading.Event)
    entered: threading.Event = field(default_factory=threading.Event)
    release: threading.Event = field(default_factory=threading.Event)
    done: threading.Event = field(default_factory=threading.Event)
    error: Exception | None = None
    held_sequence: int | None = None
    #: maps, from the next one, on which ``error`` is raised at once (no hold)
    failures: int = 0
    failed_sequences: list[int] = field(default_factory=list)
    #: ("failed", sequence) entries, in order with whatever else the test logs there
    log: list[tuple[str, Any]] = field(default_factory=list)

    def __call__(self, dmap: DistortionMap, camera: Any) -> Measurement:
        if self.failures > 0 and self.error is not None:
            self.failures -= 1
            self.failed_sequences.append(dmap.last_sequence)
            self.log.append(("failed", dmap.last_sequence))
            raise self.error
        if not self.hold.is_set():
            return self.inner(dmap, camera)
        self.hold.clear()
        self.held_sequence = dmap.last_sequence
        self.entered.set()
        if self.error is not None:
            raise self.error
        self.release.wait()
        try:
            return self.inner(dmap, camera)
        finally:
            self.done.set()


@dataclass
class Rig:
    unit: Unit
    camera: FaultyCamera
    frames: CycleFrames
    gate: Gate
    published: list[Measurement]


def wait_for(done: Callable[[], bool], timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.005)


@pytest.fixture(params=["thread", "process"])
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    """A threaded unit that has published valid distances, its maps measured on the map
    thread (the default) or sent by it to the map process."""
    frames = CycleFrames()
    cameras: list[FaultyCamera] = []

    def opener(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = open_registry_backend(name, **settings)
        cameras.append(FaultyCamera(camera, CameraFaults()))
        return cameras[-1], projector

    with listened_bus(f"map-thread-{request.node.name}", frames, 0.01) as bus:
        overrides = [*BASE, f"pipeline.worker={request.param}"]
        unit = Unit(cfg.load(environ={}, overrides=overrides), bus, open_backend=opener)
        unit.configure()
        assert unit.measure is not None
        gate = Gate(unit.measure.measure)
        unit.measure.measure = gate  # type: ignore[method-assign]
        published: list[Measurement] = []
        unit.on_measurement = published.append
        unit.activate(threaded=True)
        try:
            wait_for(lambda: any(c.valid for c in frames.cycles), 60.0)
            yield Rig(unit, cameras[0], frames, gate, published)
        finally:
            gate.release.set()
            unit.shutdown()


def test_a_map_measured_while_the_loop_went_invalid_is_not_published(rig: Rig) -> None:
    rig.gate.hold.set()
    assert rig.gate.entered.wait(10.0)
    bad_before = rig.unit.stats.bad_sub_frames
    rig.camera.faults.wrong_size_at = {rig.camera.reads + 1}
    wait_for(lambda: rig.unit.stats.bad_sub_frames > bad_before, 10.0)
    rig.gate.release.set()
    assert rig.gate.done.wait(10.0)
    wait_for(lambda: rig.unit.stats.stale_maps >= 1, 10.0)
    held = rig.gate.held_sequence
    assert held is not None
    assert not [m for m in rig.published if m.newest_sequence == held]
    # the loop's own later maps are published again (a new epoch, not a dead output)
    count = len(rig.published)
    wait_for(lambda: len(rig.published) > count, 30.0)


def test_a_hung_map_thread_makes_the_output_fault(rig: Rig) -> None:
    rig.gate.hold.set()
    assert rig.gate.entered.wait(10.0)
    hung_at = time.monotonic()
    reads = rig.camera.reads
    max_age_s = float(rig.unit.config["publish.max_age_s"])
    period_s = float(rig.unit.config["publish.period_s"])
    time.sleep(max_age_s + 0.6)
    assert rig.camera.reads > reads + 10, "the loop stopped reading: proves nothing"
    late = [c for c in list(rig.frames.cycles)
            if c.time_s > hung_at + max_age_s + 2 * period_s + 0.05]
    assert len(late) >= 5
    assert all(c.state == "FAULT" for c in late), [c.state for c in late]
    assert all(c.status["Fault_DeadlineMiss"] == 1 for c in late)
    assert all(d == "invalid" for c in late for d in c.distances)


def test_a_map_thread_that_dies_stops_the_loop_and_the_laser(rig: Rig) -> None:
    died_at = time.monotonic()
    rig.gate.error = RuntimeError("injected pipeline bug")
    rig.gate.failures = PIPELINE_ERROR_LIMIT
    wait_for(lambda: any(c.state == "FAULT" for c in list(rig.frames.cycles)
                         if c.time_s > died_at), 5.0)
    time.sleep(0.3)
    after = [c for c in list(rig.frames.cycles) if c.time_s > died_at]
    first = next(i for i, c in enumerate(after) if c.state == "FAULT")
    assert all(c.state == "FAULT" for c in after[first:])
    assert all(d == "invalid" for c in after[first:] for d in c.distances)
    assert rig.unit.projector is not None and not rig.unit.projector.is_lit
    with pytest.raises(NodeFaultError, match="injected pipeline bug"):
        rig.unit.check()


def test_a_map_the_pipeline_fails_on_goes_out_invalid_and_the_unit_goes_on(rig: Rig) -> None:
    publisher = rig.unit.publisher
    inner_update = publisher.update

    def update(measurement: Measurement | None, status: Any) -> None:
        rig.gate.log.append(("update", measurement))
        inner_update(measurement, status)

    publisher.update = update
    start = time.monotonic()
    rig.gate.error = RuntimeError("injected pipeline bug")
    rig.gate.failures = PIPELINE_ERROR_LIMIT - 1
    wait_for(lambda: rig.unit.stats.pipeline_errors == PIPELINE_ERROR_LIMIT - 1, 30.0)
    count = len(rig.published)
    wait_for(lambda: len(rig.published) > count + 2, 30.0)  # measures and publishes again
    assert len(rig.gate.failed_sequences) == PIPELINE_ERROR_LIMIT - 1
    log = list(rig.gate.log)
    for i, (what, _) in enumerate(log):
        if what == "failed":  # the next thing the output hears: invalid distances
            assert log[i + 1] == ("update", None), "the map before the failed one stayed valid"
    assert rig.unit.stats.pipeline_errors == PIPELINE_ERROR_LIMIT - 1
    assert all(c.state != "FAULT" for c in list(rig.frames.cycles) if c.time_s > start)
    assert any(c.valid for c in list(rig.frames.cycles)[-5:])
    assert rig.unit.projector is not None and rig.unit.projector.is_lit
    rig.unit.check()  # raises nothing: the unit is up


def fake_map(sequence: int) -> DistortionMap:
    values = np.zeros((2, 2), dtype=np.int32)
    return DistortionMap(values=values, saturated=np.zeros((2, 2), dtype=bool),
                         code_length=4, first_sequence=sequence - 3, last_sequence=sequence,
                         first_time_s=0.0, last_time_s=0.0)


def test_the_newest_map_replaces_a_waiting_one() -> None:
    measured: list[tuple[int, int]] = []
    busy, go = threading.Event(), threading.Event()

    def measure(dmap: DistortionMap, epoch: int) -> None:
        busy.set()
        go.wait(10.0)
        measured.append((dmap.last_sequence, epoch))

    def failed(exc: BaseException) -> None:
        raise AssertionError(f"unexpected: {exc}")

    maps = MapThread(measure, failed, "test-maps")
    maps.start()
    try:
        maps.submit(fake_map(3), 1)
        assert busy.wait(10.0)
        maps.submit(fake_map(4), 1)
        maps.submit(fake_map(5), 2)
        go.set()
        assert maps.wait_idle(10.0)
    finally:
        maps.stop()
    assert measured == [(3, 1), (5, 2)]
    assert (maps.skipped, maps.measured) == (1, 2)
    assert not maps.alive


def test_the_adaptations_exposure_is_set_by_the_loop_not_the_map_thread(
        request: pytest.FixtureRequest, tmp_path: Path) -> None:
    """With adaptation on and the map thread measuring, every exposure change reaches the
    camera from the loop's thread, between two reads (a camera is read by the loop only).
    Checked by calling ``camera.set_exposure_us`` in ``Measurer._adapt`` again: the
    changes came from the map thread and the test failed."""
    callers: list[str] = []
    # indoor_lab exposed 20x too short: the adaptation lengthens the exposure at once
    scene = tmp_path / "short_exposure.toml"
    text = (SCENES / "indoor_lab.toml").read_text(encoding="utf-8")
    scene.write_text(text.replace("exposure_us = 1000.0", "exposure_us = 50.0", 1),
                     encoding="utf-8")
    overrides = [*BASE, "adaptive.enabled=true", f"driver.scene={scene}"]
    with listened_bus(f"map-thread-{request.node.name}", CycleFrames(), 0.01) as bus:
        unit = Unit(cfg.load(environ={}, overrides=overrides), bus)
        unit.configure()
        camera = unit.camera
        assert camera is not None
        inner = camera.set_exposure_us

        def recording(exposure_us: float) -> None:
            callers.append(threading.current_thread().name)
            inner(exposure_us)

        camera.set_exposure_us = recording  # type: ignore[method-assign]
        unit.activate(threaded=True)
        try:
            wait_for(lambda: len(callers) >= 1 and unit.stats.measurements >= 20, 60.0)
        finally:
            unit.shutdown()
    assert callers and all(name.startswith("atris-unit-") for name in callers), callers
