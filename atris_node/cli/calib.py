"""``atris calib NAME``: intrinsics, printable board, laser planes, verification, radiometry,
simulation."""

from __future__ import annotations

import argparse

from atris_node.cli import dispatch

#: calibration step -> (module, one-line help); each module has add_arguments and run.
CALIB_COMMANDS: dict[str, tuple[str, str]] = {
    "intrinsics": ("calib.commands.intrinsics",
                   "camera file from ChArUco views (folder, capture set or live camera)"),
    "board": ("calib.commands.board", "write a printable ChArUco board (PNG and PDF)"),
    "laser": ("calib.commands.laser", "baseline b and angle alpha per line (flat target or board)"),
    "verify": ("calib.commands.verify", "range error on a target at a known distance"),
    "radiometry": ("calib.commands.radiometry",
                   "the lines' return on a white target (brightness against range check)"),
    "simulate": ("calib.commands.simulate", "write a simulated capture set with its truth"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", nargs="?", choices=sorted(CALIB_COMMANDS),
                        help="calibration step (none: list them)")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help="options of the step")


def run(args: argparse.Namespace) -> int:
    return dispatch("atris calib", CALIB_COMMANDS, [args.name, *args.rest] if args.name else [])
