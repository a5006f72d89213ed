"""The depthai backend, without hardware: simulated ImgFrames through a real dai.Pipeline.

A ``dai.Pipeline(createImplicitDevice=False)`` holds two host nodes (tests/depthai_rig.py):
``SimulatedMono`` plays the mono camera on its own clock (frame events, ImgFrames,
exposure control input; it never waits for the Script, so a late Script slips a frame as
on the device) and ``ScriptHost`` runs the generated on-device strobe Script unchanged,
with a small ``Device`` that holds the two emitter levels. The camera and projector under
test are the backend's own classes, fed by the pipeline's real queues. The frames' host
queue is blocking: a host that falls behind by 64 frames pauses the camera instead of
losing frames, so the tests see every sequence number they expect.
"""

from __future__ import annotations

import ast
import datetime
import itertools
import time
from collections.abc import Iterator
from typing import Any

import can
import depthai as dai
import numpy as np
import pytest
from depthai_rig import SHAPE, ScriptHost, SimulatedMono, build_rig, laser_lit, mono_frame

from atris_node.demod import BlockDemodulator
from atris_node.errors import CameraLostError, ConfigError, DeviceNotFoundError, DriverError
from atris_node.types import SubFrame
from drivers.depthai_backend import (
    DepthaiCamera,
    DepthaiProjector,
    DepthaiSettings,
    open_backend,
)
from drivers.depthai_frames import FrameReader, to_sub_frame
from drivers.depthai_script import LEASE_FRAMES, state_message, strobe_script

CHIPS = [0, 1, 1, 0, 1, 0, 0, 1]
DROPPED = (9, 10, 23)


@pytest.fixture
def rig() -> Iterator[tuple[Any, SimulatedMono, ScriptHost, DepthaiCamera, DepthaiProjector]]:
    pipeline, mono, script = build_rig()
    mono.dropped = DROPPED
    frames = mono.out.createOutputQueue(maxSize=64, blocking=True)
    projector = DepthaiProjector(script.control_in.createInputQueue(), code_length=len(CHIPS))
    camera = DepthaiCamera(FrameReader(frames, projector.chip_for),
                           control=mono.control.createInputQueue(), rate_hz=100.0)
    yield pipeline, mono, script, camera, projector
    projector.close()
    camera.close()
    pipeline.stop()
    pipeline.wait()


def settled_at(script: ScriptHost, chips: list[int], enabled: bool = True) -> int:
    """The first frame event after which the Script held ``chips`` (host messages landed)."""
    events = [seq for seq, (code, on) in sorted(script.states.items())
              if list(code) == chips and on == enabled]
    assert events, f"the Script never held {chips} (enabled={enabled})"
    return events[0]


def in_time(mono: SimulatedMono, script: ScriptHost, seq: int) -> bool:
    """True when the Script had finished frame event ``seq - 1`` (and so set the emitter
    for sub-frame ``seq``) before the sensor exposed ``seq``; else the sub-frame may show
    the level before (a slip)."""
    done = script.done_at.get(seq - 1)
    return done is not None and done <= mono.exposed_at[seq]


def assert_strobed_by_script(mono: SimulatedMono, script: ScriptHost,
                             subs: list[SubFrame]) -> int:
    """Every sub-frame shows the level the emitter had at its exposure, and each one the
    Script set in time is lit exactly when the Script's state after the previous event
    says. Returns how many were set in time (the rest may have slipped)."""
    checked = 0
    for sub in subs[1:]:
        assert laser_lit(sub.pixels) == (mono.levels[sub.sequence] > 0.0), sub.sequence
        if not in_time(mono, script, sub.sequence):
            continue
        code, enabled = script.states[sub.sequence - 1]
        expected = enabled and bool(code[sub.sequence % len(code)])
        assert laser_lit(sub.pixels) == expected, sub.sequence
        checked += 1
    return checked


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
    pipeline, mono, script, camera, projector = rig
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
    assert assert_strobed_by_script(mono, script, subs) > 0, "no sub-frame set in time"
    settled = settled_at(script, CHIPS)
    assert settled < 25
    after = [s for s in subs if s.sequence > settled and in_time(mono, script, s.sequence)]
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
    # sub-frame settled + 1 may have been exposed before the Script went dark (a slip)
    assert not any(laser_lit(s.pixels) for s in subs if s.sequence > settled + 1)
    assert (script.device.dot, script.device.flood) == (0.0, 0.0)
    assert_strobed_by_script(mono, script, subs)


def test_feature_strobe_per_sub_frame_fills_the_device_timeline(rig: Any) -> None:
    pipeline, mono, script, camera, projector = rig
    for seq, chip in enumerate(CHIPS):
        projector.strobe(chip, seq)
    assert projector.code == CHIPS and projector.commanded[3] == CHIPS[3]
    pipeline.start()
    subs = read_strobing(camera, projector, 40 - len(DROPPED))
    assert assert_strobed_by_script(mono, script, subs) > 0, "no sub-frame set in time"
    settled = settled_at(script, CHIPS)
    assert all(laser_lit(s.pixels) == bool(CHIPS[s.sequence % 8]) for s in subs
               if s.sequence > settled and in_time(mono, script, s.sequence))


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


@pytest.mark.parametrize("late_periods", [0.0, 1.0])
def test_feature_a_late_script_slips_and_the_phase_lock_measures_it(
        rig: Any, late_periods: float) -> None:
    """The camera runs on its own clock. A Script that handles each frame event a period
    late sets the emitter after the next exposure: every sub-frame shows the chip of the
    one before, and the demodulator's phase lock, fed the real frames, finds lag 1
    (lag 0 when the Script is in time), so the demodulation signs follow the light.

    Checked against the rig as it was (the camera waited for the Script on every event):
    no slip happened, the lock found lag 0 with the late Script and the lag-1 case failed.
    The period is 20 ms: a late Script lands READOUT_DELAY of a period after the next
    exposure, and at 4 ms a machine loaded by other jobs moved enough of those few
    milliseconds that the lock found no steady lag (None; twice in full runs beside two
    CPU-heavy processes).
    """
    pipeline, mono, script, camera, projector = rig
    mono.count, mono.dropped, mono.period_s = 160, (), 0.02
    script.late_s = late_periods * mono.period_s
    projector.set_code(CHIPS)
    pipeline.start()
    subs = read_strobing(camera, projector, 160)
    settled = settled_at(script, CHIPS)
    demod = BlockDemodulator(CHIPS, bits=8, lag=None)
    for sub in subs:
        if sub.sequence > settled + 2:
            demod.push(sub)
    assert demod.lag == round(late_periods)
