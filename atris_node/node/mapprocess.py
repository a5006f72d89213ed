"""The map process: each map's pipeline pass in a child process, beside the camera loop.

With ``pipeline.worker = "process"`` the unit's pipeline is a :class:`MapProcess`: it
stands in for the :class:`~atris_node.pipeline.chain.Pipeline` (same ``process`` and
attributes), and runs the pass in a child process with its own interpreter and GIL, so
the camera loop's demodulation and the pipeline's Python glue run on two cores instead of
taking turns. The rest stays in the unit: the map thread (:mod:`atris_node.node.worker`:
newest map wins, epochs) calls ``process`` and waits for the answer with the GIL
released, then adapts and publishes; the camera, the demodulator and the adaptation never
leave the unit.

The child keeps the pipeline's state across maps (counter, closing-speed tracker, ground
plane, ROI). A map reaches it through shared memory (:mod:`atris_node.node.shared`: values
and saturation mask written once per measured map) and a small notice down a pipe. The
map's raw sub-frames stay in the unit: when the pipeline reads their time course at its
peaks (:func:`~atris_node.pipeline.temporal.window_series`) the child sends the peaks'
pixel indices up the pipe and the unit answers with their values (a few thousand pixels
of N + 1 frames, instead of copying 76 MB per map at 2048x1088). The
:class:`~atris_node.pipeline.chain.PipelineResult` comes back whole (~0.2-0.3 MB pickled:
the samples and points the adaptation, the snapshots and the benchmarks read).

Failures:
- the pipeline raising in the child: :class:`~atris_node.errors.MapProcessError` with the
  child's traceback, handled as a pipeline error in the map thread (that map invalid,
  ``PIPELINE_ERROR_LIMIT`` in a row stop the unit);
- the child ending (pipe EOF), or a pipe operation with it (a request sent, an answer
  received whole) not finished within ``deadline_s`` (the child is then killed):
  :class:`~atris_node.errors.MapProcessLostError`, after which every ``process`` raises it
  too; the unit stops at once (laser off, FAULT) as for a map thread that dies.

The child is started with "spawn" (a fresh interpreter: forking a process that runs
python-can notifier threads and numba's thread pool is not safe), ignores SIGINT (the
unit stops it), and ends when its pipe closes, so it does not outlive the unit.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any, NoReturn

import numpy as np

from atris_node.errors import ConfigError, MapProcessError, MapProcessLostError
from atris_node.node.shared import MapNotice, Segment, map_bytes, notice_of
from atris_node.pipeline.chain import Pipeline, PipelineResult
from atris_node.pipeline.temporal import window_series
from atris_node.types import DistortionMap, WindowFrames

logger = logging.getLogger(__name__)

#: seconds a map may take in the child before it is taken for hung (killed, FAULT)
MAP_DEADLINE_S = 2.0
#: seconds the child may take to start (imports, compiled kernels from numba's cache)
START_TIMEOUT_S = 120.0
#: seconds the child has to end after it was asked to, before it is killed
STOP_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class PipelineParts:
    """What the child builds its Pipeline from."""

    config: Any
    calibration: Any
    mounting: Any
    layout: Any


class MapProcess:
    """The pipeline of one unit, run in a child process (module docstring).

    Args:
        pipeline: the unit's pipeline; its parts (config, calibration, mounting, layout)
            build the child's, and its attributes are read here.
        deadline_s: seconds one map may take in the child.
        name: the child's process name.
    """

    def __init__(self, pipeline: Pipeline, deadline_s: float = MAP_DEADLINE_S,
                 name: str = "atris-map-process") -> None:
        self.config = pipeline.config
        self.calibration = pipeline.calibration
        self.mounting = pipeline.mounting
        self.layout = pipeline.layout
        self.bands = pipeline.bands
        self.deadline_s = deadline_s
        self._name = name
        self._parts = PipelineParts(pipeline.config, pipeline.calibration, pipeline.mounting,
                                    pipeline.layout)
        self._process: BaseProcess | None = None
        self._conn: Connection | None = None
        self._map: Segment | None = None
        self._lost: str | None = None
        self._guard: Watchdog | None = None  # made at the first pipe operation
        #: seconds the last start took (spawn, imports, the child's Pipeline)
        self.start_s: float | None = None
        #: times the child asked for the window's values at its peaks
        self.series_requests = 0

    # ----------------------------------------------------------------- lifecycle
    @property
    def alive(self) -> bool:
        return self._process is not None and self._process.is_alive() and self._lost is None

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    def start(self) -> None:
        """Start the child (a no-op while it runs); waits until its pipeline is built.

        Raises:
            MapProcessLostError: it could not be started, or did not start within
                START_TIMEOUT_S.
        """
        if self.alive:
            return
        self.close()
        started = time.monotonic()
        cam = self.calibration.camera
        self._map = Segment.create(map_bytes(cam.height_px, cam.width_px))
        context = multiprocessing.get_context("spawn")
        self._conn, child_end = context.Pipe()
        self._process = context.Process(target=serve, args=(child_end, self._parts,
                                                            self._map.name),
                                        name=self._name, daemon=True)
        try:
            with _one_blas_thread():
                self._process.start()
        except (OSError, RuntimeError) as exc:  # no interpreter, a main module spawn refuses
            self._process = None  # never started: nothing to join
            child_end.close()
            self.close()  # the pipe and the segment go
            self._lost = f"could not start: {exc}"
            raise MapProcessLostError(f"{self._name} {self._lost}") from exc
        child_end.close()
        self._lost = None
        try:
            self._expect_ready()
        except MapProcessLostError:
            self.close()  # the segment goes, the child is reaped
            raise
        self.start_s = time.monotonic() - started
        logger.info("%s (pid %s) started in %.2f s", self._name, self.pid, self.start_s)

    def _expect_ready(self) -> None:
        assert self._conn is not None
        try:
            ready = self._conn.poll(START_TIMEOUT_S) and self._conn.recv() == ("ready", None)
        except (EOFError, OSError):
            ready = False
        if not ready:
            self._fail(f"did not start (within {START_TIMEOUT_S:.0f} s)")

    def close(self) -> None:
        """Ask the child to end, wait for it (kill it after STOP_TIMEOUT_S), unlink the
        shared memory; safe to call more than once."""
        process, conn = self._process, self._conn
        self._process, self._conn = None, None
        if conn is not None:
            with contextlib.suppress(OSError):  # the child may be gone already
                conn.send(None)
        if process is not None:
            _end(process)
        if conn is not None:
            conn.close()
        if self._map is not None:
            self._map.close()
        self._map = None
        if self._guard is not None:
            self._guard.stop()
        self._guard = None

    # ----------------------------------------------------------------- maps
    def process(self, dmap: DistortionMap) -> PipelineResult:
        """The child's PipelineResult of ``dmap``.

        Raises:
            MapProcessError: the pipeline raised in the child.
            MapProcessLostError: the child is gone or did not answer in time.
        """
        if self._lost is not None or self._conn is None:
            raise MapProcessLostError(f"{self._name} is not running ({self._lost or 'stopped'})")
        self._send(self._write(dmap))
        while True:
            kind, payload = self._receive()
            if kind == "series":  # the window's values at the peaks, read here
                assert dmap.window is not None
                self.series_requests += 1
                self._send(window_series(dmap.window, payload))
            elif kind == "error":
                raise MapProcessError(f"the pipeline failed in {self._name}: {payload}")
            else:
                result: PipelineResult = payload
                return result

    def _send(self, message: Any) -> None:
        assert self._conn is not None
        with self._watchdog() as overdue:
            try:
                self._conn.send(message)
            except OSError:
                self._fail(self._late(overdue) or "its pipe is closed")
        self._raise_if(overdue)

    def _receive(self) -> tuple[str, Any]:
        """The child's next message; MapProcessLostError when it ended or is late."""
        assert self._conn is not None
        with self._watchdog() as overdue:
            try:
                kind, payload = self._conn.recv()
            except (EOFError, OSError):
                self._fail(self._late(overdue) or "ended")
        self._raise_if(overdue)
        return kind, payload

    @contextlib.contextmanager
    def _watchdog(self) -> Iterator[threading.Event]:
        """Kill the child when the pipe operation inside has not finished within
        ``deadline_s``; the event yielded is set when it did. A deadline on waiting for
        the first byte is not enough: a child stopped halfway through its answer (the
        result is ~0.3 MB, written in pieces) leaves a ``recv`` blocked on the rest, and
        one that stopped reading leaves a ``send`` larger than the pipe's buffer (the
        window's values at its peaks) blocked; both for ever, with the projector lit. The
        kill closes the child's end, and the blocked call returns with EOF or EPIPE."""
        if self._guard is None:
            self._guard = Watchdog(f"{self._name}-watchdog")
        with self._guard.armed(self.deadline_s, self._kill_overdue) as overdue:
            yield overdue

    def _kill_overdue(self) -> None:
        process = self._process
        if process is not None:
            try:
                process.kill()
            except (OSError, ValueError) as exc:  # reaped or closed meanwhile
                logger.error("%s: the overdue child could not be killed: %s", self._name, exc)

    def _late(self, overdue: threading.Event) -> str | None:
        return f"did not answer within {self.deadline_s:.1f} s" if overdue.is_set() else None

    def _raise_if(self, overdue: threading.Event) -> None:
        """The operation finished, but the watchdog had already killed the child."""
        late = self._late(overdue)
        if late is not None:
            self._fail(late)

    def _fail(self, what: str) -> NoReturn:
        """The child is unusable: kill it (it may hang) and raise MapProcessLostError."""
        process = self._process
        if process is not None:
            process.kill()
            process.join(STOP_TIMEOUT_S)
        code = None if process is None else process.exitcode
        self._lost = f"{what}, exit code {code}"
        raise MapProcessLostError(f"{self._name} {self._lost}")

    def _write(self, dmap: DistortionMap) -> MapNotice:
        """Copy the map's values and mask into the map slot; the notice that describes
        it."""
        assert self._map is not None
        if dmap.values.nbytes + dmap.saturated.nbytes > self._map.size:
            raise ConfigError(f"distortion map is {dmap.values.shape[1]}x"
                              f"{dmap.values.shape[0]} {dmap.values.dtype}: larger than the "
                              f"calibrated image the map slot holds")
        values = self._map.array(dmap.values.shape, dmap.values.dtype)
        values[...] = dmap.values
        self._map.array(dmap.values.shape, bool, values.nbytes)[...] = dmap.saturated
        return notice_of(dmap)


#: thread-pool sizes of the BLAS libraries numpy may use, set to 1 for the child
BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _one_blas_thread() -> Iterator[None]:
    """The environment a child is spawned with: one BLAS thread. An OpenBLAS pool's
    threads spin for a while after each call (the pipeline's ``test @ series``), on the
    core the camera loop needs; the child's work is one core's by design."""
    saved = {key: os.environ.get(key) for key in BLAS_THREADS}
    os.environ.update({key: "1" for key in BLAS_THREADS})
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _end(process: BaseProcess) -> None:
    """Wait for ``process`` to end; terminate, then kill it when it does not."""
    process.join(STOP_TIMEOUT_S)
    if process.is_alive():
        logger.error("%s did not end within %.1f s; terminated", process.name, STOP_TIMEOUT_S)
        process.terminate()
        process.join(STOP_TIMEOUT_S)
    if process.is_alive():
        process.kill()
        process.join(STOP_TIMEOUT_S)


class Watchdog:
    """One thread that runs an action when an armed deadline passes: a deadline for each
    pipe operation of the map thread without a thread started per operation (a
    ``threading.Timer`` each cost ~130 us of CPU, three per map: 5 % of a core at 120
    maps/s)."""

    def __init__(self, name: str) -> None:
        self._wake = threading.Condition()
        self._due: float | None = None  # monotonic s; None: disarmed
        self._action: Callable[[], None] | None = None
        self._overdue = threading.Event()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    @contextlib.contextmanager
    def armed(self, seconds: float, action: Callable[[], None]) -> Iterator[threading.Event]:
        """Run ``action`` (from the watchdog's thread) unless the block ends within
        ``seconds``; the event yielded is set once it ran. One arming at a time."""
        overdue = threading.Event()
        with self._wake:
            self._due, self._action, self._overdue = time.monotonic() + seconds, action, overdue
            self._wake.notify()
        try:
            yield overdue
        finally:
            with self._wake:
                self._due, self._action = None, None

    def stop(self) -> None:
        with self._wake:
            self._stopping = True
            self._wake.notify()
        self._thread.join(STOP_TIMEOUT_S)

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._stopping and (self._due is None
                                              or time.monotonic() < self._due):
                    self._wake.wait(None if self._due is None
                                    else max(0.0, self._due - time.monotonic()))
                if self._stopping:
                    return
                action, overdue = self._action, self._overdue
                self._due, self._action = None, None
                overdue.set()
            if action is not None:
                try:
                    action()
                except Exception:  # the watchdog must outlive what it runs
                    logger.exception("%s: the overdue action failed", self._thread.name)


# --------------------------------------------------------------------- the child
#: the pixels of a window frame the child does not hold (``WindowFrames.gather`` reads them)
_ELSEWHERE = np.empty((0, 0), dtype=np.uint8)


def _child_map(memory: Segment, notice: MapNotice, conn: Connection) -> DistortionMap:
    """The map in the map slot, its window read from the unit through ``conn``."""
    values = memory.array(notice.shape, notice.values_dtype)
    saturated = memory.array(notice.shape, bool, values.nbytes)
    window = None
    if notice.window:
        before = None if notice.before is None else (notice.before, _ELSEWHERE)
        window = WindowFrames((), notice.signs, before, gather=lambda flat: _ask(conn, flat))
    return DistortionMap(values=values, saturated=saturated, **notice.fields, window=window)


def _ask(conn: Connection, flat: Any) -> Any:
    """The window's values at the flat pixel indices ``flat``, from the unit."""
    conn.send(("series", flat))
    return conn.recv()


def serve(conn: Connection, parts: PipelineParts, map_name: str) -> None:
    """The child's main: build the pipeline, then measure each map it is told of until
    the pipe says stop (None) or closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    pipeline = Pipeline(parts.config, parts.calibration, parts.mounting, parts.layout)
    memory = Segment.attach(map_name)
    conn.send(("ready", None))
    try:
        while (notice := _next(conn)) is not None:
            conn.send(_measure(pipeline, _child_map(memory, notice, conn)))
    finally:
        memory.close()


def _next(conn: Connection) -> MapNotice | None:
    try:
        notice: MapNotice | None = conn.recv()
    except EOFError:  # the unit is gone
        return None
    return notice


def _measure(pipeline: Pipeline, dmap: DistortionMap) -> tuple[str, Any]:
    """("ok", the result) or ("error", the exception and its traceback as text)."""
    try:
        return "ok", pipeline.process(dmap)
    except Exception as exc:  # handed to the unit, which counts it and goes invalid
        return "error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
