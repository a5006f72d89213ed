"""The node: lifecycle over its components and the real-time loop that ties them.

Lifecycle (as rclpy's managed nodes): ``configure()`` opens the camera, projector, bus
services and pipeline with the laser off; ``activate()`` starts the loop; ``deactivate()``
stops it and switches the laser off; ``shutdown()`` releases everything. Every method is
safe to call more than once.

One sub-frame step of the loop::

    negotiation says may_strobe?  --no-->  laser off, window reset, status NEGOTIATING/NO_CODE
            | yes
    strobe chip[seq % N] for the next sub-frame, read it, push it to the demodulator
            | a distortion map is complete
    map thread (atris_node.node.worker): pipeline -> Measurement -> publisher
                                         (status + sectors + nearest)

With ``pipeline.worker = "thread"`` (the default, when the loop runs in its own thread) the
loop hands each complete map to the map thread and reads on; a measurement is published
only if the loop has not gone invalid since its map was complete (the loop's epoch). With
``"process"`` the map thread sends the pipeline pass to the map process
(atris_node.node.mapprocess) and waits for it. With ``"inline"``, and in ``step()`` /
``run_for()`` called directly, the map is measured in the loop.

The projector is off whenever the node is not demodulating: before activation, while the
code is not owned, on a camera fault, on deactivate/shutdown, and (through ``atexit`` and the
signal handlers of the CLI) when the process ends.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import can

from atris_node.adaptive.controller import controller_from_config
from atris_node.bus.can.publisher import Publisher
from atris_node.bus.canopen.device import CanopenDevice
from atris_node.codes import walsh_chips
from atris_node.config import Config
from atris_node.demod import PendingMap
from atris_node.errors import (
    AtrisError,
    BusError,
    CameraLostError,
    DemodulationError,
    DriverError,
    MapProcessLostError,
    NodeFaultError,
)
from atris_node.node import wiring
from atris_node.node.mapprocess import MapProcess
from atris_node.node.measure import Measurer
from atris_node.node.snapshot import write_snapshot
from atris_node.node.stats import NodeStats
from atris_node.node.status import compose_status, negotiated_status, unit_state
from atris_node.node.worker import MapThread
from atris_node.types import (
    FaultBits,
    Measurement,
    SubFrame,
    UnitStatus,
)
from drivers import Camera, Projector

logger = logging.getLogger(__name__)

#: seconds between reconnection attempts after a camera loss (doubles up to the cap)
RECONNECT_BACKOFF_S = (0.1, 2.0)
#: how long deactivate() waits for the loop to end (a camera read may hang longer)
LOOP_JOIN_TIMEOUT_S = 5.0
#: maps in a row the pipeline may raise on before the unit takes it for broken (FAULT)
PIPELINE_ERROR_LIMIT = 3


class Lifecycle:
    """Lifecycle states of a node."""

    UNCONFIGURED = "unconfigured"
    INACTIVE = "inactive"
    ACTIVE = "active"
    FINALIZED = "finalized"


class Unit:
    """One sensor unit: camera + projector + demodulator + pipeline + bus services."""

    def __init__(
        self,
        config: Config,
        bus: can.BusABC,
        open_backend: Callable[..., tuple[Camera, Projector]] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config
        self.bus = bus
        self.clock = clock
        self.lifecycle = Lifecycle.UNCONFIGURED
        self.stats = NodeStats()
        self.faults = FaultBits.NONE
        self._open_backend = open_backend
        self._camera: Camera | None = None
        self._projector: Projector | None = None
        self._measure: Measurer | None = None
        self._publisher: Publisher | CanopenDevice | None = None
        self._negotiator: Any = None
        self._services: wiring.BusServices | None = None
        self._thread: threading.Thread | None = None
        self._maps: MapThread | None = None
        self._stop = threading.Event()
        #: the loop's epoch: a new one whenever it publishes invalid distances or stops;
        #: a measurement of an older epoch is not published
        self._epoch = 0
        self._publish_lock = threading.Lock()
        self._fatal: BaseException | None = None
        self._next_seq: int | None = None
        self._counter = 0
        self._output_errors = 0  # the output's refused frames, as last seen
        self._output_sent = 0  # and its frames taken
        self._lapses = 0  # the projector's lapses, as last seen
        self._pipeline_errors_in_row = 0
        #: called with every measurement handed to the publisher (benchmarks, views)
        self.on_measurement: Callable[[Measurement], None] | None = None

    # ----------------------------------------------------------------- lifecycle
    def configure(self) -> None:
        """Open every component with the laser off (and start the map process with
        ``pipeline.worker = "process"``).

        Raises:
            MapProcessLostError: the map process did not start.
        """
        if self.lifecycle != Lifecycle.UNCONFIGURED:
            return
        self._camera, self._projector = self._open_driver()
        pipeline: Any = wiring.make_pipeline(self.config, self._camera)
        if self.config["pipeline.worker"] == "process":
            pipeline = MapProcess(pipeline, name=f"atris-map-process-{self.label}")
        self._services = wiring.make_bus_services(self.config, self.bus)
        self._publisher = wiring.make_output(self.config, self.bus, self._services, self.clock)
        self._negotiator = wiring.make_negotiator(self.config, self.bus, self._camera,
                                                  self._services, self.clock)
        self._negotiator.on_change = self._on_negotiation_change
        self._publisher.status_at_send = self._status_at_send
        wiring.connect_output(self._publisher, self._negotiator, self.config)
        adaptive = controller_from_config(self.config,
                                          float(getattr(self._camera, "rate_hz", 0.0)))
        self._measure = Measurer(self.config, pipeline, adaptive, self._negotiator, self.stats,
                                 self.clock)
        self._start_map_process()  # its start-up (seconds) belongs here, not in activate()
        self.lifecycle = Lifecycle.INACTIVE
        logger.info("unit %s configured", self.label)

    def activate(self, threaded: bool = True) -> None:
        """Start the bus services and the real-time loop (in a thread by default).

        Raises:
            NodeFaultError: the loop of the previous activation has not ended yet (it hangs,
                e.g. in a camera read): a second loop beside it would strobe and read the
                same devices. The laser stays off and the state says FAULT until it ended.
            MapProcessLostError: the map process (``pipeline.worker = "process"``) did not
                start; the unit stays inactive, the laser off.
        """
        if self.lifecycle != Lifecycle.INACTIVE:
            return
        self._refuse_beside_old_loop()
        self._start_map_process()
        self._stop.clear()
        assert self._publisher is not None
        self._publisher.start()
        self._negotiator.start()
        self.lifecycle = Lifecycle.ACTIVE
        if threaded and self.config["pipeline.worker"] != "inline":
            self._maps = MapThread(self._measure_map, self._on_map_thread_error,
                                   name=f"atris-maps-{self.label}")
            self._maps.start()
        if threaded:
            self._thread = threading.Thread(target=self._guarded_loop,
                                            name=f"atris-unit-{self.label}", daemon=True)
            self._thread.start()

    def _start_map_process(self) -> None:
        """Start the map process when the unit has one (configure), or again when it died
        (activate)."""
        assert self._measure is not None
        if isinstance(self._measure.pipeline, MapProcess):
            self._measure.pipeline.start()

    def deactivate(self) -> None:
        """Stop the loop and the bus services: laser off, the loop stopped (and the laser
        off again, in case the loop lit it on its way out), the code released, then a
        final frame with state STOPPED and invalid distances."""
        if self.lifecycle != Lifecycle.ACTIVE:
            return
        self._stop.set()
        self._laser_off()
        self._join_loop()
        self._stop_map_thread()
        self._laser_off()
        self._negotiator.stop()
        assert self._publisher is not None
        self._publisher.stop()
        self.lifecycle = Lifecycle.INACTIVE

    def _join_loop(self) -> None:
        """Wait for the loop thread to end; one that hangs is kept (activate() refuses to
        start another beside it) and reported."""
        if self._thread is None:
            return
        self._thread.join(timeout=LOOP_JOIN_TIMEOUT_S)
        if self._thread.is_alive():
            logger.error("unit %s: the loop did not stop within %.1f s", self.label,
                         LOOP_JOIN_TIMEOUT_S)
        else:
            self._thread = None

    def _old_loop_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _refuse_beside_old_loop(self) -> None:
        """Raise NodeFaultError while the previous activation's loop still runs: laser
        off, FAULT on the bus (the output runs to say so until shutdown or activation)."""
        if not self._old_loop_alive():
            self._thread = None
            return
        self._laser_off()
        assert self._publisher is not None
        self._publisher.start()
        self._publish_fault()
        raise NodeFaultError(f"unit {self.label}: the loop of the previous activation has not "
                             "ended (a camera read that hangs?); not activated")

    def shutdown(self) -> None:
        """Deactivate and release everything; safe to call more than once."""
        self.deactivate()
        if self._publisher is not None:  # it reports FAULT after a refused activate()
            self._publisher.stop()
        self._laser_off()
        if self._measure is not None and isinstance(self._measure.pipeline, MapProcess):
            self._measure.pipeline.close()
        for part in (self._projector, self._camera):
            if part is not None:
                part.close()
        if self._services is not None:
            self._services.stop()
        self.lifecycle = Lifecycle.FINALIZED

    def check(self) -> None:
        """Re-raise a fatal error stored by the loop thread or a bus service."""
        if self._fatal is not None:
            raise NodeFaultError(f"unit {self.label} stopped: {self._fatal}") from self._fatal
        for service in (self._publisher, self._negotiator):
            if service is not None and hasattr(service, "check"):
                service.check()

    @property
    def label(self) -> str:
        return str(self.config["unit.label"])

    @property
    def last_result(self) -> Any:
        """The newest PipelineResult, or None."""
        return None if self._measure is None else self._measure.last_result

    @property
    def measure(self) -> Measurer | None:
        """The per-map work (demodulator, pipeline, adaptation); None before configure()."""
        return self._measure

    @property
    def camera(self) -> Camera | None:
        return self._camera

    @property
    def projector(self) -> Projector | None:
        return self._projector

    @property
    def negotiator(self) -> Any:
        return self._negotiator

    @property
    def publisher(self) -> Any:
        """The unit's output: the DBC cycle Publisher or the CanopenDevice."""
        return self._publisher

    def _open_driver(self) -> tuple[Camera, Projector]:
        """Camera and projector, the laser off; the projector takes a strobe only while the
        negotiation permits it and goes dark by itself when the loop stops strobing."""
        return wiring.open_driver(self.config, self._open_backend, self._may_light, self.clock)

    def _may_light(self) -> bool:
        return self._negotiator is not None and bool(self._negotiator.may_strobe)

    def _on_negotiation_change(self, *change: object) -> None:
        """The negotiation changed (state, row or plan), in whatever thread it learnt it:
        the laser goes off at once when it may no longer strobe, not at the next sub-frame
        (the loop may be blocked in a camera read), and the output sends a cycle at once
        (its status is checked against the negotiation at send time)."""
        if not self._may_light():
            self._laser_off()
            send_now = getattr(self._publisher, "send_now", None)
            if send_now is not None:  # the DBC cycle says so at once, not a period later
                send_now()

    def _status_at_send(self, status: UnitStatus) -> UnitStatus:
        """The status the output hands to the bus: the state and code row as the
        negotiation stands at send time (a loop blocked in a camera read cannot report
        the code lost), not as the loop last saw it."""
        return negotiated_status(status, self._negotiator)

    # ----------------------------------------------------------------- the loop
    def _guarded_loop(self) -> None:
        try:
            while not self._stop.is_set():
                self.step()
        except Exception as exc:  # stored and re-raised by check(); the laser goes off
            logger.exception("unit %s loop failed", self.label)
            self._fatal = exc
        if self._fatal is not None:  # the loop's own error, or the map thread's
            self._laser_off()
            self._publish_fault()

    def _on_map_thread_error(self, exc: BaseException) -> None:
        """The map thread failed: stored for check(), the loop stopped, laser off, FAULT."""
        self._fatal = exc
        self._stop.set()
        self._laser_off()
        self._publish_fault()

    def _stop_map_thread(self) -> None:
        """A new epoch (nothing measured from now on is published), then the thread ends."""
        with self._publish_lock:
            self._epoch += 1
        if self._maps is not None:
            self.stats.maps_skipped = self._maps.skipped
            self._maps.stop()
            self._maps = None

    def _publish_fault(self) -> None:
        """After the loop died: state FAULT and invalid distances on the bus at once."""
        try:
            self._publish(None)
        except Exception:
            logger.exception("unit %s: the FAULT state could not be published", self.label)

    def run_for(self, duration_s: float) -> None:
        """Run the loop in the calling thread for ``duration_s`` seconds."""
        end = self.clock() + duration_s
        while self.clock() < end and not self._stop.is_set():
            self.step()

    def step(self) -> None:
        """One sub-frame: negotiate, strobe, read, demodulate, measure, publish."""
        self._watch_output()
        self._tick_negotiation()
        self._apply_exposure_request()
        allowed = bool(self._negotiator.may_strobe)
        chips = self._strobe_next(self._chips() if allowed else None)
        if chips is None:
            self._laser_off()
        try:
            sub = self._read()
        except CameraLostError as exc:
            self._on_camera_lost(exc)
            return
        self._record_strobe(allowed)
        assert self._measure is not None
        self._measure.last_sub = sub
        if self.faults & FaultBits.CAMERA_LOST:
            self.faults &= ~FaultBits.CAMERA_LOST
            self._emcy("emcy_reset")
        self.stats.sub_frames += 1
        lapsed = self._strobe_lapsed()
        pending = self._demodulate(sub) if chips is not None and not lapsed else None
        if pending is not None:
            self.faults &= ~FaultBits.DEADLINE_MISS  # a whole window kept its strobe
            self._on_map(pending)
        elif chips is None:
            self._publish(None)
        elif self._maps is None or self._maps.idle:
            # progress: the loop is alive between maps; while the map thread measures,
            # its publishing is the progress (a hung pipeline makes the output FAULT)
            assert self._publisher is not None
            self._publisher.heartbeat()

    def _apply_exposure_request(self) -> None:
        """Set the exposure the adaptation asked for, between two reads (never from the
        map thread while the loop reads)."""
        request = None if self._measure is None else self._measure.take_exposure_request()
        if request is not None and self._camera is not None:
            self._camera.set_exposure_us(request)

    def _tick_negotiation(self) -> None:
        """Advance the negotiation; a receive error it reports (the laser is already off:
        the negotiator went back to CLAIMING) is logged and counted, and the loop goes on:
        a link that flaps must not end the unit."""
        try:
            self._negotiator.tick()
        except BusError as exc:
            self.stats.bus_errors += 1
            logger.error("unit %s: %s", self.label, exc)

    def _watch_output(self) -> None:
        """The bus refused one of our distance frames: nobody may hear our claim either,
        so the negotiator takes the strobe permission back until it is heard again."""
        errors = int(getattr(self._publisher, "send_errors", 0))
        sent = int(getattr(self._publisher, "frames_sent", 0))
        if errors > self._output_errors:
            self._negotiator.report_send_failure()
        elif sent > self._output_sent:
            self._negotiator.report_send_ok()
        self._output_errors, self._output_sent = errors, sent

    def _strobe_next(self, chips: Any) -> Any:
        """Command the next sub-frame's chip; the chips, or None (laser off, LASER_FAULT,
        the window restarted) when the projector refused: a sub-frame whose chip is not
        known must not be demodulated."""
        projector = self._projector
        if chips is None or projector is None or self._next_seq is None:
            return chips
        try:
            projector.strobe(int(chips[self._next_seq % len(chips)]), self._next_seq)
        except DriverError as exc:
            self._on_laser_fault(exc)
            return None
        if not projector.is_lit:  # the permission went between asking and strobing
            return None
        if self.faults & FaultBits.LASER_FAULT:
            logger.info("unit %s: the projector takes commands again", self.label)
            self.faults &= ~FaultBits.LASER_FAULT
        return chips

    def _on_laser_fault(self, exc: DriverError) -> None:
        """The projector refused a command: laser off, LASER_FAULT, EMCY, window restarted."""
        if not self.faults & FaultBits.LASER_FAULT:
            logger.error("unit %s: projector fault: %s", self.label, exc)
            self._emcy("emcy_laser_fault")
        self.faults |= FaultBits.LASER_FAULT
        self.stats.laser_faults += 1
        self._laser_off()
        if self._measure is not None:
            self._measure.reset()

    def _strobe_lapsed(self) -> bool:
        """True when the projector went dark by itself since the last sub-frame (no strobe
        for its lease: the loop stalled): this sub-frame may have been exposed dark, so
        the window restarts without it, and the status says DEADLINE_MISS until a window
        completes (a loop starved on every sub-frame never measures; without the bit its
        status would only say NEGOTIATING or RUNNING)."""
        lapses = int(getattr(self._projector, "lapses", 0))
        if lapses == self._lapses:
            return False
        self._lapses = lapses
        self.stats.strobe_lapses += 1
        self.faults |= FaultBits.DEADLINE_MISS  # until a window completes without a lapse
        logger.warning("unit %s: the loop stalled, the projector went dark; window restarted",
                       self.label)
        if self._measure is not None:
            self._measure.reset()
        return True

    def _read(self) -> SubFrame:
        assert self._camera is not None
        sub = self._camera.read(timeout_s=1.0)
        self._next_seq = sub.sequence + 1
        return sub

    def _record_strobe(self, allowed: bool) -> None:
        lit = bool(self._projector is not None and self._projector.is_lit)
        self.stats.record_strobe(self.clock(), lit, allowed, self._negotiator.code_row)

    def _chips(self) -> Any:
        row = self._negotiator.code_row
        plan = self._negotiator.plan
        if row is None:
            return None
        key = (int(plan.code_length), int(row))
        assert self._measure is not None
        if key != self._measure.key:
            try:
                self._new_code(key)
            except DriverError as exc:  # the device did not take the code: tried again
                self._on_laser_fault(exc)
                return None
        return walsh_chips(*key)

    def _new_code(self, key: tuple[int, int]) -> None:
        """Demodulate code ``key`` = (N, row) from now on; the device strobes it too (first:
        a device that refuses it leaves the demodulator on the old code)."""
        assert self._measure is not None
        set_code = getattr(self._projector, "set_code", None)
        if set_code is not None:  # backends that strobe on the device (depthai Script)
            set_code(walsh_chips(*key))
        self._measure.set_code(key, int(getattr(self._camera, "bits", 8)))
        logger.info("unit %s: code row %d of N=%d", self.label, key[1], key[0])

    def _demodulate(self, sub: SubFrame) -> PendingMap | None:
        assert self._measure is not None
        try:
            return self._measure.demodulate(sub)
        except DemodulationError as exc:
            self._on_bad_sub_frame(exc)
            return None

    def _on_map(self, pending: PendingMap) -> None:
        if self._maps is None:
            self._measure_map(pending, self._epoch)
            return
        self._maps.submit(pending, self._epoch)
        self.stats.maps_skipped = self._maps.skipped

    def _measure_map(self, pending: PendingMap, epoch: int) -> None:
        """Take the map (complete in the loop's ``epoch``: built and its gain measured
        here), measure it and publish it (the map thread, or the loop itself without
        one)."""
        assert self._measure is not None
        try:
            measurement = self._measure.measure(pending.take(), self._camera)
        except MapProcessLostError:  # no map can be measured any more: the unit stops
            raise
        except Exception as exc:
            self._on_pipeline_error(exc)
            return
        self._pipeline_errors_in_row = 0
        self._publish(measurement, epoch)

    def _on_pipeline_error(self, exc: Exception) -> None:
        """The pipeline raised on one map: that map's distances go out invalid (a new
        epoch), the error is logged with its traceback and counted, and the unit goes on:
        a fault that one scene's data trigger must not blind the vehicle for good. The
        ``PIPELINE_ERROR_LIMIT``-th map in a row that fails re-raises: a pipeline that
        fails on every map is broken, and the unit stops (laser off, FAULT)."""
        self.stats.pipeline_errors += 1
        self._pipeline_errors_in_row += 1
        if self._pipeline_errors_in_row >= PIPELINE_ERROR_LIMIT:
            raise exc
        logger.error("unit %s: the pipeline failed on a map (%d in a row), its distances "
                     "are sent invalid: %s", self.label, self._pipeline_errors_in_row, exc,
                     exc_info=exc)
        self._publish(None)

    def _on_bad_sub_frame(self, exc: DemodulationError) -> None:
        """A sub-frame that cannot be demodulated: drop it, restart the window, go invalid."""
        self.stats.bad_sub_frames += 1
        logger.warning("unit %s: sub-frame rejected: %s", self.label, exc)
        assert self._measure is not None
        self._measure.reset()
        self._publish(None)

    def _on_camera_lost(self, exc: AtrisError) -> None:
        """Camera fault: laser off, invalid distances, reconnect with back-off."""
        self._laser_off()
        if not self.faults & FaultBits.CAMERA_LOST:
            self._emcy("emcy_camera_lost")
        self.faults |= FaultBits.CAMERA_LOST
        self.stats.camera_faults += 1
        logger.warning("unit %s: camera lost: %s", self.label, exc)
        self._publish(None)
        if self._measure is not None:
            self._measure.reset()
        self._next_seq = None
        self._reconnect()

    def _reconnect(self) -> None:
        delay = RECONNECT_BACKOFF_S[0] * 2 ** min(self.stats.camera_faults - 1, 5)
        self._stop.wait(min(delay, RECONNECT_BACKOFF_S[1]))
        try:
            if self._camera is not None:
                self._camera.close()
            self._camera, projector = self._open_driver()
        except AtrisError as exc:
            logger.warning("unit %s: reconnect failed: %s", self.label, exc)
            return
        if self._projector is not None:
            self._projector.close()
        self._projector = projector
        self._projector.off()
        self._lapses = 0
        self.stats.reconnects += 1

    def _emcy(self, name: str) -> None:
        """Send a CANopen EMCY (CANopen mode only; the DBC frames carry fault bits)."""
        send = getattr(self._publisher, name, None)
        if send is not None:
            send()

    def _laser_off(self) -> None:
        if self._projector is not None:
            try:
                self._projector.off()
            except DriverError as exc:  # off() of the shipped backends never raises
                logger.error("unit %s: projector did not take off(): %s", self.label, exc)

    def truth_sector_distances(self) -> tuple[float | None, ...] | None:
        """The simulator's true sector distances for the newest map, or None (hardware)."""
        work = self._measure
        return None if work is None else work.truth_sector_distances(self._camera)

    def snapshot(self, directory: str | Path) -> list[Path]:
        """Write the newest plain sub-frame, distortion map and top-down obstacle map."""
        if self._measure is None:
            return write_snapshot(directory, self.label, None, None, None)
        return self._measure.snapshot(directory, self.label,
                                      float(self.config["pipeline.z_max_m"]))

    # ----------------------------------------------------------------- output
    def status(self) -> UnitStatus:
        """The content of the status frame now."""
        loop_failed = self._fatal is not None or (
            self.lifecycle != Lifecycle.ACTIVE and self._old_loop_alive())
        state = unit_state(self.faults, loop_failed, self._negotiator)
        return compose_status(state, self.faults, self._negotiator, self._measure,
                              float(getattr(self._camera, "rate_hz", 0.0)), self._counter,
                              self.stats)

    def _publish(self, measurement: Measurement | None, epoch: int | None = None) -> None:
        """Hand ``measurement`` (None: distances invalid, a new epoch) to the output; a
        measurement of an epoch that is over is not handed (``stats.stale_maps``)."""
        assert self._publisher is not None
        with self._publish_lock:
            if measurement is None:
                self._epoch += 1
            elif epoch is not None and epoch != self._epoch:
                self.stats.stale_maps += 1
                return
            else:
                self._counter += 1
                measurement = replace(measurement, counter=self._counter)
                if self.on_measurement is not None:
                    self.on_measurement(measurement)
            self._publisher.update(measurement, self.status())

