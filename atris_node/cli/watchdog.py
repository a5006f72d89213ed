"""``atris watchdog``: keep the laser's enable line set only while the node's lease runs.

Runs as its own process beside ``atris run`` / ``atris launch`` (which write the lease with
``driver.projector_state_file``), so a node that is killed or hangs cannot keep a
host-driven laser lit: the line is cleared at most ``--poll-ms`` after the lease ran out.
Stops on SIGTERM / SIGINT with the line cleared. ``--json`` prints every transition.
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
from types import FrameType

from atris_node.errors import ConfigError
from drivers.watchdog import LeaseWatchdog


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--state-file", required=True,
                        help="the lease the node writes (driver.projector_state_file)")
    parser.add_argument("--enable", required=True, metavar="LINE",
                        help="file that takes 1/0: a sysfs GPIO value file, or a plain file")
    parser.add_argument("--poll-ms", type=float, default=5.0,
                        help="lease read period, ms (0 < P <= 1000; default 5)")
    parser.add_argument("--json", action="store_true",
                        help="print each transition as a JSON line (time, enabled, lease end)")


def run(args: argparse.Namespace) -> int:
    if not 0.0 < args.poll_ms <= 1000.0:
        raise ConfigError(f"--poll-ms must be in (0, 1000], got {args.poll_ms}")
    watchdog = LeaseWatchdog(args.state_file, args.enable, args.poll_ms / 1000.0)
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, on_signal)
    if args.json:
        watchdog.on_transition = lambda t, on, end: print(
            json.dumps({"time_s": t, "enabled": on, "lease_end_s": end}), flush=True)
    watchdog.run(stop)
    return 0
