"""``atris eds``: print the shipped CANopen EDS, e.g. ``atris eds > atris.eds``."""

from __future__ import annotations

import argparse
import sys

from atris_node.bus.canopen_device import eds_text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", "-o", help="write to this file instead of stdout")


def run(args: argparse.Namespace) -> int:
    text = eds_text()
    if args.output:
        with open(args.output, "w", encoding="utf-8") as out:
            out.write(text)
    else:
        sys.stdout.write(text)
    return 0
