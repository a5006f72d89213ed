"""``atris dbc``: print the CAN database (DBC), e.g. ``atris dbc > atris.dbc``.

``--base-id 0x...`` prints the database of a fleet whose unit frames start elsewhere than
the default (generated from the frame table); ``--generate`` rewrites the shipped
``atris.dbc`` from the frame table (after a change to ``atris_node/bus/can/layouts.py``),
or writes it to ``--output``.
"""

from __future__ import annotations

import argparse

from atris_node.bus.can.dbc import generate_text
from atris_node.bus.can.frames import dbc_path, dbc_text
from atris_node.bus.can.ids import DEFAULT_BASE_ID, check_base_id
from atris_node.cli.common import add_output_argument, write_text
from atris_node.errors import ConfigError


def _base_id(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"base ID must be an integer such as 0x680, got {text!r}") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_output_argument(parser)
    parser.add_argument("--base-id", type=_base_id, default=DEFAULT_BASE_ID,
                        help=f"first unit frame ID (default 0x{DEFAULT_BASE_ID:03X})")
    parser.add_argument("--generate", action="store_true",
                        help="rewrite the shipped atris.dbc (or --output) from the frame "
                        "table")


def run(args: argparse.Namespace) -> int:
    base_id = check_base_id(args.base_id, allow_canopen=True)
    if args.generate:
        if base_id != DEFAULT_BASE_ID:
            raise ConfigError("--generate writes the DBC of the default base; use --base-id "
                              "without it for another base")
        return write_text(generate_text(), args.output or str(dbc_path()))
    text = dbc_text() if base_id == DEFAULT_BASE_ID else generate_text(base_id)
    return write_text(text, args.output)
