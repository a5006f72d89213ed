"""``atris run``: run one unit in the foreground until SIGINT/SIGTERM or ``--duration``."""

from __future__ import annotations

import argparse
import json

from atris_node.cli.common import add_config_arguments, config_from_args
from atris_node.node.runner import run_unit


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config_arguments(parser)
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: run until SIGINT/SIGTERM)")
    parser.add_argument("--json", action="store_true", help="print a summary object at the end")
    parser.add_argument("--snapshot", metavar="DIR",
                        help="at the end write plain, demodulated and top-down obstacle PNGs")


def run(args: argparse.Namespace) -> int:
    unit = run_unit(config_from_args(args), duration_s=args.duration,
                    snapshot_dir=args.snapshot)
    if args.json:
        stats = unit.stats
        print(json.dumps({"name": unit.label, "sub_frames": stats.sub_frames,
                          "measurements": stats.measurements,
                          "dropped_sub_frames": stats.dropped_sub_frames,
                          "maps_skipped": stats.maps_skipped,
                          "stale_maps": stats.stale_maps,
                          "pipeline_errors": stats.pipeline_errors,
                          "deadline_misses": stats.deadline_misses,
                          "camera_faults": stats.camera_faults}))
    return 0
