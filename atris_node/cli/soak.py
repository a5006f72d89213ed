"""``atris soak --minutes M [--json]``: the simulated four-unit fleet, resource use measured."""

from __future__ import annotations

import argparse
import json

from atris_node.errors import ConfigError
from atris_node.node.launch import load_launch
from atris_node.node.soak import soak


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--minutes", type=float, default=10.0, help="run time, minutes")
    parser.add_argument("--launch", default="sim_soak", help="launch file of the fleet")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")


def run(args: argparse.Namespace) -> int:
    if not 0.0 < args.minutes <= 24 * 60:
        raise ConfigError(f"--minutes must be in (0, 1440], got {args.minutes}")
    report = soak(args.minutes, load_launch(args.launch))
    if args.json:
        print(json.dumps(report.as_dict(), indent=1))
    else:
        for key, value in report.as_dict().items():
            print(f"{key:<24} {value}")
    return 0
