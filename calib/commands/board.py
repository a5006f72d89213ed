"""``atris calib board``: write a printable ChArUco board (PNG and PDF, true size)."""

from __future__ import annotations

import argparse
from pathlib import Path

from calib.board import write_printable
from calib.commands.common import add_board_arguments, board_from_args


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_board_arguments(parser)
    parser.add_argument("--out", type=Path, default=Path("charuco_board.png"),
                        help="PNG file; the PDF is written beside it with the .pdf suffix")
    parser.add_argument("--dpi", type=int, default=300, help="print resolution")
    parser.add_argument("--no-pdf", action="store_true", help="write the PNG only")


def run(args: argparse.Namespace) -> int:
    spec = board_from_args(args)
    pdf = None if args.no_pdf else args.out.with_suffix(".pdf")
    png, pdf_written = write_printable(spec, args.out, pdf, args.dpi)
    width, height = spec.size_m
    print(f"board {spec.squares_x}x{spec.squares_y}, {width * 1000:.0f} x "
          f"{height * 1000:.0f} mm: {png}" + (f", {pdf_written}" if pdf_written else ""))
    return 0
