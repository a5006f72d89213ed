"""Options and output shared by the ``atris calib`` subcommands."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from atris_node.errors import CalibrationError
from calib.board import BoardSpec


def add_board_arguments(parser: argparse.ArgumentParser) -> None:
    """The ChArUco board: squares across/down, square and marker side (mm), dictionary."""
    default = BoardSpec()
    group = parser.add_argument_group("board")
    group.add_argument("--squares-x", type=int, default=default.squares_x)
    group.add_argument("--squares-y", type=int, default=default.squares_y)
    group.add_argument("--square-mm", type=float, default=default.square_m * 1000)
    group.add_argument("--marker-mm", type=float, default=default.marker_m * 1000)
    group.add_argument("--dictionary", default=default.dictionary)


def board_from_args(args: argparse.Namespace) -> BoardSpec:
    """The :class:`BoardSpec` the board options describe."""
    return BoardSpec(args.squares_x, args.squares_y, args.square_mm / 1000.0,
                     args.marker_mm / 1000.0, args.dictionary)


def add_output_arguments(parser: argparse.ArgumentParser) -> None:
    """``--json`` and ``--plot PNG``."""
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--plot", type=Path, default=None,
                        help="residual plot (PNG); default: next to the output file")


def plot_path(args: argparse.Namespace, beside: Path) -> Path:
    """``--plot`` or ``<output stem>.residuals.png`` beside the output file."""
    return args.plot if args.plot is not None else beside.with_name(
        beside.name.split(".")[0] + ".residuals.png")


def print_result(values: dict[str, object], as_json: bool) -> None:
    """Print ``values`` as JSON or as ``key: value`` lines."""
    if as_json:
        print(json.dumps(values, indent=2))
        return
    for key, value in values.items():
        print(f"{key}: {value}")


def split_pair(text: str, option: str) -> tuple[str, str]:
    """``A=B`` -> (A, B); anything else is a clear error naming the option."""
    left, sep, right = text.partition("=")
    if not sep or not left or not right:
        raise CalibrationError(f"{option} expects LEFT=RIGHT, got {text!r}")
    return left, right


def add_driver_arguments(parser: argparse.ArgumentParser) -> None:
    """Repeated ``--driver-option KEY=VALUE`` for a live camera backend."""
    parser.add_argument("--driver-option", action="append", default=[], metavar="KEY=VALUE",
                        help="setting passed to the backend (repeatable; numbers are numbers)")


def _option_value(text: str) -> object:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def driver_settings(args: argparse.Namespace) -> dict[str, object]:
    """The ``--driver-option`` settings; text that reads as an int or float becomes one."""
    pairs = (split_pair(o, "--driver-option") for o in args.driver_option)
    return {key: _option_value(value) for key, value in pairs}
