"""``atris bench realtime``: the real node chain fed at a camera's native rate.

    atris bench realtime --camera oak --mode sliding
    atris bench realtime --camera paper --json
    atris bench realtime --camera 640x400@120 --seconds 5
    atris bench realtime --camera paper --worker process

``--camera`` is ``oak`` (OV9282: 1280x800, 8-bit, 120 sub-frames/s), ``paper`` (CMV2000:
2048x1088, 10-bit, 600 sub-frames/s) or ``WxH[xBITS]@RATE``: width and height in pixels,
bits per pixel 8..16 (8 when left out), sub-frames per second (e.g. ``640x400@120``,
``2048x1088x10@600``). The scene (``--scene``, indoor_lab by default) is scaled to that
resolution (same optics: focal length, principal point, pixel pitch and blur scaled with
the width) and N pictures of it with the projector ON and N with it OFF are rendered
before anything is timed. A :class:`~atris_node.bench.pacing.PacedCamera` then hands them
to a real :class:`~atris_node.node.unit.Unit` (negotiation, demodulator, pipeline,
publisher on an in-process python-can virtual bus) at the camera's rate from the host
clock, through a bounded queue of ``--queue`` frame buffers; a sub-frame that finds the
queue full when it is due is dropped (the pacing module says why).

The first ``--warmup`` seconds (negotiation, the first maps) are not counted; then
``--seconds`` of sub-frames are. The row (``--json`` prints it as one object):

- ``sub_frames``: ``offered``, ``consumed``, ``dropped`` (queue full) and ``pending``
  (still queued at the end); ``offered == consumed + dropped + pending``; ``gaps``: how
  often the unit read a sub-frame that did not follow the one before (each restarts the
  demodulation window: N sub-frames without output in sliding mode).
- ``measurements`` and ``output_hz`` (measurements whose newest sub-frame was counted, per
  counted second) beside ``expected_output_hz`` (the rate in sliding mode, rate / N in
  block mode).
- ``age_ms``: data age as ``atris bench latency`` defines it, the send time of the quality
  frame carrying a measurement minus the host time of its newest sub-frame, here the
  sub-frame's scheduled arrival: ``samples``, ``p50``, ``p99``, ``max`` (null without
  samples).
- ``stages``: ``demod`` (every sub-frame), ``pipeline`` (every map: the pipeline and the
  adaptation) and ``publish`` (the publisher's update, which sends a new measurement from
  the loop's thread): calls, wall ms per call p50/p99/max, CPU seconds and % of one core.
- ``threads``: CPU seconds and % of one core per thread over the counted time;
  ``process_cpu_pct`` for the whole process (200 = two cores busy).
- ``worker``: where maps were measured (``--worker``: ``pipeline.worker``, thread, process
  or inline); ``map_thread``: true unless inline. With ``process``, ``map_process``: the
  child's CPU (``cpu_pct``, % of one core over the counted time), its start-up time
  (``start_s``); the ``pipeline`` stage is then the map thread's wait for the child, its CPU the map
  thread's own.
- ``peak_rss_mb`` (the process's peak resident set, pre-rendered pictures included),
  ``prerendered_mb`` and ``sensor_late_max_ms`` (the sensor thread's worst wake-up delay).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import can

from atris_node import codes
from atris_node import config as cfg
from atris_node.bench import cputime
from atris_node.bench._timing import spread_ms
from atris_node.bench.accuracy import scaled
from atris_node.bench.latency import Arrivals
from atris_node.bench.pacing import PacedCamera, PacedProjector, Prerendered
from atris_node.config import WORKERS
from atris_node.errors import CodeError, UsageError
from atris_node.node.mapprocess import MapProcess
from atris_node.node.unit import Unit
from atris_node.sim import Simulator, load_scene
from atris_node.types import Measurement

CHANNEL = "atris-bench-realtime"
MODES = ("block", "sliding")
STAGES = ("demod", "pipeline", "publish")
#: seconds the unit may take after the counted sub-frames to consume what it queued
GRACE_S = 2.0


@dataclass(frozen=True)
class CameraSpec:
    """A camera format: pixels, bits per pixel and sub-frames per second."""

    name: str
    width: int
    height: int
    bits: int
    rate_hz: float


CAMERAS = {"oak": CameraSpec("oak", 1280, 800, 8, 120.0),
           "paper": CameraSpec("paper", 2048, 1088, 10, 600.0)}
_FORMAT = re.compile(r"(\d+)x(\d+)(?:x(\d+))?@(\d+(?:\.\d+)?)")
ACCEPTED = ("oak, paper or WxH[xBITS]@RATE with width 64..8192 px, height 32..8192 px, "
            "bits 8..16 (8 when left out) and rate 1..10000 sub-frames/s, e.g. 640x400@120 "
            "or 2048x1088x10@600")


def parse_camera(text: str) -> CameraSpec:
    """The camera format ``text`` names; UsageError (exit 2) saying what is accepted."""
    if text in CAMERAS:
        return CAMERAS[text]
    match = _FORMAT.fullmatch(text.strip())
    if match is None:
        raise UsageError(f"--camera {text!r} is not a camera format; accepted: {ACCEPTED}")
    width, height = int(match[1]), int(match[2])
    bits, rate = int(match[3] or 8), float(match[4])
    if not (64 <= width <= 8192 and 32 <= height <= 8192 and 8 <= bits <= 16
            and 1.0 <= rate <= 10000.0):
        raise UsageError(f"--camera {text!r} is out of range; accepted: {ACCEPTED}")
    return CameraSpec(text, width, height, bits, rate)


def prerender(spec: CameraSpec, scene_name: str, code_length: int) -> Prerendered:
    """N ON and N OFF pictures of ``scene_name`` scaled to ``spec`` (index i = sequence
    i of the simulator, its own noise); exposure limited to 90 % of a sub-frame period."""
    base = scaled(load_scene(scene_name), spec.width, spec.height)
    exposure_us = min(base.camera.exposure_us, 0.9e6 / spec.rate_hz)
    scene = replace(base, camera=replace(base.camera, bits=spec.bits, rate_hz=spec.rate_hz,
                                         exposure_us=exposure_us))
    sim = Simulator(scene, seed=1)
    off = [sim.render(i, 0).pixels for i in range(code_length)]
    on = [sim.render(i, 1).pixels for i in range(code_length)]
    return Prerendered(off, on, spec.rate_hz, spec.bits, exposure_us, sim.calibration(),
                       sim.mounting)


def _instrument(unit: Unit, timers: dict[str, cputime.StageTimer], stall_ms: float) -> None:
    """Time the demodulator, the per-map work and the publisher's update of ``unit``
    (instance attributes over the bound methods); ``stall_ms`` of sleep added per map."""
    measurer, publisher = unit.measure, unit.publisher
    assert measurer is not None and publisher is not None
    inner = measurer.measure

    def stalled(*args: Any) -> Any:
        time.sleep(stall_ms * 1e-3)
        return inner(*args)

    measure: Callable[..., Any] = stalled if stall_ms > 0 else inner
    setattr(measurer, "demodulate", timers["demod"].wrap(measurer.demodulate))  # noqa: B010
    setattr(measurer, "measure", timers["pipeline"].wrap(measure))  # noqa: B010
    setattr(publisher, "update", timers["publish"].wrap(publisher.update))  # noqa: B010


def _sleep_until(clock_s: float) -> None:
    delay = clock_s - time.monotonic()
    if delay > 0:
        time.sleep(delay)


def _ages(sent: dict[int, tuple[float, int]], sends: dict[int, float],
          camera: PacedCamera) -> dict[str, Any]:
    """Data age (ms) of the counted measurements that reached the bus."""
    return spread_ms([1e3 * (sends[c] - t) for c, (t, seq) in sent.items()
                      if c in sends and camera.counts.holds(seq)])


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


@dataclass(frozen=True)
class Options:
    """What to run: camera, demodulation mode, counted and warm-up seconds, scene, N,
    frame buffers, a deliberate stall per map (ms, for tests of the drop rule), and
    where maps are measured (``worker``: ``pipeline.worker``)."""

    camera: CameraSpec
    mode: str = "sliding"
    seconds: float = 10.0
    warmup_s: float = 1.0
    scene: str = "indoor_lab"
    code_length: int = 16
    queue_depth: int = 4
    stall_ms: float = 0.0
    worker: str = "thread"


def measure(opts: Options) -> dict[str, Any]:
    """Run the unit on the paced camera and return the row (module docstring)."""
    frames = prerender(opts.camera, opts.scene, opts.code_length)
    projector = PacedProjector()
    camera = PacedCamera(frames, projector, opts.queue_depth)
    first = math.ceil(opts.warmup_s * opts.camera.rate_hz)
    camera.count(first, first + max(1, round(opts.seconds * opts.camera.rate_hz)))
    config = cfg.load(environ={}, overrides=[
        f"driver.scene={opts.scene}", f"code.length={opts.code_length}",
        f"code.demod={opts.mode}", f"bus.channel={CHANNEL}",
        f"pipeline.worker={opts.worker}"])
    timers = {name: cputime.StageTimer() for name in STAGES}
    sent: dict[int, tuple[float, int]] = {}
    arrivals = Arrivals()
    with can.Bus(interface="virtual", channel=CHANNEL) as rx, \
            can.Bus(interface="virtual", channel=CHANNEL) as tx:
        notifier = can.Notifier(rx, [arrivals], timeout=0.05)
        unit = Unit(config, tx, open_backend=lambda name, **kw: (camera, projector))

        def remember(m: Measurement) -> None:
            sent[m.counter & 0xFFFF] = (m.newest_time_s, m.newest_sequence)

        unit.on_measurement = remember
        try:
            unit.configure()
            _instrument(unit, timers, opts.stall_ms)
            camera.start()
            unit.activate()
            usage = _counted_run(camera, timers, _map_process(unit))
            _drain(camera)
        finally:
            unit.shutdown()
            pending = camera.stop()
            notifier.stop()
        unit.check()
    row = _row(opts, camera, frames, sent, arrivals.sends, timers, usage, pending)
    row["maps"] = {"skipped": unit.stats.maps_skipped, "stale": unit.stats.stale_maps}
    if "map_process" in usage:
        row["map_process"] = usage["map_process"]
    return row


def _map_process(unit: Unit) -> MapProcess | None:
    pipeline = None if unit.measure is None else unit.measure.pipeline
    return pipeline if isinstance(pipeline, MapProcess) else None


def _counted_run(camera: PacedCamera, timers: dict[str, cputime.StageTimer],
                 child: MapProcess | None) -> dict[str, Any]:
    """Wait through the counted sub-frames; CPU per thread and of the process over them
    (and of the map process, ``child``)."""
    start_s, end_s = camera.due_s(camera.counts.first), camera.due_s(camera.counts.end)
    for timer in timers.values():
        timer.start_s, timer.end_s = start_s, end_s
    _sleep_until(start_s)
    threads, process = cputime.thread_cpu_s(), _cpu_s()
    child_cpu = cputime.process_cpu_s(child.pid) if child and child.pid else 0.0
    _sleep_until(end_s)
    seconds = max(time.monotonic() - start_s, 1e-9)
    usage = {"threads": cputime.per_thread(threads, cputime.thread_cpu_s(), seconds),
             "process_cpu_pct": round(100.0 * (_cpu_s() - process) / seconds, 1),
             "seconds": seconds}
    if child is not None and child.pid:
        child_cpu = cputime.process_cpu_s(child.pid) - child_cpu
        usage["map_process"] = {"cpu_pct": round(100.0 * child_cpu / seconds, 1),
                                "start_s": round(child.start_s or 0.0, 3)}
    return usage


def _drain(camera: PacedCamera) -> None:
    """Wait (at most GRACE_S) until the counted sub-frames are consumed or dropped."""
    deadline = time.monotonic() + GRACE_S
    counts = camera.counts
    while counts.consumed + counts.dropped < counts.offered and time.monotonic() < deadline:
        time.sleep(0.01)


def _row(opts: Options, camera: PacedCamera, frames: Prerendered,
         sent: dict[int, tuple[float, int]], sends: dict[int, float],
         timers: dict[str, cputime.StageTimer], usage: dict[str, Any],
         pending: int) -> dict[str, Any]:
    spec, counts, seconds = opts.camera, camera.counts, float(usage["seconds"])
    measurements = sum(camera.counts.holds(seq) for _, seq in sent.values())
    expected = spec.rate_hz if opts.mode == "sliding" else spec.rate_hz / opts.code_length
    return {
        "camera": {"name": spec.name, "width": spec.width, "height": spec.height,
                   "bits": spec.bits, "rate_hz": spec.rate_hz},
        "mode": opts.mode, "code_length": opts.code_length, "scene": opts.scene,
        "worker": opts.worker, "map_thread": opts.worker != "inline",
        "queue_depth": opts.queue_depth, "seconds": round(seconds, 3),
        "sub_frames": {"offered": counts.offered, "consumed": counts.consumed,
                       "dropped": counts.dropped, "pending": pending,
                       "gaps": counts.gaps},
        "measurements": measurements, "output_hz": round(measurements / seconds, 2),
        "expected_output_hz": round(expected, 2),
        "age_ms": _ages(sent, sends, camera),
        "stages": {name: timer.row(seconds) for name, timer in timers.items()},
        "threads": usage["threads"], "process_cpu_pct": usage["process_cpu_pct"],
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "prerendered_mb": round(frames.nbytes / 2**20, 1),
        "sensor_late_max_ms": round(camera.sensor_late_max_s * 1e3, 3),
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--camera", default="oak", help=f"camera format: {ACCEPTED}")
    parser.add_argument("--mode", choices=MODES, default="sliding", help="demodulation")
    parser.add_argument("--seconds", type=float, default=10.0, help="counted run time, s")
    parser.add_argument("--warmup", type=float, default=1.0, help="uncounted start, s")
    parser.add_argument("--scene", default="indoor_lab", help="simulator scene, scaled")
    parser.add_argument("--code-length", type=int, default=16, help="N")
    parser.add_argument("--queue", type=int, default=4, help="camera frame buffers")
    parser.add_argument("--stall-ms", type=float, default=0.0,
                        help="sleep added per map (to see the drop rule at work), ms")
    parser.add_argument("--worker", choices=WORKERS, default=None,
                        help="where maps are measured (pipeline.worker; default thread)")
    parser.add_argument("--serial", action="store_true",
                        help="measure maps in the camera loop (= --worker inline)")
    parser.add_argument("--json", action="store_true", help="print the row as one object")


def options_of(args: argparse.Namespace) -> Options:
    """The run asked for on the command line; UsageError for values out of range."""
    if not (args.seconds > 0 and args.warmup >= 0 and args.queue >= 1 and args.stall_ms >= 0):
        raise UsageError("--seconds must be > 0, --warmup >= 0, --queue >= 1 and "
                         f"--stall-ms >= 0; got {args.seconds}, {args.warmup}, {args.queue}, "
                         f"{args.stall_ms}")
    try:
        length = codes.check_length(args.code_length)
    except CodeError as exc:
        raise UsageError(f"--code-length: {exc}") from exc
    if args.serial and args.worker not in (None, "inline"):
        raise UsageError(f"--serial is --worker inline; it cannot go with --worker {args.worker}")
    worker = "inline" if args.serial else args.worker or "thread"
    return Options(parse_camera(args.camera), args.mode, args.seconds, args.warmup,
                   args.scene, length, args.queue, args.stall_ms, worker)


def _table(row: dict[str, Any]) -> str:
    cam, subs, age = row["camera"], row["sub_frames"], row["age_ms"]
    lines = [
        f"camera {cam['name']}: {cam['width']}x{cam['height']} {cam['bits']}-bit at "
        f"{cam['rate_hz']:g} sub-frames/s, {row['mode']} N={row['code_length']}, "
        f"{row['seconds']:.1f} s counted",
        f"sub-frames  offered {subs['offered']}  consumed {subs['consumed']}  "
        f"dropped {subs['dropped']}  pending {subs['pending']}  gaps {subs['gaps']}",
        f"output      {row['output_hz']:.1f} Hz of {row['expected_output_hz']:.1f} Hz "
        f"({row['measurements']} measurements; maps skipped {row['maps']['skipped']}, "
        f"stale {row['maps']['stale']}; worker {row['worker']})",
        f"data age    p50 {age['p50']} ms  p99 {age['p99']} ms  max {age['max']} ms",
        f"{'stage':<10} {'calls':>7} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'cpu %':>6}"]
    lines += [f"{name:<10} {s['calls']:>7} {s['p50_ms']:>8.3f} {s['p99_ms']:>8.3f} "
              f"{s['max_ms']:>8.3f} {s['cpu_pct']:>6.1f}" for name, s in row["stages"].items()]
    lines += [f"thread {t['thread']}: {t['cpu_pct']:.1f} % of a core" for t in row["threads"]]
    child = row.get("map_process")
    if child is not None:
        lines.append(f"map process: {child['cpu_pct']:.1f} % of a core, started in "
                     f"{child['start_s']:.2f} s")
    lines.append(f"process {row['process_cpu_pct']:.1f} % of a core, peak RSS "
                 f"{row['peak_rss_mb']:.0f} MB ({row['prerendered_mb']:.0f} MB pre-rendered), "
                 f"sensor late by up to {row['sensor_late_max_ms']:.1f} ms")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    row = measure(options_of(args))
    print(json.dumps(row) if args.json else _table(row))
    return 0
