"""``atris eds``: print the shipped CANopen EDS, e.g. ``atris eds > atris.eds``."""

from __future__ import annotations

import argparse

from atris_node.bus.canopen.device import eds_text
from atris_node.cli.common import add_output_argument, write_text

add_arguments = add_output_argument


def run(args: argparse.Namespace) -> int:
    return write_text(eds_text(), args.output)
