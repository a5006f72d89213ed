"""``atris monitor``: decoded view of every unit on a live bus or in a recorded log.

A live bus is named in python-can's terms (``--interface``, ``--channel``, ``--bitrate``,
``--fd``) with python-can's precedence: these options, then ``CAN_INTERFACE`` /
``CAN_CHANNEL`` / ``CAN_BITRATE`` / ``CAN_CONFIG``, then python-can's config files
(``~/.canrc``...), then ``virtual`` on channel ``atris``. ``--log FILE`` records every
frame (format from the suffix: .asc, .blf, .csv, .db, .log, .trc...); an existing FILE is
refused unless ``--overwrite`` is given. ``--replay FILE`` reads a recorded log instead of
a bus, frame by frame with the log's own timestamps, and shows the state at its end.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from typing import Any

import can

from atris_node.bus.can.config import BusConfig, open_bus
from atris_node.bus.can.ids import DEFAULT_BASE_ID, check_base_id
from atris_node.bus.can.logfile import check_log_target, open_log_writer, read_log
from atris_node.bus.can.monitor import BusMonitor, BusTap, render_table
from atris_node.errors import ConfigError, UsageError

logger = logging.getLogger(__name__)

CLEAR = "\x1b[H\x1b[2J"
#: options that describe a live bus, refused with --replay
LIVE_OPTIONS = ("interface", "channel", "bitrate", "fd", "duration", "log")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--interface", "--bus", help="python-can interface (default: "
                        "$CAN_INTERFACE, $CAN_CONFIG, python-can config file, else virtual)")
    parser.add_argument("--channel", help="python-can channel (default: $CAN_CHANNEL, "
                        "$CAN_CONFIG, python-can config file, else atris on the virtual "
                        "bus, the backend's own default on another)")
    parser.add_argument("--bitrate", type=int, help="bit rate, bit/s (default: "
                        "$CAN_BITRATE, $CAN_CONFIG, python-can config file, else 500000 "
                        "where the interface has one)")
    parser.add_argument("--fd", action="store_true", default=None, help="CAN FD")
    parser.add_argument("--base-id", type=_base_id, default=DEFAULT_BASE_ID, metavar="ID",
                        help="first ID of the units' frames, as their bus.base_id "
                        f"(default {DEFAULT_BASE_ID:#x})")
    parser.add_argument("--replay", metavar="FILE", help="read a recorded log (any python-can "
                        "format: .asc, .blf, .csv, .db, .log, .trc...) instead of a bus")
    parser.add_argument("--duration", type=float, help="stop after S seconds")
    parser.add_argument("--refresh", type=float, default=0.5, help="table refresh period, s")
    parser.add_argument("--json", action="store_true", help="print a JSON summary at the end")
    parser.add_argument("--log", metavar="FILE",
                        help="record frames (.asc, .blf, .csv, .db, .log, .trc, ...)")
    parser.add_argument("--overwrite", action="store_true",
                        help="let --log replace an existing file")


def run(args: argparse.Namespace) -> int:
    if args.replay:
        given = [f"--{name}" for name in LIVE_OPTIONS if getattr(args, name) is not None]
        if given:
            verb = "applies" if len(given) == 1 else "apply"
            raise UsageError(f"--replay reads a log file; {', '.join(given)} {verb} only to "
                             "a live bus (to convert a log, use python -m can.logconvert)")
        summary = replay(args.replay, args.base_id)
    else:
        if args.log:
            check_log_target(args.log, args.overwrite)
        summary = watch_bus(args)
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    elif args.replay or not sys.stdout.isatty():
        print(render_table(summary))
    return 1 if summary.get("frames_not_taken") else 0


def _base_id(text: str) -> int:
    """``--base-id``: an ID in decimal or 0x hex, checked as bus.base_id is."""
    try:
        value = int(text, 0)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from exc
    try:
        return check_base_id(value, allow_canopen=True)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def replay(path: str, base_id: int = DEFAULT_BASE_ID) -> dict[str, Any]:
    """Feed every frame of the log at ``path`` to a BusMonitor; its snapshot at the log's
    last frame (ages and rates in the log's time, not the time of the replay)."""
    monitor, frames = BusMonitor(base_id=base_id), 0
    for msg in read_log(path):
        monitor.feed(msg)
        frames += 1
    if not frames:
        logger.warning("log file %s holds no frame python-can could read", path)
    return monitor.snapshot()


def watch_bus(args: argparse.Namespace) -> dict[str, Any]:
    """Watch the live bus the options name; the snapshot at the end, at wall time."""
    config = BusConfig(args.interface, args.channel, args.bitrate, args.fd)
    monitor = BusMonitor(base_id=args.base_id)
    with open_bus(config, receive_own_messages=False) as bus:
        listeners: list[can.Listener] = [monitor]
        if args.log:
            listeners.append(open_log_writer(args.log, args.overwrite))
        tap = BusTap(bus, listeners)  # stops the log writer, once
        try:
            _watch(monitor, args)
        finally:
            tap.stop()
    summary = monitor.snapshot(time.time())
    summary["frames_not_taken"] = tap.failures
    if tap.failures:
        logger.error("%d frame(s) could not be decoded or logged, the first: %s",
                     tap.failures, tap.first_failure)
    return summary


def _watch(monitor: BusMonitor, args: argparse.Namespace) -> None:
    """Until ``--duration`` has passed or Ctrl-C (which ends the watch, not the command:
    the summary and the log still come out)."""
    end = None if args.duration is None else time.monotonic() + args.duration
    live = not args.json and sys.stdout.isatty()
    try:
        while end is None or time.monotonic() < end:
            left = args.refresh if end is None else min(args.refresh, end - time.monotonic())
            time.sleep(max(0.0, left))
            if live:
                sys.stdout.write(CLEAR + render_table(monitor.snapshot(time.time())) + "\n")
                sys.stdout.flush()
    except KeyboardInterrupt:
        logger.info("interrupted: the watch ends")
