"""``atris eds``: print the shipped CANopen EDS, e.g. ``atris eds > atris.eds``;
``atris eds --check [FILE]`` checks an EDS (the shipped one by default) for conformance."""

from __future__ import annotations

import argparse
from pathlib import Path

from atris_node.bus.canopen.conformance import problems
from atris_node.bus.canopen.device import eds_text
from atris_node.cli.common import add_output_argument, write_text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_output_argument(parser)
    parser.add_argument("--check", nargs="?", const="", metavar="FILE",
                        help="check FILE (default: the shipped EDS) against CiA 306 and "
                             "the objects the device serves; exit 1 on any problem")


def run(args: argparse.Namespace) -> int:
    if args.check is None:
        return write_text(eds_text(), args.output)
    text = Path(args.check).read_text("utf-8") if args.check else eds_text()
    found = problems(text)
    report = "".join(f"{line}\n" for line in found) or "EDS conforms\n"
    write_text(report, args.output)
    return 1 if found else 0
