"""``atris dbc``: print the shipped CAN database (DBC), e.g. ``atris dbc > atris.dbc``."""

from __future__ import annotations

import argparse
import sys

from atris_node.bus.frames import dbc_text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", "-o", help="write to this file instead of stdout")


def run(args: argparse.Namespace) -> int:
    text = dbc_text()
    if args.output:
        with open(args.output, "w", encoding="utf-8") as out:
            out.write(text)
    else:
        sys.stdout.write(text)
    return 0
