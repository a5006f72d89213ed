"""An OAK without hardware: a free-running mono camera and the strobe Script in a
``dai.Pipeline(createImplicitDevice=False)``, in this process or in a device process.

``SimulatedMono`` plays the sensor on its own clock: a sub-frame exposed every
``period_s`` with whatever level the dot projector has at that moment, its frame event
(start of readout) ``READOUT_DELAY`` of a period later. The Script sets the emitter for the
next sub-frame on each event. The camera never waits for it: when the Script has not set
the emitter by the next exposure, that sub-frame shows the previous level (a slip), as on
the device.
``ScriptHost`` runs the generated on-device strobe Script's source unchanged, with a small
``Device`` that holds the two emitter levels; ``late_s`` delays its handling of each frame
event (a slow Script, for slip tests).

Run as a script, this module is one side of a two-process rig (``device`` or ``host``)
joined by two pipes (their file descriptors are arguments: depthai logs on stdout), so
that the host can be killed or stopped while the device runs on::

    device LOG COUNT PERIOD FRAMES_FD CONTROL_FD: frames (sequence, level) out, Script
            control messages in; starts with the host's first message and writes its
            event log (JSON) to LOG when its COUNT frames are done
    host CHIPS FRAMES_FD CONTROL_FD: the backend's DepthaiCamera/DepthaiProjector on
            those pipes, strobing every sub-frame as the node does; prints "strobing" on
            stderr once it has
"""

from __future__ import annotations

import datetime
import json
import os
import struct
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, BinaryIO

import depthai as dai
import numpy as np

from drivers.depthai_backend import DepthaiCamera, DepthaiProjector
from drivers.depthai_frames import FrameReader
from drivers.depthai_script import CONTROL_INPUT, EVENT_INPUT, strobe_script

SHAPE = (40, 64)
LASER_ROW = 17
#: a sub-frame's frame event (start of readout) comes this fraction of a period after its
#: exposure, so the Script has the rest of the period to set the emitter for the next one
READOUT_DELAY = 0.5
#: device -> host record of one frame: sequence number, emitter level at exposure
FRAME_RECORD = struct.Struct("!id")
#: host -> device: length of the control message that follows
CONTROL_LENGTH = struct.Struct("!H")


class EmitterLevels:
    """The ``Device`` the Script sees: the two IR emitter levels, and a count of updates.
    ``dot_since`` is the Script's count of frame events since its newest control message
    when it set the dot level (``lease_age`` reads it from the running Script),
    ``dot_sets`` the number of times the dot level was set."""

    def __init__(self) -> None:
        self.dot = 0.0
        self.flood = 0.0
        self.updates = 0
        self.dot_since = 0
        self.dot_sets = 0
        self.lease_age: Callable[[], int] = lambda: 0
        self.changed = threading.Condition()

    def setIrLaserDotProjectorIntensity(self, level: float) -> None:  # noqa: N802 - Script API
        with self.changed:
            self.dot, self.updates = level, self.updates + 1
            self.dot_since, self.dot_sets = self.lease_age(), self.dot_sets + 1
            self.changed.notify_all()

    def setIrFloodLightIntensity(self, level: float) -> None:  # noqa: N802 - Script API
        with self.changed:
            self.flood, self.updates = level, self.updates + 1
            self.changed.notify_all()


class ScriptHost(dai.node.ThreadedHostNode):
    """Runs a strobe Script's source as the device would, on real depthai inputs.

    ``states[seq]`` is the Script's (code, enabled and leased) once it finished frame event
    ``seq``, i.e. the state that decided the emitter level of sub-frame ``seq + 1``;
    ``done_at[seq]`` is when it had finished (``time.monotonic``, taken after the emitter
    was set), ``since[seq]`` the frame events since its newest control message then.
    """

    def __init__(self) -> None:
        super().__init__()
        self.event_in = self.createInput()
        self.control_in = self.createInput()
        self.device = EmitterLevels()
        self.states: dict[int, tuple[tuple[int, ...], bool]] = {}
        self.done_at: dict[int, float] = {}
        self.since: dict[int, int] = {}
        self.late_s = 0.0
        self.source = strobe_script([0, 0], "dot", 0.8)

    def run(self) -> None:
        env: dict[str, Any] = {"Device": self.device}
        self.device.lease_age = lambda: int(env.get("since", 0))
        last: list[int] = []
        host = self

        class Events:
            """``node.io['event']``: notes the state the previous event left behind."""

            def get(self) -> Any:
                if last:
                    host.note(last[0], env)
                event = host.event_in.get()
                host.wait_late(event)
                last[:] = [event.getSequenceNum()]
                return event

        io = {EVENT_INPUT: Events(), CONTROL_INPUT: self.control_in}
        env["node"] = type("ScriptNode", (), {"io": io, "warn": print})()
        try:
            exec(compile(self.source, "atris_strobe", "exec"), env)
        except dai.MessageQueue.QueueException:
            return

    def note(self, seq: int, env: dict[str, Any]) -> None:
        leased = env["since"] <= env["lease"]
        with self.device.changed:
            self.states[seq] = (tuple(env["code"]), bool(env["enabled"]) and leased)
            self.since[seq] = int(env["since"])
            self.done_at[seq] = time.monotonic()
            self.device.changed.notify_all()

    def wait_late(self, event: Any) -> None:
        """Handle the event ``late_s`` after it was sent (a slow Script), not earlier."""
        if self.late_s > 0.0:
            due = event.getTimestamp().total_seconds() + self.late_s
            time.sleep(max(0.0, due - time.monotonic()))


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


def laser_lit(pixels: np.ndarray[Any, Any]) -> bool:
    return bool(pixels[LASER_ROW].mean() > pixels[LASER_ROW + 5].mean() + 50)


class SimulatedMono(dai.node.ThreadedHostNode):
    """A free-running mono camera: a dark room with one laser row lit by the dot projector.

    ``exposed_at[seq]`` and ``levels[seq]`` are when sub-frame ``seq`` was exposed and the
    dot projector's level then; sequence numbers in ``dropped`` are exposed but never sent.
    """

    def __init__(self) -> None:
        super().__init__()
        self.out = self.createOutput()
        self.event = self.createOutput()
        self.control = self.createInput()
        self.script: ScriptHost | None = None
        self.count = 40
        self.exposure_us = 500
        self.period_s = 0.004
        self.dropped: tuple[int, ...] = ()
        self.exposed_at: dict[int, float] = {}
        self.levels: dict[int, float] = {}
        #: the Script's lease age when it set the level sub-frame ``seq`` was exposed with
        self.set_since: dict[int, int] = {}
        #: which of the Script's dot settings (1, 2, ...) sub-frame ``seq`` was exposed with:
        #: two sub-frames with the same one mean the Script was late for the second (a slip)
        self.set_index: dict[int, int] = {}

    def _control(self) -> None:
        control = self.control.tryGet()
        if control is not None:
            self.exposure_us = int(control.getExposureTime().total_seconds() * 1e6)

    def _expose(self, seq: int) -> dai.ImgFrame:
        level, since, index = 0.0, 0, 0
        if self.script is not None:
            with self.script.device.changed:
                device = self.script.device
                level, since, index = device.dot, device.dot_since, device.dot_sets
        self.exposed_at[seq], self.levels[seq] = time.monotonic(), level
        self.set_since[seq], self.set_index[seq] = since, index
        return mono_frame(seq, level, self.exposure_us)

    def run(self) -> None:
        start = time.monotonic()
        for seq in range(self.count):
            if not self.isRunning():
                return
            self._control()
            exposed_at = start + seq * self.period_s
            time.sleep(max(0.0, exposed_at - time.monotonic()))
            frame = self._expose(seq)
            time.sleep(max(0.0, exposed_at + READOUT_DELAY * self.period_s - time.monotonic()))
            event = dai.ImgFrame()  # start of frame: the readout of ``seq`` begins
            event.setSequenceNum(seq)
            event.setTimestamp(datetime.timedelta(seconds=time.monotonic()))
            self.event.send(event)
            if seq not in self.dropped:
                self.out.send(frame)


def build_rig(count: int = 40) -> tuple[Any, SimulatedMono, ScriptHost]:
    """A pipeline (not started) with the camera's events linked to the Script."""
    pipeline = dai.Pipeline(createImplicitDevice=False)
    mono, script = pipeline.create(SimulatedMono), pipeline.create(ScriptHost)
    mono.script, mono.count = script, count
    mono.event.link(script.event_in)
    return pipeline, mono, script


# --- the two-process rig ---------------------------------------------------------------


def _read_exactly(stream: BinaryIO, size: int) -> bytes | None:
    data = b""
    while len(data) < size:
        chunk = stream.read(size - len(data))
        if not chunk:
            return None
        data += chunk
    return data


def _forward_frames(frames: Any, mono: SimulatedMono, out: BinaryIO) -> None:
    """Device side: each frame's (sequence, level) to the host until the host is gone."""
    try:
        while True:
            seq = frames.get().getSequenceNum()
            out.write(FRAME_RECORD.pack(seq, mono.levels[seq]))
            out.flush()
    except (BrokenPipeError, OSError, dai.MessageQueue.QueueException):
        return


def _forward_control(stream: BinaryIO, control: Any, first_only: bool = False) -> None:
    """Device side: the host's control messages into the Script until the pipe closes
    (or after the first one)."""
    while (head := _read_exactly(stream, CONTROL_LENGTH.size)) is not None:
        body = _read_exactly(stream, CONTROL_LENGTH.unpack(head)[0])
        if body is None:
            return
        buffer = dai.Buffer()
        buffer.setData(body)
        control.send(buffer)
        if first_only:
            return


def device_main(log_path: str, count: int, period_s: float, frames_fd: int,
                control_fd: int) -> None:
    """The device: started by the host's first control message, then ``count`` frames
    whatever the host does; then the log of every sub-frame's exposure."""
    pipeline, mono, script = build_rig(count)
    mono.period_s = period_s
    frames = mono.out.createOutputQueue(maxSize=8, blocking=False)
    control = script.control_in.createInputQueue()
    frames_out, control_in = os.fdopen(frames_fd, "wb"), os.fdopen(control_fd, "rb")
    _forward_control(control_in, control, first_only=True)
    pipeline.start()
    threading.Thread(target=_forward_frames, args=(frames, mono, frames_out),
                     daemon=True).start()
    threading.Thread(target=_forward_control, args=(control_in, control),
                     daemon=True).start()
    while pipeline.isRunning() and len(mono.levels) < count:
        time.sleep(0.01)
    pipeline.stop()
    pipeline.wait()
    events = [{"seq": seq, "t": mono.exposed_at[seq], "level": mono.levels[seq],
               "since": mono.set_since[seq], "set": mono.set_index[seq]}
              for seq in sorted(mono.levels)]
    with open(log_path, "w", encoding="utf-8") as log:
        json.dump(events, log)


class PipeFrames:
    """Host side: the device's frame records as ImgFrames (what a dai output queue gives)."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream

    def get(self, timeout: datetime.timedelta) -> Any:
        record = _read_exactly(self.stream, FRAME_RECORD.size)
        if record is None:
            return None
        seq, level = FRAME_RECORD.unpack(record)
        return mono_frame(seq, level)


class PipeControl:
    """Host side: the Script's control input queue over a pipe."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream

    def send(self, buffer: Any) -> None:
        body = bytes(buffer.getData())
        self.stream.write(CONTROL_LENGTH.pack(len(body)) + body)
        self.stream.flush()


def host_main(chips: list[int], frames_fd: int, control_fd: int) -> None:
    """The host: reads sub-frames and strobes the next one's chip, forever (as the node)."""
    control = PipeControl(os.fdopen(control_fd, "wb"))
    projector = DepthaiProjector(control, code_length=len(chips))
    camera = DepthaiCamera(FrameReader(PipeFrames(os.fdopen(frames_fd, "rb")),
                                       projector.chip_for))
    projector.set_code(chips)
    for count in range(1 << 30):
        sub = camera.read(timeout_s=2.0)
        following = sub.sequence + 1
        projector.strobe(chips[following % len(chips)], following)
        if count == 20:
            print("strobing", file=sys.stderr, flush=True)


if __name__ == "__main__":
    if sys.argv[1] == "device":
        device_main(sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5]),
                    int(sys.argv[6]))
        # the log is written: leave without the interpreter's finalization, in which a
        # daemon forwarding thread coming back from a depthai call (GIL released) is
        # ended by pthread_exit through a noexcept C++ frame: std::terminate, SIGABRT
        # (seen once in a fresh make test with the host stopped)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    else:
        host_main([int(c) for c in sys.argv[2]], int(sys.argv[3]), int(sys.argv[4]))
