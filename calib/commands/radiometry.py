"""``atris calib radiometry``: the lines' radiometric calibration (return_dn_m2) from a
white target of known albedo facing the unit at a known distance, written into a copy of
the unit's calibration file.

The target's distortion map comes from a file (``--map``, with its code length) or live
from a camera backend (``--backend``). The exposure the map was taken at is given
(``--exposure-us``): the pipeline scales the expected return by each map's exposure.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from atris_node.errors import CalibrationError
from calib.captures import load_map
from calib.commands.common import (
    add_driver_arguments,
    add_output_arguments,
    driver_settings,
    print_result,
)
from calib.files import load_calibration, save_updated_calibration
from calib.live import capture_map
from calib.radiometry import measure_return, with_return


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--calibration", type=Path, required=True, help="unit calibration file")
    parser.add_argument("--map", type=Path, help="distortion map (.npy) of the target")
    parser.add_argument("--backend", help="capture the target live from this camera backend")
    add_driver_arguments(parser)
    parser.add_argument("--code-length", type=int, default=16, help="code length N of the map")
    parser.add_argument("--code-row", type=int, default=2, help="live: Walsh row to strobe")
    parser.add_argument("--distance", type=float, required=True,
                        help="distance of the target from the camera, metres")
    parser.add_argument("--albedo", type=float, required=True,
                        help="the target's albedo (matte white card or paper: 0.8-0.9)")
    parser.add_argument("--exposure-us", type=float, required=True,
                        help="exposure the map was taken at, microseconds")
    parser.add_argument("--out", type=Path, required=True,
                        help="unit calibration file to write (may be --calibration itself)")
    add_output_arguments(parser)


def run(args: argparse.Namespace) -> int:
    calibration = load_calibration(args.calibration)  # a bad file stops here
    if (args.map is None) == (args.backend is None):
        raise CalibrationError("give the target as --map FILE or --backend NAME (one of them)")
    values = (load_map(args.map) if args.map is not None else
              capture_map(args.backend, args.code_length, args.code_row,
                          **driver_settings(args)))
    calibration = load_calibration(args.calibration, (values.shape[1], values.shape[0]))
    report = measure_return(calibration, values, args.code_length, args.distance,
                            args.albedo, args.exposure_us)
    written = save_updated_calibration(args.calibration, args.out,
                                       with_return(calibration, report))
    print_result({**report.as_dict(), "written": str(written)}, args.json)
    return 0
