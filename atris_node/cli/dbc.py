"""``atris dbc``: print the shipped CAN database (DBC), e.g. ``atris dbc > atris.dbc``."""

from __future__ import annotations

import argparse

from atris_node.bus.can.frames import dbc_text
from atris_node.cli.common import add_output_argument, write_text

add_arguments = add_output_argument


def run(args: argparse.Namespace) -> int:
    return write_text(dbc_text(), args.output)
