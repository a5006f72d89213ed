"""The ``sim`` backend: a camera and a projector sharing one :class:`atris_node.sim.Simulator`.

Timing: the simulated clock is ``sequence / rate_hz`` (device time = exposure mid-time).
Host times are the host clock when a sub-frame is handed over (its arrival, as a real
driver stamps it); simulated time 0 is ``time_origin_s`` on that clock, and with
``realtime=True`` a read sleeps until ``time_origin_s + sequence / rate_hz``. A
:class:`SimulatedClock` given to :func:`open_backend` replaces the host clock with the
simulated time of the sub-frames handed out: a unit stepped as fast as the machine allows
(a benchmark, a test) then runs its timers (contest windows, time-outs, data age) on it and
does the same thing, sub-frame for sub-frame, however fast or loaded the machine is.

The projector's ``strobe(chip, seq)`` sets the chip of sub-frame ``seq + lag_sub_frames``
(depthai's "next frame" habit with ``lag_sub_frames=1``); a chip holds until the next
command; ``off()`` darkens at once and drops pending commands. Every rendered sub-frame
appends ``(sequence, start_time_s, chip_emitted)`` to ``projector.strobe_log``. The
SubFrame's ``chip`` is the chip commanded for that sequence (None if none was), as real
hardware reports it; what was emitted is in the log.

Fault injection for tests: ``camera.drop(n)`` skips the next n sequence numbers,
``camera.disconnect()`` makes reads raise CameraLostError until ``camera.reconnect()``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from atris_node.calibration import Calibration
from atris_node.errors import CameraLostError, ConfigError
from atris_node.mounting import Mounting
from atris_node.sim import Scene, Simulator, load_scene
from atris_node.sim.strobe import Strobe, log_strobe
from atris_node.types import SubFrame
from drivers.base import Camera, Projector

logger = logging.getLogger(__name__)
#: strobe log entries kept (the oldest half is dropped beyond this)
LOG_LIMIT = 100_000


class SimProjector(Projector):
    """The simulated projector: a chip schedule by sequence number and a strobe log."""

    def __init__(self, simulator: Simulator, lag_sub_frames: int = 0) -> None:
        if lag_sub_frames < 0:
            raise ConfigError(f"lag_sub_frames must be >= 0, got {lag_sub_frames}")
        self.simulator = simulator
        self.lag_sub_frames = lag_sub_frames
        self.strobe_log: list[tuple[int, float, int]] = []
        self.commanded: dict[int, int] = {}
        self._pending: dict[int, int] = {}
        self._chip = 0

    def _strobe(self, chip: int, sequence: int) -> None:
        self.commanded[sequence] = chip
        self._pending[sequence + self.lag_sub_frames] = chip

    def _off(self) -> None:
        self._pending.clear()
        self._chip = 0

    def emit(self, sequence: int) -> int:
        """The chip emitted during sub-frame ``sequence`` (logged); 0 when off or closed."""
        due = [s for s in self._pending if s <= sequence]
        if due:
            self._chip = self._pending[max(due)]
            for s in due:
                del self._pending[s]
        chip = self._chip if (self._lit and not self._closed) else 0
        self.strobe_log.append((sequence, self.simulator.window(sequence)[0], chip))
        if len(self.strobe_log) > LOG_LIMIT:
            del self.strobe_log[: LOG_LIMIT // 2]
        return chip

    def commanded_chip(self, sequence: int) -> int | None:
        """The chip commanded for ``sequence`` (popped), or None."""
        return self.commanded.pop(sequence, None)

    def strobe_function(self) -> Strobe:
        """This projector's emissions as a strobe other simulated units can attach."""
        return log_strobe(self.strobe_log, self.simulator.exposure_us * 1e-6)


class SimulatedClock:
    """Simulated time, s: the end of the newest sub-frame the attached camera handed out
    (``sub-frames read / rate_hz``; 0.0 before a camera is attached). Call it for the time.

    Example:
        >>> clock = SimulatedClock()
        >>> clock()
        0.0
    """

    def __init__(self) -> None:
        self.camera: SimCamera | None = None

    def __call__(self) -> float:
        camera = self.camera
        return 0.0 if camera is None else camera.sub_frames_read / camera.rate_hz


class SimCamera(Camera):
    """The simulated camera: renders sub-frame after sub-frame with the projector's chips."""

    def __init__(self, simulator: Simulator, projector: SimProjector, realtime: bool = False,
                 sleep: Callable[[float], None] = time.sleep,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.simulator = simulator
        self.projector = projector
        self.realtime = realtime
        self.rate_hz = simulator.rate_hz
        self.size = (simulator.camera.width_px, simulator.camera.height_px)
        self.bits = simulator.camera.bits
        self.mounting: Mounting = simulator.mounting
        self._sleep, self._clock = sleep, clock
        self._host_offset_s = clock()
        self._sequence = 0
        self._connected = True

    def _read(self, timeout_s: float) -> SubFrame:
        if self._closed or not self._connected:
            raise CameraLostError("simulated camera is disconnected"
                                  if not self._closed else "simulated camera is closed")
        sequence = self._sequence
        self._sequence += 1
        host_time = self.simulator.window(sequence)[0] + self._host_offset_s
        if self.realtime:
            delay = host_time - self._clock()
            if delay > 0:
                self._sleep(delay)
        sub = self.simulator.render(sequence, self.projector.emit(sequence))
        # host time = arrival on the host clock, as a real camera's driver stamps it
        return replace(sub, host_time_s=self._clock(),
                       chip=self.projector.commanded_chip(sequence))

    @property
    def sub_frames_read(self) -> int:
        """Sub-frames handed out or dropped so far (the next sequence number)."""
        return self._sequence

    @property
    def time_origin_s(self) -> float:
        """Host ``time.monotonic()`` at simulated time 0 (sub-frame 0's exposure start)."""
        return self._host_offset_s

    def factory_calibration(self) -> Calibration:
        """The simulator's true calibration."""
        return self.simulator.calibration()

    def set_exposure_us(self, exposure_us: float) -> None:
        """Change the exposure of the following sub-frames."""
        self.simulator.set_exposure_us(exposure_us)

    def drop(self, count: int = 1) -> None:
        """Fault injection: the next ``count`` sub-frames are lost (sequence gap)."""
        for sequence in range(self._sequence, self._sequence + count):
            self.projector.emit(sequence)
        self._sequence += count

    def disconnect(self) -> None:
        """Fault injection: reads raise CameraLostError until :meth:`reconnect`."""
        self._connected = False

    def reconnect(self) -> None:
        """Undo :meth:`disconnect`; sequence numbers continue."""
        self._connected = True


def open_backend(scene: str | Scene, seed: int | None = None, *, lag_sub_frames: int = 0,
                 rate_hz: float | None = None, realtime: bool = False, unit: int = 0,
                 exposure_us: float | None = None, clock: SimulatedClock | None = None,
                 **kw: Any) -> tuple[SimCamera, SimProjector]:
    """A simulated camera and projector for ``scene`` (a Scene, a shipped name or a path).

    ``rate_hz`` overrides the scene's sub-frame rate; ``clock`` (not with ``realtime``)
    is attached to the camera, whose host times are then simulated time; unknown settings
    are rejected.
    """
    if kw:
        raise ConfigError(f"sim driver: unknown settings {sorted(kw)}; accepted: scene, seed, "
                          "lag_sub_frames, rate_hz, realtime, unit, exposure_us, clock")
    if clock is not None and realtime:
        raise ConfigError("sim driver: a simulated clock cannot pace a realtime camera; "
                          "give clock or realtime=True, not both")
    loaded = scene if isinstance(scene, Scene) else load_scene(scene)
    if rate_hz is not None:
        loaded = replace(loaded, camera=replace(loaded.camera, rate_hz=float(rate_hz)))
    simulator = Simulator(loaded, seed=seed, unit=unit)
    if exposure_us is not None:
        simulator.set_exposure_us(exposure_us)
    projector = SimProjector(simulator, lag_sub_frames)
    logger.info("sim driver: scene %s, unit %d, %.0f Hz", loaded.name, unit, simulator.rate_hz)
    if clock is None:
        return SimCamera(simulator, projector, realtime=realtime), projector
    camera = SimCamera(simulator, projector, clock=clock)
    clock.camera = camera
    return camera, projector
