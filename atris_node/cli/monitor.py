"""``atris monitor``: live decoded view of every unit on a bus.

The bus is named in python-can's terms (``--interface``, ``--channel``, ``--bitrate``,
``--fd``); missing values come from ``CAN_INTERFACE`` / ``CAN_CHANNEL`` / ``CAN_BITRATE``
and python-can's config files, then ``virtual``/``atris``. ``--log FILE`` records every
frame with ``can.Logger`` (.log, .asc, .blf...), readable by ``cantools decode``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import can

from atris_node.bus.can.config import BusConfig, open_bus
from atris_node.bus.can.monitor import BusMonitor, render_table

CLEAR = "\x1b[H\x1b[2J"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--interface", "--bus", help="python-can interface (default: "
                        "$CAN_INTERFACE, python-can config, else virtual)")
    parser.add_argument("--channel", help="python-can channel (default: $CAN_CHANNEL, atris)")
    parser.add_argument("--bitrate", type=int, help="bit rate, bit/s")
    parser.add_argument("--fd", action="store_true", default=None, help="CAN FD")
    parser.add_argument("--duration", type=float, help="stop after S seconds")
    parser.add_argument("--refresh", type=float, default=0.5, help="table refresh period, s")
    parser.add_argument("--json", action="store_true", help="print a JSON summary at the end")
    parser.add_argument("--log", metavar="FILE", help="record frames (.log, .asc, .blf, ...)")


def run(args: argparse.Namespace) -> int:
    config = BusConfig(args.interface, args.channel, args.bitrate, args.fd)
    monitor = BusMonitor()
    with open_bus(config, python_can_sources=True, receive_own_messages=False) as bus:
        listeners: list[can.Listener] = [monitor]
        if args.log:
            listeners.append(can.Logger(args.log))
        notifier = can.Notifier(bus, listeners, timeout=0.1)
        try:
            _watch(monitor, args)
        finally:
            notifier.stop()
            for listener in listeners:
                listener.stop()
    if args.json:
        print(json.dumps(monitor.snapshot(time.time()), indent=2, default=str))
    return 0


def _watch(monitor: BusMonitor, args: argparse.Namespace) -> None:
    end = None if args.duration is None else time.monotonic() + args.duration
    live = not args.json and sys.stdout.isatty()
    while end is None or time.monotonic() < end:
        left = args.refresh if end is None else min(args.refresh, end - time.monotonic())
        time.sleep(max(0.0, left))
        if live:
            sys.stdout.write(CLEAR + render_table(monitor.snapshot(time.time())) + "\n")
            sys.stdout.flush()
    if not args.json and not live:
        print(render_table(monitor.snapshot(time.time())))
