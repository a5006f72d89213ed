"""The ``depthai`` backend: an OAK-D Pro's left mono camera and its IR emitters.

Graph on the device (``build_device_pipeline``)::

    MonoCamera CAM_B (rate, resolution, exposure) --out--------> host queue -> FrameReader
                      \\--frameEvent--> Script (strobe timeline) <--control-- host projector

* ``emitter="dot"`` or ``"flood"``: the Script of :mod:`drivers.depthai_script` sets the IR
  dot projector or the flood LED per chip for the next frame.
* ``emitter="external"``: the camera runs in frame-sync INPUT mode, triggered by an
  external pulse generator that also switches the laser; the host side only records the
  commanded chips and the IR emitters stay dark.

With no device attached, :func:`open_backend` fails in about half a second with
DeviceNotFoundError (``getAllAvailableDevices`` is asked first; ``dai.Device()`` alone
would take ~11 s to fail).
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import depthai as dai

from atris_node.errors import ConfigError, DeviceNotFoundError, DriverError
from atris_node.types import SubFrame
from drivers.base import Camera, Projector
from drivers.depthai_frames import FrameReader
from drivers.depthai_script import (
    CONTROL_INPUT,
    EVENT_INPUT,
    RENEW_FRAMES,
    check_chips,
    check_intensity,
    state_message,
    strobe_script,
)

logger = logging.getLogger(__name__)

#: sensor resolutions of the OV9282 mono camera
RESOLUTIONS = {"400p": "THE_400_P", "720p": "THE_720_P", "800p": "THE_800_P"}
#: (width, height) in pixels of each resolution
SIZES = {"400p": (640, 400), "720p": (1280, 720), "800p": (1280, 800)}
EMITTER_MODES = ("dot", "flood", "external")
#: commanded chips the projector keeps (the newest ones)
COMMAND_HISTORY = 4096


@dataclass(frozen=True)
class DepthaiSettings:
    """Settings of the depthai backend. ``exposure_us`` None keeps auto exposure."""

    rate_hz: float = 120.0
    resolution: str = "800p"
    emitter: str = "dot"
    intensity: float = 0.8
    exposure_us: float | None = None
    iso: int = 400
    code_length: int = 16
    device_id: str = ""
    queue_size: int = 8

    def check(self) -> DepthaiSettings:
        """Return self; raise ConfigError naming the first setting out of range."""
        if self.resolution not in RESOLUTIONS:
            raise ConfigError(f"resolution {self.resolution!r}; accepted: {', '.join(RESOLUTIONS)}")
        if self.emitter not in EMITTER_MODES:
            raise ConfigError(f"emitter {self.emitter!r}; accepted: {', '.join(EMITTER_MODES)}")
        if not 1.0 <= self.rate_hz <= 255.0:
            raise ConfigError(f"rate_hz {self.rate_hz!r}; accepted: 1..255 Hz")
        if self.code_length < 2:
            raise ConfigError(f"code_length {self.code_length!r}; accepted: 2 or more")
        check_intensity(self.intensity)
        return self


class DepthaiCamera(Camera):
    """A camera over a queue of ImgFrames (a MonoCamera's output, or a host node's).

    ``control`` is the camera's control input queue (exposure), ``on_close`` releases
    the pipeline and device. ``size`` is (width, height) in pixels, ``bits`` the
    significant bits per pixel (8 for the MonoCamera's RAW8 output).
    """

    def __init__(self, reader: FrameReader, control: Any | None = None, rate_hz: float = 0.0,
                 *, on_close: Callable[[], None] | None = None,
                 size: tuple[int, int] | None = None, bits: int = 8) -> None:
        self.reader = reader
        self.control = control
        self.rate_hz = rate_hz
        self.size = size
        self.bits = bits
        self._on_close = on_close

    @property
    def dropped_sub_frames(self) -> int:
        """Sub-frames lost so far, from gaps in the sequence numbers."""
        return self.reader.dropped

    def _read(self, timeout_s: float) -> SubFrame:
        return self.reader.read(timeout_s)

    def set_exposure_us(self, exposure_us: float, iso: int = 400) -> None:
        """Manual exposure in microseconds (and sensitivity ISO) from the next frames on."""
        if exposure_us <= 0:
            raise ConfigError(f"exposure must be > 0 µs, got {exposure_us!r}")
        if self.control is None:
            logger.warning("this camera has no control queue; exposure not changed")
            return
        control = dai.CameraControl()
        control.setManualExposure(round(exposure_us), int(iso))
        self.control.send(control)

    def _close(self) -> None:
        if self._on_close is not None:
            self._on_close()


class DepthaiProjector(Projector):
    """The host side of the on-device strobe timeline.

    ``strobe(chip, sequence)`` records the commanded chip and writes it into the code
    slot ``sequence % code_length``; when the code changes, and at least every
    RENEW_FRAMES sub-frames (the Script's lease), the whole state is sent to the Script
    (``control`` queue). ``off()`` (and ``close()``) tells the Script to go dark and
    sets both emitter intensities to 0 on the device directly.
    """

    def __init__(self, control: Any | None, device: Any | None = None, code_length: int = 16,
                 intensity: float = 0.8, external: bool = False) -> None:
        self.control = control
        self.device = device
        self.external = external
        self.code = [0] * code_length
        self.intensity = check_intensity(intensity)
        self.enabled = False
        self.commanded: OrderedDict[int, int] = OrderedDict()
        self._renewed_at: int | None = None  # sequence of the last state sent while strobing

    def _send_state(self) -> None:
        if self.control is None:
            return
        buffer = dai.Buffer()
        buffer.setData(state_message(self.enabled, self.intensity, self.code))
        try:
            self.control.send(buffer)
        except (RuntimeError, dai.MessageQueue.QueueException) as exc:
            raise DriverError(f"strobe Script cannot be reached: {exc}") from exc

    def _remember(self, chip: int, sequence: int) -> None:
        self.commanded[sequence] = chip
        self.commanded.move_to_end(sequence)
        while len(self.commanded) > COMMAND_HISTORY:
            self.commanded.popitem(last=False)

    def _strobe(self, chip: int, sequence: int) -> None:
        self._remember(chip, sequence)
        slot = sequence % len(self.code)
        renewed = self._renewed_at
        due = renewed is None or not 0 <= sequence - renewed < RENEW_FRAMES
        if self.code[slot] != chip or not self.enabled or due:
            self.code[slot] = chip
            self.enabled = True
            self._send_state()
            self._renewed_at = sequence

    def set_code(self, chips: Sequence[int]) -> None:
        """Load a whole code (chip for ``sequence % N``) at once and start strobing it."""
        self.code = check_chips(chips)
        self.enabled = True
        self._send_state()
        self._lit = True

    def chip_for(self, sequence: int) -> int | None:
        """The chip commanded for ``sequence``: recorded, else the timeline's, else None."""
        if sequence in self.commanded:
            return self.commanded[sequence]
        if self.external:
            return None
        return self.code[sequence % len(self.code)] if self.enabled else 0

    def _off(self) -> None:
        """Script dark and both intensities 0; errors are logged, never raised."""
        self.enabled = False
        try:
            self._send_state()
        except DriverError:
            logger.exception("strobe Script not reached while switching off")
        if self.device is not None:
            switch_emitters_off(self.device)

    def set_intensity(self, fraction: float) -> None:
        """Lit level of the emitter, 0..1 of its maximum."""
        self.intensity = check_intensity(fraction)
        self._send_state()


def find_device(device_id: str = "") -> Any:
    """The ``dai.DeviceInfo`` to open; DeviceNotFoundError when none (or not that one)."""
    devices = dai.Device.getAllAvailableDevices()
    if not devices:
        raise DeviceNotFoundError("no OAK device attached (depthai found none on USB or the "
                                  "network); accepted: an OAK-D Pro, or driver 'sim' / 'replay'")
    if not device_id:
        return devices[0]
    for info in devices:
        if device_id in (info.getDeviceId(), info.name):
            return info
    found = ", ".join(f"{d.getDeviceId()} ({d.name})" for d in devices)
    raise DeviceNotFoundError(f"OAK device {device_id!r} not attached; found: {found}")


def _build_camera(pipeline: Any, settings: DepthaiSettings) -> Any:
    mono = pipeline.create(dai.node.MonoCamera)
    mono.setBoardSocket(dai.CameraBoardSocket.CAM_B)
    mono.setResolution(getattr(dai.MonoCameraProperties.SensorResolution,
                               RESOLUTIONS[settings.resolution]))
    mono.setFps(settings.rate_hz)
    if settings.exposure_us is not None:
        mono.initialControl.setManualExposure(int(settings.exposure_us), settings.iso)
    if settings.emitter == "external":
        mono.initialControl.setFrameSyncMode(dai.CameraControl.FrameSyncMode.INPUT)
    return mono


def _build_script(pipeline: Any, mono: Any, settings: DepthaiSettings) -> Any:
    script = pipeline.create(dai.node.Script)
    script.setProcessor(dai.ProcessorType.LEON_CSS)
    script.setScript(strobe_script([0] * settings.code_length, settings.emitter,
                                   settings.intensity), "atris_strobe")
    mono.frameEvent.link(script.inputs[EVENT_INPUT])
    return script.inputs[CONTROL_INPUT].createInputQueue(maxSize=4, blocking=False)


def build_device_pipeline(device: Any, settings: DepthaiSettings
                          ) -> tuple[Any, DepthaiCamera, DepthaiProjector]:
    """Create and start the device graph; return (pipeline, camera, projector)."""
    pipeline = dai.Pipeline(device)
    mono = _build_camera(pipeline, settings)
    frames = mono.out.createOutputQueue(maxSize=settings.queue_size, blocking=False)
    control = mono.inputControl.createInputQueue()
    external = settings.emitter == "external"
    strobe_control = None if external else _build_script(pipeline, mono, settings)
    projector = DepthaiProjector(strobe_control, device, settings.code_length,
                                 settings.intensity, external=external)
    pipeline.start()
    camera = DepthaiCamera(FrameReader(frames, projector.chip_for), control,
                           settings.rate_hz, on_close=lambda: _release(pipeline, device),
                           size=SIZES[settings.resolution])
    return pipeline, camera, projector


def switch_emitters_off(device: Any) -> None:
    """Set the dot projector and flood LED intensities to 0; failures are logged."""
    for step in (device.setIrLaserDotProjectorIntensity, device.setIrFloodLightIntensity):
        try:
            step(0.0)
        except RuntimeError:
            logger.exception("could not switch an IR emitter off")


def _release(pipeline: Any, device: Any) -> None:
    switch_emitters_off(device)
    pipeline.stop()
    device.close()


def open_backend(**settings: Any) -> tuple[DepthaiCamera, DepthaiProjector]:
    """Open the first (or ``device_id``) OAK; settings are the fields of DepthaiSettings."""
    try:
        checked = DepthaiSettings(**settings).check()
    except TypeError as exc:
        raise ConfigError(f"depthai settings: {exc}; accepted: "
                          f"{', '.join(DepthaiSettings.__dataclass_fields__)}") from exc
    info = find_device(checked.device_id)
    device = None
    try:
        device = dai.Device(info)
        _, camera, projector = build_device_pipeline(device, checked)
    except RuntimeError as exc:
        if device is not None:
            device.close()
        raise DriverError(f"OAK device {info.getDeviceId()} cannot be started: {exc}") from exc
    logger.info("OAK %s: %s at %.1f Hz, emitter %s", info.getDeviceId(), checked.resolution,
                checked.rate_hz, checked.emitter)
    return camera, projector
