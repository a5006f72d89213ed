"""The map process (``pipeline.worker = "process"``): the pipeline pass in a child process.

Promises:
- the same maps give bitwise the same results as the pipeline in the unit's own process
  (sectors, distances, samples, points, diagnostics), the pipeline's state across maps
  included, and the window's values really are read from the unit;
- a pipeline that raises in the child is a pipeline error of that map (the next map is
  measured again);
- a child that is killed or that hangs stops the unit at the next map: FAULT, invalid
  distances, the laser off, ``check()`` raising; no valid distance afterwards;
- deactivate and shutdown (twice) leave no shared-memory segment and no child process;
- a bad ``pipeline.worker`` value is refused with a message that names the key and the
  accepted values.

The epoch rule (a map measured while the loop went invalid is not published) and the
newest-map-wins slot are the map thread's, which the map process runs behind: the tests
of tests/test_map_thread.py run with both workers.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from cycle_frames import CycleFrames
from listened_bus import listened_bus

from atris_node import config as cfg
from atris_node.codes import walsh_chips
from atris_node.demod import SlidingDemodulator
from atris_node.errors import ConfigError, MapProcessError, MapProcessLostError, NodeFaultError
from atris_node.node.mapprocess import MapProcess
from atris_node.node.shared import PREFIX
from atris_node.node.unit import Unit
from atris_node.pipeline.chain import Pipeline, PipelineConfig, PipelineResult
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim import Simulator, load_scene
from atris_node.types import DistortionMap, Measurement

BASE = ["code.length=8", "negotiation.window_s=0.1", "negotiation.reannounce_s=0.5",
        "negotiation.silence_timeout_s=1.5", "pipeline.worker=process"]
SHM = Path("/dev/shm")


def sliding_maps(scene_name: str, count: int) -> tuple[Simulator, list[DistortionMap]]:
    """The first ``count`` sliding maps of ``scene_name`` (with their windows)."""
    scene = load_scene(scene_name)
    chips = walsh_chips(scene.code_length, scene.code_row)
    sim = Simulator(scene, chips=chips, seed=1)
    demod = SlidingDemodulator(chips, bits=scene.camera.bits, lag=0)
    maps = (demod.push(sim.render(sequence)) for sequence in itertools.count())
    return sim, list(itertools.islice((m for m in maps if m is not None), count))


#: s; the tests of what the child computes give it this long per map: on a loaded machine
#: (the suite beside other CPU-heavy processes) a map took over the unit's 2 s deadline,
#: which is the watchdog's to test (test_a_hung_map_process_is_killed_...), not theirs
RESULTS_DEADLINE_S = 60.0


def assert_same(a: PipelineResult, b: PipelineResult) -> None:
    """Bitwise the same result (the stage timings aside)."""
    assert a.measurement == b.measurement
    assert a.objects == b.objects
    assert (dataclasses.replace(a.diagnostics, timings_ms={})
            == dataclasses.replace(b.diagnostics, timings_ms={}))
    for name in ("valid", "points_camera_m", "points_vehicle_m", "sigma_z_m"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    for field in dataclasses.fields(a.samples):
        x, y = getattr(a.samples, field.name), getattr(b.samples, field.name)
        assert np.array_equal(x, y), field.name
        assert np.asarray(x).dtype == np.asarray(y).dtype, field.name


@pytest.mark.parametrize("scene_name", ["parking_pedestrian", "jammer_line"])
def test_the_map_process_gives_bitwise_the_results_of_the_pipeline(scene_name: str) -> None:
    """A moving pedestrian (own stripes that move within a window) and a foreign line:
    the window's time course decides peaks there. The ground plane is refitted every
    other map and the ROI narrows, so the pipeline's state across maps counts too."""
    sim, maps = sliding_maps(scene_name, 12)
    config = PipelineConfig(ground_plane="estimate", ground_estimate_every=2,
                            roi_narrowing=True)
    layout = SectorLayout(config.sector_count, math.radians(config.fov_deg))
    local = Pipeline(config, sim.calibration(), sim.mounting, layout)
    remote = MapProcess(Pipeline(config, sim.calibration(), sim.mounting, layout),
                        deadline_s=RESULTS_DEADLINE_S)
    remote.start()
    try:
        for dmap in maps:
            assert_same(local.process(dmap), remote.process(dmap))
        assert remote.series_requests > 0, "the window was not read from the unit"
    finally:
        remote.close()


def test_a_pipeline_error_in_the_child_is_that_maps_error() -> None:
    sim, maps = sliding_maps("indoor_lab", 2)
    config = PipelineConfig()
    layout = SectorLayout(config.sector_count, math.radians(config.fov_deg))
    remote = MapProcess(Pipeline(config, sim.calibration(), sim.mounting, layout),
                        deadline_s=RESULTS_DEADLINE_S)
    remote.start()
    try:
        wrong = dataclasses.replace(maps[0], values=maps[0].values[:-1],
                                    saturated=maps[0].saturated[:-1])
        with pytest.raises(MapProcessError, match="distortion map is"):
            remote.process(wrong)
        assert remote.process(maps[1]).measurement.newest_sequence == maps[1].last_sequence
    finally:
        remote.close()


def process_in_thread(remote: MapProcess, dmap: DistortionMap) -> BaseException | None:
    """What ``remote.process(dmap)`` raised, run in a thread given STOP_WAIT_S; a call
    still blocked then fails the test (its child is killed so that the thread ends)."""
    raised: list[BaseException | None] = []

    def run() -> None:
        try:
            remote.process(dmap)
            raised.append(None)
        except BaseException as exc:  # handed to the test
            raised.append(exc)

    thread = threading.Thread(target=run, name="process-under-test", daemon=True)
    thread.start()
    thread.join(STOP_WAIT_S)
    if thread.is_alive():
        pid = remote.pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        thread.join(STOP_WAIT_S)
        pytest.fail(f"process() still blocked after {STOP_WAIT_S:.0f} s")
    return raised[0]


@pytest.mark.parametrize("child", ["answers_half", "asks_and_stops_reading"])
def test_a_child_stalled_halfway_through_the_pipe_is_killed_at_its_deadline(
        child: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A child that stops halfway through its answer (the unit's ``recv`` has the first
    bytes and waits for the rest), or that asks for the window's values at its peaks and
    stops reading (the unit's answer, megabytes, fills the pipe and its ``send``
    blocks): the unit's call returns MapProcessLostError at the deadline and the child is
    killed. A deadline on the first byte alone lets both wait for ever; a SIGSTOP landing
    there hung a CI run's unit with its projector lit.

    Checked by taking the watchdog out (``_watchdog`` yielding without a timer): both
    cases stayed blocked, and the test failed ("still blocked after 30 s")."""
    import stalled_child

    from atris_node.node import mapprocess

    monkeypatch.setattr(mapprocess, "serve", getattr(stalled_child, child))
    sim, maps = sliding_maps("indoor_lab", 1)
    assert maps[0].window is not None
    config = PipelineConfig()
    layout = SectorLayout(config.sector_count, math.radians(config.fov_deg))
    remote = MapProcess(Pipeline(config, sim.calibration(), sim.mounting, layout),
                        deadline_s=0.5)
    remote.start()
    try:
        raised = process_in_thread(remote, maps[0])
        assert isinstance(raised, MapProcessLostError), raised
        assert "did not answer within 0.5 s" in str(raised)
        assert not remote.alive
        with pytest.raises(MapProcessLostError):  # and every map after it
            remote.process(maps[0])
    finally:
        remote.close()


UNGUARDED_MAIN = """
import math
from atris_node.node.mapprocess import MapProcess
from atris_node.pipeline.chain import Pipeline, PipelineConfig
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim import Simulator, load_scene

scene = load_scene("indoor_lab")
sim = Simulator(scene, seed=1)
config = PipelineConfig()
layout = SectorLayout(config.sector_count, math.radians(config.fov_deg))
remote = MapProcess(Pipeline(config, sim.calibration(), sim.mounting, layout))
try:
    remote.start()
finally:
    remote.close()
"""


def test_a_child_that_cannot_be_started_is_a_lost_map_process(tmp_path: Path) -> None:
    """A main module without its ``__main__`` guard starts a map process at import: the
    spawned child imports it again and its own start is refused by multiprocessing
    (RuntimeError, still bootstrapping). That start must raise MapProcessLostError saying
    why, leave no shared-memory segment, and the close after it must be safe. Before the
    fix the unstarted process was kept and the close raised AssertionError ("can only join
    a started process"), outside the exception tree, leaking the segment (seen once, then
    fixed; shown again with the fix taken out: this test failed on it)."""
    import subprocess
    import sys

    script = tmp_path / "unguarded.py"
    script.write_text(UNGUARDED_MAIN)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=300, check=False)
    assert run.returncode != 0  # the parent's map process never became ready
    assert "MapProcessLostError" in run.stderr and "could not start" in run.stderr
    assert "can only join a started process" not in run.stderr
    assert "leaked shared_memory" not in run.stderr  # the segment went with it


# --------------------------------------------------------------------- the unit
@dataclass
class Rig:
    unit: Unit
    frames: CycleFrames
    published: list[Measurement]

    @property
    def child(self) -> MapProcess:
        assert self.unit.measure is not None
        pipeline = self.unit.measure.pipeline
        assert isinstance(pipeline, MapProcess)
        return pipeline


#: s; how long a test waits for the unit to stop after its map process is lost (a
#: behaviour bound, not a timing one: without the deadline the unit never stops)
STOP_WAIT_S = 30.0


def wait_for(done: Callable[[], bool], timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.005)


def segments() -> set[str]:
    return {p.name for p in SHM.glob(f"{PREFIX}{os.getpid()}_*")}


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    """A threaded unit with a map process that has published valid distances."""
    frames = CycleFrames()
    with listened_bus(f"map-process-{request.node.name}", frames, 0.01) as bus:
        unit = Unit(cfg.load(environ={}, overrides=BASE), bus)
        published: list[Measurement] = []
        unit.on_measurement = published.append
        try:
            unit.configure()
            unit.activate(threaded=True)
            wait_for(lambda: any(c.valid for c in frames.cycles), 60.0)
            yield Rig(unit, frames, published)
        finally:
            unit.shutdown()


def stopped(unit: Unit) -> bool:
    """True once the unit stored a fatal error (``check()`` raises)."""
    try:
        unit.check()
    except NodeFaultError:
        return True
    return False


def assert_stopped_safely(rig: Rig, since: float) -> None:
    """The unit stops (``check()`` raising the lost map process); FAULT and invalid
    distances from the first FAULT cycle after ``since`` on, nothing published after the
    stop, the laser off. The stop is waited for up to STOP_WAIT_S: with four CPU-heavy
    processes beside the suite on two cores a hung child's stop took over 10 s."""
    wait_for(lambda: stopped(rig.unit), STOP_WAIT_S)
    count = len(rig.published)
    time.sleep(0.3)
    after = [c for c in list(rig.frames.cycles) if c.time_s > since]
    first = next(i for i, c in enumerate(after) if c.state == "FAULT")
    assert all(c.state == "FAULT" for c in after[first:])
    assert all(d == "invalid" for c in after[first:] for d in c.distances)
    assert len(rig.published) == count
    assert rig.unit.projector is not None and not rig.unit.projector.is_lit
    with pytest.raises(NodeFaultError) as raised:
        rig.unit.check()
    assert isinstance(raised.value.__cause__, MapProcessLostError)


def test_a_killed_map_process_stops_the_unit_at_the_next_map(rig: Rig) -> None:
    """The child killed while the unit runs: the next map finds its pipe closed, and the
    unit stops at once (FAULT, laser off), without taking it for one map's pipeline error.

    Checked by removing ``except MapProcessLostError: raise`` in ``Unit._measure_map``:
    the lost child was counted as pipeline errors (invalid maps, the unit going on until
    PIPELINE_ERROR_LIMIT of them) and the pipeline_errors assertion failed."""
    pid = rig.child.pid
    assert pid is not None
    killed_at = time.monotonic()
    os.kill(pid, signal.SIGKILL)
    assert_stopped_safely(rig, killed_at)
    assert rig.unit.stats.pipeline_errors == 0


def test_a_hung_map_process_is_killed_and_the_laser_goes_off(rig: Rig) -> None:
    """The child stopped (SIGSTOP) in the middle of the run: after its deadline the unit
    kills it and stops: FAULT, laser off. (A hung map thread only makes the output FAULT
    by the data's age while the loop strobes on; a child is killed.)

    Checked by waiting without a deadline in ``MapProcess._receive`` (``poll(None)``,
    when the deadline was a poll's; the watchdog that replaced it is checked by
    test_a_child_stalled_halfway_...): the unit waited for the child for ever and never
    stopped (the output went FAULT by
    the data's age only, the projector stayed lit); the test timed out waiting for the
    stop and failed."""
    rig.child.deadline_s = 0.5
    pid = rig.child.pid
    assert pid is not None
    hung_at = time.monotonic()
    os.kill(pid, signal.SIGSTOP)
    try:
        assert_stopped_safely(rig, hung_at)
        assert not rig.child.alive
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGCONT)


def test_shutdown_leaves_no_segment_and_no_child(request: pytest.FixtureRequest) -> None:
    """Deactivate, activate again, shut down twice: no /dev/shm segment of this process
    and no child process is left (none running, none waiting to be reaped)."""
    import multiprocessing

    with listened_bus(f"map-process-{request.node.name}", CycleFrames(), 0.01) as bus:
        unit = Unit(cfg.load(environ={}, overrides=BASE), bus)
        unit.configure()
        assert unit.measure is not None
        child = unit.measure.pipeline
        assert isinstance(child, MapProcess) and child.alive
        pid = child.pid
        assert segments()
        environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        assert b"OPENBLAS_NUM_THREADS=1" in environ  # no BLAS pool spinning beside the loop
        unit.activate(threaded=True)
        wait_for(lambda: unit.stats.measurements >= 3, 60.0)
        unit.deactivate()
        unit.deactivate()
        assert child.alive and child.pid == pid  # kept between activations
        unit.activate(threaded=True)
        wait_for(lambda: unit.stats.measurements >= 6, 60.0)
        unit.shutdown()
        unit.shutdown()
        unit.check()
    assert not segments()
    assert not child.alive and child.pid is None
    assert not multiprocessing.active_children()
    assert not [t for t in threading.enumerate() if t.name.endswith("-watchdog")]
    with pytest.raises(ChildProcessError):  # reaped: no zombie left behind
        os.waitpid(pid or -1, os.WNOHANG)


def test_a_bad_worker_is_refused_with_the_accepted_values() -> None:
    with pytest.raises(ConfigError, match=r"pipeline.worker: must be one of thread, process, "
                                          r"inline, got 'processes'"):
        cfg.load(environ={}, overrides=["pipeline.worker=processes"])
    with pytest.raises(ConfigError, match=r"pipeline\.thread was replaced by pipeline\.worker"):
        cfg.load(environ={}, overrides=["pipeline.thread=false"])


def test_a_unit_with_a_map_process_measures_in_the_loop_too(
        request: pytest.FixtureRequest) -> None:
    """step()/run_for() called directly measure each map in the loop, through the child."""
    with listened_bus(f"map-process-{request.node.name}", CycleFrames(), 0.01) as bus:
        unit = Unit(cfg.load(environ={}, overrides=BASE), bus)
        published: list[Measurement] = []
        unit.on_measurement = published.append
        unit.configure()
        try:
            unit.activate(threaded=False)
            end = time.monotonic() + 60.0
            while not published and time.monotonic() < end:
                unit.run_for(0.5)
        finally:
            unit.shutdown()
    assert published
    assert not segments()


def test_the_atris_command_asks_for_one_blas_thread_unless_told(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """An OpenBLAS pool thread spinning after the demodulator's dot products took a
    fifth to a third of the second core (docs/benchmarks.md, issue 20)."""
    from atris_node import cli

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    monkeypatch.setattr(os, "environ", dict(os.environ))
    cli.one_blas_thread()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
    assert os.environ["OMP_NUM_THREADS"] == "2"
