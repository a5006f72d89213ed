"""``atris launch FILE``: run the units of a launch file and watch what they publish.

``--print`` shows what would start. Every frame on the bus goes through a decoding
monitor (E2E checked) and, with ``--log FILE``, into a python-can log in the format of the
file's suffix; an existing FILE is refused (exit 2) unless ``--overwrite`` is given. With
``--json`` the run prints no table and ends with a summary object on stdout: ``units``,
each with ``name``, ``code_row``, ``code_length``, ``state``, ``frames_sent`` and
``e2e_errors``; ``frames_not_taken`` counts frames the monitor or the log could not take
(then the exit code is 1, after the summary).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from typing import Any

import can

from atris_node.bus.can.config import open_bus
from atris_node.bus.can.ids import DEFAULT_BASE_ID
from atris_node.bus.can.logfile import check_log_target, open_log_writer
from atris_node.bus.can.monitor import BusMonitor, BusTap, e2e_errors_by_unit
from atris_node.node.fleetview import fleet_table
from atris_node.node.launch import LaunchSpec, describe, load_launch
from atris_node.node.runner import FleetRun, ProcessRun, stop_on_signals
from atris_node.node.wiring import bus_settings

logger = logging.getLogger(__name__)

CLEAR = "\x1b[H\x1b[2J"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="launch file (path, or name of a shipped one)")
    parser.add_argument("--print", action="store_true", help="show what would start, and exit")
    parser.add_argument("--duration", type=float, metavar="S",
                        help="run time, s (default: the launch file's)")
    parser.add_argument("--json", action="store_true", help="end with a JSON summary")
    parser.add_argument("--log", metavar="FILE",
                        help="write every frame (.asc, .blf, .csv, .db, .log, .trc, ...)")
    parser.add_argument("--overwrite", action="store_true",
                        help="let --log replace an existing file")
    parser.add_argument("--refresh", type=float, default=1.0, help="table period, s")
    parser.add_argument("--quiet", action="store_true", help="no table while running")


def run(args: argparse.Namespace) -> int:
    spec = load_launch(args.file)
    if args.print:
        print("\n".join(describe(spec)))
        return 0
    if args.log:
        check_log_target(args.log, args.overwrite)
    duration = spec.duration_s if args.duration is None else args.duration
    quiet = args.quiet or args.json  # stdout carries the JSON summary alone
    summary = run_launch(spec, duration, args.log, None if quiet else args.refresh,
                         live=sys.stdout.isatty(), overwrite=args.overwrite)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(summary_text(summary))
    if summary.get("failed"):
        logger.error("units that stopped and stay down: %s", ", ".join(summary["failed"]))
        return 1
    return 1 if summary["frames_not_taken"] else 0


def _monitor_bus(spec: LaunchSpec) -> can.BusABC:
    """The bus of the first unit, opened as the unit opens it (same settings, same
    precedence), without its own frames."""
    return open_bus(bus_settings(spec.units[0]), receive_own_messages=False)


def run_launch(spec: LaunchSpec, duration_s: float, log: str | None = None,
               refresh_s: float | None = 1.0, live: bool = False,
               overwrite: bool = False) -> dict[str, Any]:
    """Run ``spec`` for ``duration_s`` seconds; return the summary object. With ``log``
    every frame is also written there (an existing file only if ``overwrite``)."""
    base_id = int(spec.units[0]["bus.base_id"]) if spec.units else DEFAULT_BASE_ID
    monitor = BusMonitor(e2e_timeout_s=0.5, base_id=base_id)
    stop = threading.Event()
    with _monitor_bus(spec) as bus:
        listeners: list[can.Listener] = [monitor]
        if log:
            listeners.append(open_log_writer(log, overwrite))
        tap = BusTap(bus, listeners)  # stops the log writer, once
        runner: FleetRun | ProcessRun = (FleetRun(spec) if spec.mode == "threads"
                                         else ProcessRun(spec))
        running: dict[str, Any] | None = None
        try:
            with stop_on_signals(stop):
                runner.start()
                _watch(runner, monitor, duration_s, stop, refresh_s=refresh_s, live=live)
                running = monitor.snapshot()["units"]  # before the units' final frames
        finally:
            runner.stop()
            tap.stop()
    summary = summarize(spec, runner, monitor, running)
    summary["frames_not_taken"] = tap.failures
    if tap.failures:
        logger.error("%d frame(s) could not be decoded or logged, the first: %s",
                     tap.failures, tap.first_failure)
    return summary


def _watch(runner: FleetRun | ProcessRun, monitor: BusMonitor, duration_s: float,
           stop: threading.Event, *, refresh_s: float | None, live: bool) -> None:
    end = time.monotonic() + duration_s
    next_table = time.monotonic() + (refresh_s or duration_s)
    while not stop.is_set() and time.monotonic() < end:
        stop.wait(min(0.1, max(0.0, end - time.monotonic())))
        runner.check()
        if len(getattr(runner, "failed", [])) == len(runner.spec.units):
            logger.error("every unit stopped and stays down: the launch ends")
            return
        if refresh_s is not None and time.monotonic() >= next_table:
            next_table += refresh_s
            _show(runner, monitor, live)


def _show(runner: FleetRun | ProcessRun, monitor: BusMonitor, live: bool) -> None:
    """Draw the live table; a display that fails is logged, the fleet runs on."""
    try:
        table = fleet_table(runner, monitor)
    except Exception:
        logger.exception("the fleet table could not be drawn")
        return
    sys.stdout.write((CLEAR if live else "") + table + "\n")
    sys.stdout.flush()


def summarize(spec: LaunchSpec, runner: FleetRun | ProcessRun, monitor: BusMonitor,
              running: dict[str, Any] | None = None) -> dict[str, Any]:
    """The summary object of a launch run (fields are relied on by other tools): state
    and code as at the end of the run (``running``, the monitor's units then; the final
    STOPPED frames of the units come after), frame and error counts of the whole run."""
    snapshot = monitor.snapshot()["units"]
    at_end = snapshot if running is None else running
    errors = e2e_errors_by_unit(monitor)
    units = []
    for config in spec.units:
        unit_id = int(config["unit.unit_id"])
        view, end = snapshot.get(str(unit_id), {}), at_end.get(str(unit_id), {})
        units.append({
            "name": config["unit.label"],
            "unit_id": unit_id,
            "code_row": end.get("code_row"),
            "code_length": end.get("code_length"),
            "state": end.get("state"),
            "frames_sent": int(view.get("frames", 0)),
            "e2e_errors": errors.get(unit_id, 0),
        })
    for entry, unit in zip(units, getattr(runner, "units", []), strict=False):
        entry["measurements"] = unit.stats.measurements
        entry["deadline_misses"] = unit.stats.deadline_misses
        entry["dropped_sub_frames"] = unit.stats.dropped_sub_frames
    return {"launch": spec.name, "mode": spec.mode, "units": units,
            "error_frames": monitor.error_frames, "unknown_frames": monitor.unknown_frames,
            "failed": list(getattr(runner, "failed", []))}


def summary_text(summary: dict[str, Any]) -> str:
    """A few readable lines of a summary."""
    lines = [f"launch {summary['launch']} ({summary['mode']}):"]
    for unit in summary["units"]:
        lines.append(f"  {unit['name']:<8} code {unit['code_row']}/{unit['code_length']}  "
                     f"state {unit['state']}  frames {unit['frames_sent']}  "
                     f"E2E errors {unit['e2e_errors']}")
    return "\n".join(lines)
