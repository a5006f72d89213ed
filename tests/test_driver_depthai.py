"""The depthai backend, without hardware: simulated ImgFrames through a real dai.Pipeline.

A ``dai.Pipeline(createImplicitDevice=False)`` holds two host nodes: ``SimulatedMono``
plays the mono camera (frame events, ImgFrames, exposure control input) and
``ScriptHost`` runs the generated on-device strobe Script unchanged, with a small
``Device`` that holds the two emitter levels. The camera and projector under test are
the backend's own classes, fed by the pipeline's real queues.
"""

from __future__ import annotations

import ast
import datetime
import itertools
import threading
import time
from collections.abc import Iterator
from typing import Any

import can
import depthai as dai
import numpy as np
import pytest

from atris_node.errors import CameraLostError, ConfigError, DeviceNotFoundError, DriverError
from atris_node.types import SubFrame
from drivers.depthai_backend import (
    DepthaiCamera,
    DepthaiProjector,
    DepthaiSettings,
    open_backend,
)
from drivers.depthai_frames import FrameReader, to_sub_frame
from drivers.depthai_script import (
    CONTROL_INPUT,
    EVENT_INPUT,
    LEASE_FRAMES,
    state_message,
    strobe_script,
)

SHAPE = (40, 64)
LASER_ROW = 17
CHIPS = [0, 1, 1, 0, 1, 0, 0, 1]
DROPPED = (9, 10, 23)


class EmitterLevels:
    """The ``Device`` the Script sees: the two IR emitter levels, and a count of updates."""

    def __init__(self) -> None:
        self.dot = 0.0
        self.flood = 0.0
        self.updates = 0
        self.changed = threading.Condition()

    def setIrLaserDotProjectorIntensity(self, level: float) -> None:  # noqa: N802 - Script API
        with self.changed:
            self.dot, self.updates = level, self.updates + 1
            self.changed.notify_all()

    def setIrFloodLightIntensity(self, level: float) -> None:  # noqa: N802 - Script API
        with self.changed:
            self.flood, self.updates = level, self.updates + 1
            self.changed.notify_all()


class ScriptHost(dai.node.ThreadedHostNode):
    """Runs a strobe Script's source as the device would, on real depthai inputs.

    ``states[seq]`` is the Script's (code, enabled) once it finished frame event ``seq``,
    i.e. the state that decided the emitter level of sub-frame ``seq + 1``.
    """

    def __init__(self) -> None:
        super().__init__()
        self.event_in = self.createInput()
        self.control_in = self.createInput()
        self.device = EmitterLevels()
        self.states: dict[int, tuple[tuple[int, ...], bool]] = {}
        self.source = strobe_script([0, 0], "dot", 0.8)

    def run(self) -> None:
        env: dict[str, Any] = {"Device": self.device}
        last: list[int] = []
        host = self

        class Events:
            """``node.io['event']``: notes the state the previous event left behind."""

            def get(self) -> Any:
                with host.device.changed:
                    if last:  # enabled, and inside the lease the host renews
                        leased = env["since"] <= env["lease"]
                        host.states[last[0]] = (tuple(env["code"]),
                                                bool(env["enabled"]) and leased)
                    host.device.changed.notify_all()
                event = host.event_in.get()
                last[:] = [event.getSequenceNum()]
                return event

        io = {EVENT_INPUT: Events(), CONTROL_INPUT: self.control_in}
        env["node"] = type("ScriptNode", (), {"io": io, "warn": print})()
        try:
            exec(compile(self.source, "atris_strobe", "exec"), env)
        except dai.MessageQueue.QueueException:
            return


def mono_frame(seq: int, level: float, exposure_us: int = 500) -> dai.ImgFrame:
    """A GRAY8 frame of the dark room, its laser row at ``level`` (0..1); its host
    timestamp is its creation, as depthai stamps a frame on the host clock."""
    pixels = np.full(SHAPE, 20, np.uint8)
    pixels[LASER_ROW] += np.uint8(200 * level)
    frame = dai.ImgFrame()
    frame.setType(dai.ImgFrame.Type.GRAY8)
    frame.setWidth(SHAPE[1])
    frame.setHeight(SHAPE[0])
    frame.setFrame(pixels)
    frame.setSequenceNum(seq)
    frame.setTimestampDevice(datetime.timedelta(seconds=10.0 + seq / 100.0))
    settings = frame.cam
    settings.exposureTimeUs = exposure_us
    frame.cam = settings
    return frame


class SimulatedMono(dai.node.ThreadedHostNode):
    """A mono camera: a dark room with one laser row that is lit by the dot projector."""

    def __init__(self) -> None:
        super().__init__()
        self.out = self.createOutput()
        self.event = self.createOutput()
        self.control = self.createInput()
        self.script: ScriptHost | None = None
        self.count = 40
        self.exposure_us = 500
        self.period_s = 0.004

    def _frame(self, seq: int, level: float) -> dai.ImgFrame:
        return mono_frame(seq, level, self.exposure_us)

    def _wait_for_script(self, seq: int) -> None:
        """Block until the Script finished frame event ``seq`` (as the sensor's SoF does)."""
        script = self.script
        assert script is not None
        with script.device.changed:
            script.device.changed.wait_for(lambda: seq in script.states, 2.0)

    def run(self) -> None:
        for seq in range(self.count):
            if not self.isRunning():
                return
            control = self.control.tryGet()
            if control is not None:
                self.exposure_us = int(control.getExposureTime().total_seconds() * 1e6)
            level = self.script.device.dot if self.script else 0.0  # set on the last event
            event = dai.ImgFrame()
            event.setSequenceNum(seq)
            self.event.send(event)
            if self.script is not None:
                self._wait_for_script(seq)
            if seq not in DROPPED:
                self.out.send(self._frame(seq, level))
            time.sleep(self.period_s)


@pytest.fixture
def rig() -> Iterator[tuple[Any, SimulatedMono, ScriptHost, DepthaiCamera, DepthaiProjector]]:
    pipeline = dai.Pipeline(createImplicitDevice=False)
    mono, script = pipeline.create(SimulatedMono), pipeline.create(ScriptHost)
    mono.script = script
    mono.event.link(script.event_in)
    frames = mono.out.createOutputQueue(maxSize=64, blocking=True)
    projector = DepthaiProjector(script.control_in.createInputQueue(), code_length=len(CHIPS))
    camera = DepthaiCamera(FrameReader(frames, projector.chip_for),
                           control=mono.control.createInputQueue(), rate_hz=100.0)
    yield pipeline, mono, script, camera, projector
    projector.close()
    camera.close()
    pipeline.stop()
    pipeline.wait()


def laser_lit(pixels: np.ndarray[Any, Any]) -> bool:
    return bool(pixels[LASER_ROW].mean() > pixels[LASER_ROW + 5].mean() + 50)


def settled_at(script: ScriptHost, chips: list[int], enabled: bool = True) -> int:
    """The first frame event after which the Script held ``chips`` (host messages landed)."""
    events = [seq for seq, (code, on) in sorted(script.states.items())
              if list(code) == chips and on == enabled]
    assert events, f"the Script never held {chips} (enabled={enabled})"
    return events[0]


def assert_strobed_by_script(script: ScriptHost, subs: list[SubFrame]) -> None:
    """Each sub-frame is lit exactly when the Script's state after the previous event says."""
    for sub in subs[1:]:
        code, enabled = script.states[sub.sequence - 1]
        expected = enabled and bool(code[sub.sequence % len(code)])
        assert laser_lit(sub.pixels) == expected, sub.sequence


def read_strobing(camera: DepthaiCamera, projector: DepthaiProjector, count: int,
                  chips: list[int] = CHIPS) -> list[SubFrame]:
    """Read ``count`` sub-frames as the node does: after each, strobe the next one's chip
    (which also renews the Script's lease)."""
    subs = []
    for _ in range(count):
        subs.append(camera.read(timeout_s=2.0))
        following = subs[-1].sequence + 1
        projector.strobe(chips[following % len(chips)], following)
    return subs


def test_feature_strobed_sub_frames_through_a_real_pipeline(rig: Any) -> None:
    pipeline, _, script, camera, projector = rig
    projector.set_code(CHIPS)
    pipeline.start()
    subs = read_strobing(camera, projector, 40 - len(DROPPED))
    assert [s.sequence for s in subs] == [n for n in range(40) if n not in DROPPED]
    assert camera.dropped_sub_frames == len(DROPPED)
    for sub in subs:
        assert sub.pixels.dtype == np.uint8 and sub.pixels.shape == SHAPE and sub.bits == 8
        assert sub.chip == CHIPS[sub.sequence % len(CHIPS)]
        assert sub.device_time_s == pytest.approx(10.0 + sub.sequence / 100.0 - 250e-6)
        assert sub.exposure_us == pytest.approx(500.0)
    assert_strobed_by_script(script, subs)
    settled = settled_at(script, CHIPS)
    assert settled < 25
    after = [s for s in subs if s.sequence > settled]
    assert after and all(laser_lit(s.pixels) == bool(s.chip) for s in after)
    assert script.device.flood == 0.0
    assert all(a.host_time_s <= b.host_time_s for a, b in itertools.pairwise(subs))


def test_feature_off_darkens_both_emitters_and_frames(rig: Any) -> None:
    pipeline, mono, script, camera, projector = rig
    mono.count = 200
    projector.set_code([1])
    pipeline.start()
    first_lit = next(n for n in range(50) if laser_lit(camera.read(2.0).pixels))
    assert first_lit < 50 and projector.is_lit
    projector.off()
    assert not projector.is_lit
    subs = [camera.read(2.0) for _ in range(50)]
    settled = settled_at(script, [1], enabled=False)
    assert settled < subs[-1].sequence - 5
    assert not any(laser_lit(s.pixels) for s in subs if s.sequence > settled)
    assert (script.device.dot, script.device.flood) == (0.0, 0.0)
    assert_strobed_by_script(script, subs)


def test_feature_strobe_per_sub_frame_fills_the_device_timeline(rig: Any) -> None:
    pipeline, _, script, camera, projector = rig
    for seq, chip in enumerate(CHIPS):
        projector.strobe(chip, seq)
    assert projector.code == CHIPS and projector.commanded[3] == CHIPS[3]
    pipeline.start()
    subs = read_strobing(camera, projector, 40 - len(DROPPED))
    assert_strobed_by_script(script, subs)
    settled = settled_at(script, CHIPS)
    assert all(laser_lit(s.pixels) == bool(CHIPS[s.sequence % 8]) for s in subs
               if s.sequence > settled)


def test_feature_a_host_that_stops_renewing_leaves_the_laser_dark_after_the_lease(
        rig: Any) -> None:
    """The host strobes every sub-frame, then stops (it hangs, or was killed: either
    way no more messages reach the Script) while the device keeps running. The Script
    keeps the laser lit at most LEASE_FRAMES frame events after the last message, then
    dark. Measured here: lit for 16 sub-frames after the host's last strobe call.

    Checked by giving the Script a lease of 10**6 frames (no lease, as before): the laser
    strobed to the last frame and the dark assert failed.
    """
    pipeline, mono, _, camera, projector = rig
    mono.count = 120
    projector.set_code([1])
    pipeline.start()
    subs = read_strobing(camera, projector, 30, chips=[1])
    assert any(laser_lit(s.pixels) for s in subs[-8:]), "never lit: proves nothing"
    last = subs[-1].sequence + 1  # the sub-frame of the host's last strobe call
    rest = [camera.read(2.0) for _ in range(60)]  # the device runs on, the host is silent
    lit_after = [s.sequence - last for s in rest if laser_lit(s.pixels)]
    print(f"\nlit for {max(lit_after, default=0)} sub-frames after the last strobe call "
          f"(lease {LEASE_FRAMES} frame events)")
    assert max(lit_after, default=0) <= LEASE_FRAMES + 2
    assert not any(laser_lit(s.pixels) for s in rest[-20:])


def test_feature_exposure_control_reaches_the_camera(rig: Any) -> None:
    pipeline, mono, _, camera, _ = rig
    mono.count = 200
    pipeline.start()
    assert camera.read(2.0).exposure_us == pytest.approx(500.0)
    camera.set_exposure_us(750.0)
    exposures = [camera.read(2.0).exposure_us for _ in range(60)]
    assert exposures[-1] == pytest.approx(750.0)
    with pytest.raises(ConfigError, match="exposure"):
        camera.set_exposure_us(0.0)


def test_exception_timeout_and_closed_queue_are_camera_lost(rig: Any) -> None:
    pipeline, mono, _, camera, _ = rig
    mono.count = 2
    pipeline.start()
    camera.read(2.0)
    camera.read(2.0)
    start = time.monotonic()
    with pytest.raises(CameraLostError, match=r"within 0.2 s"):
        camera.read(0.2)
    assert time.monotonic() - start < 1.0
    pipeline.stop()
    pipeline.wait()
    with pytest.raises(CameraLostError) as lost:
        camera.read(0.2)
    assert isinstance(lost.value.__cause__, dai.MessageQueue.QueueException)


def test_exception_xlink_error_is_wrapped() -> None:
    class BrokenLink:
        def get(self, timeout: datetime.timedelta) -> Any:
            raise dai.XLinkReadError("Couldn't read data from stream: 'frames' (X_LINK_ERROR)")

    with pytest.raises(CameraLostError, match="X_LINK_ERROR") as lost:
        FrameReader(BrokenLink()).read(0.1)
    assert isinstance(lost.value.__cause__, dai.XLinkError)


@pytest.mark.parametrize(("kind", "bits", "dtype"), [
    (dai.ImgFrame.Type.RAW10, 10, np.uint16), (dai.ImgFrame.Type.RAW16, 16, np.uint16),
    (dai.ImgFrame.Type.RAW8, 8, np.uint8)])
def test_feature_raw_frames_keep_their_bits(kind: Any, bits: int, dtype: Any) -> None:
    pixels = (np.arange(24).reshape(4, 6) * 37 % (1 << bits)).astype(dtype)
    frame = dai.ImgFrame()
    frame.setType(kind)
    frame.setWidth(6)
    frame.setHeight(4)
    frame.setFrame(pixels)
    frame.setSequenceNum(5)
    sub = to_sub_frame(frame, host_time_s=3.5, chip=1)
    assert (sub.bits, sub.pixels.dtype, sub.sequence, sub.host_time_s, sub.chip) == (
        bits, np.dtype(dtype), 5, 3.5, 1)
    assert np.array_equal(sub.pixels, pixels)


def test_exception_colour_frames_are_refused() -> None:
    frame = dai.ImgFrame()
    frame.setType(dai.ImgFrame.Type.NV12)
    with pytest.raises(DriverError, match="accepted: GRAY8"):
        to_sub_frame(frame, 0.0)


def _script_code(source: str) -> list[int]:
    for statement in ast.parse(source).body:
        if isinstance(statement, ast.Assign) and ast.unparse(statement.targets[0]) == "code":
            return list(ast.literal_eval(statement.value))
    raise AssertionError("no code = [...] in the Script")


def test_feature_script_is_valid_python_and_encodes_the_chips() -> None:
    source = strobe_script(CHIPS, "flood", 0.5)
    compile(source, "atris_strobe", "exec")
    assert _script_code(source) == CHIPS
    assert "Device.setIrFloodLightIntensity(level)" in source
    assert "Device.setIrLaserDotProjectorIntensity(level)" in strobe_script([0, 1])
    assert state_message(True, 0.25, [0, 1, 1]) == b"atris 1 0.2500 011"


@pytest.mark.parametrize(("call", "match"), [
    (lambda: strobe_script([0, 2]), "0/1 chips"), (lambda: strobe_script([]), "0/1 chips"),
    (lambda: strobe_script([0, 1], "laser"), "accepted: dot, flood"),
    (lambda: strobe_script([0, 1], intensity=1.5), "within 0..1"),
    (lambda: DepthaiSettings(resolution="1080p").check(), "accepted: 400p"),
    (lambda: open_backend(colour=True), "accepted: rate_hz")])
def test_exception_bad_settings(call: Any, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        call()


def test_exception_no_device_fails_fast() -> None:
    if dai.Device.getAllAvailableDevices():
        pytest.skip("an OAK device is attached")
    start = time.monotonic()
    with pytest.raises(DeviceNotFoundError, match="no OAK device attached"):
        open_backend(rate_hz=60.0)
    assert time.monotonic() - start < 2.0


@pytest.mark.hardware
def test_hardware_oak_strobes_the_dot_projector() -> None:
    """On an OAK-D Pro facing a surface within a few metres: the dot projector lights the
    sub-frames whose chip is 1 and only those, with a contrast well above the frame-to-frame
    noise. (Runs only with ``-m hardware`` and a device attached; none on the development
    machine, so this test has not been run against its protection.)"""
    camera, projector = open_backend(rate_hz=60.0, resolution="400p", exposure_us=2000.0)
    with camera, projector:
        projector.set_code([0, 1])
        subs = [camera.read(2.0) for _ in range(60)][20:]
        projector.off()
    assert all(b.sequence > a.sequence for a, b in itertools.pairwise(subs))
    assert subs[0].pixels.shape == (400, 640) and subs[0].pixels.dtype == np.uint8
    level = np.array([s.pixels.astype(np.float64).mean() for s in subs])
    lit = np.array([s.chip == 1 for s in subs])
    contrast = level[lit].mean() - level[~lit].mean()  # signed: a swapped label fails
    noise = level[~lit].std()
    assert contrast > max(1.0, 5.0 * noise), (
        f"lit - dark {contrast:.2f} grey levels against a dark-frame noise of {noise:.2f}")
    # every sub-frame carries the chip it was exposed with (a one-frame slip of the labels
    # makes about half of them wrong)
    agree = np.mean((level > level[lit].mean() - contrast / 2) == lit)
    assert agree >= 0.95, f"only {agree:.0%} of the sub-frames are lit as their chip says"


class ListQueue:
    """A ``FrameQueue`` over a list of ImgFrames (what the reader sees of a dai queue)."""

    def __init__(self, frames: list[dai.ImgFrame]) -> None:
        self.frames = frames

    def get(self, timeout: datetime.timedelta) -> Any:
        return self.frames.pop(0) if self.frames else None


def stamped_frame(seq: int, host_time_s: float) -> dai.ImgFrame:
    frame = mono_frame(seq, 1.0)
    frame.setTimestamp(datetime.timedelta(seconds=host_time_s))
    return frame


@pytest.mark.parametrize(("offset_s", "valid"), [(-6.0, False), (-0.05, True), (0.5, False)])
def test_feature_a_frames_age_is_its_exposure_time_not_its_arrival(
        offset_s: float, valid: bool) -> None:
    """A frame exposed 6 s ago (it sat in a queue) is read now: its sub-frame keeps the
    exposure time, and the distances measured from it go out invalid; one stamped in the
    future (broken clock sync) is invalid too; a fresh one is valid. The publisher and the
    DBC codec are the real ones.

    Checked by stamping the sub-frame with the read time (as before): the timestamp
    assert failed, and with it taken out the 6 s old frame's distances went out valid
    (and the future-stamped frame's too): two of the three cases failed.
    """
    from atris_node.bus.can.frames import FrameCodec
    from atris_node.bus.can.ids import FrameKind, frame_id
    from atris_node.bus.can.publisher import Publisher
    from atris_node.types import Measurement, SectorDistance, SectorState, UnitState, UnitStatus

    exposed_s = time.monotonic() + offset_s
    sub = FrameReader(ListQueue([stamped_frame(5, exposed_s)])).read(0.1)
    assert sub.host_time_s == pytest.approx(exposed_s - 250e-6, abs=1e-5)  # mid-exposure
    sectors = (SectorDistance(0, 0.0, SectorState.VALID, 2.0, 0.9),)
    measurement = Measurement(1, sectors, sub.host_time_s, 1)
    status = UnitStatus(UnitState.RUNNING, 2, 8, 120.0, 1)
    with can.Bus(interface="virtual", channel=f"age-{offset_s}") as bus:
        frames = Publisher(bus, 0, max_age_s=0.25).compose(measurement, status,
                                                           time.monotonic())
    codec = FrameCodec()
    sectors_id = frame_id(0, FrameKind.SECTORS)
    sector = next(codec.decode_message(m) for m in frames if m.arbitration_id == sectors_id)
    assert isinstance(sector.signals["Distance0"], float) is valid
