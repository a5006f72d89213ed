"""``atris calib verify``: range error on a flat target at a known distance, beside the
bound ``σ_z ≈ z²·σ_u/(f·b)``; exit status 1 when the error is outside ``3·σ_z``.

The target's distortion map comes from a file (``--map``), a capture set's
``[[verify]]`` entries (``--captures``) or live from a camera backend (``--backend``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import numpy.typing as npt

from atris_node.errors import CalibrationError
from calib.captures import load_capture_set, load_map
from calib.commands.common import (
    add_driver_arguments,
    add_output_arguments,
    driver_settings,
    plot_path,
    print_result,
)
from calib.files import load_calibration
from calib.live import capture_map
from calib.peaks import find_line_rows
from calib.plots import plot_verify
from calib.verify import DEFAULT_SIGMA_U_PX, verify_flat_target


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--calibration", type=Path, required=True, help="unit calibration file")
    parser.add_argument("--captures", type=Path,
                        help="capture set folder: its [[verify]] targets are measured")
    parser.add_argument("--map", type=Path, help="distortion map (.npy) of a flat target")
    parser.add_argument("--backend", help="capture the target live from this camera backend")
    add_driver_arguments(parser)
    parser.add_argument("--code-length", type=int, default=16, help="live: code length N")
    parser.add_argument("--code-row", type=int, default=2, help="live: Walsh row to strobe")
    parser.add_argument("--distance", type=float,
                        help="distance of the --map or --backend target, metres")
    parser.add_argument("--sigma-u", type=float, default=DEFAULT_SIGMA_U_PX,
                        help="line row accuracy σ_u for the expected bound, px")
    add_output_arguments(parser)


def _need_distance(args: argparse.Namespace, option: str) -> float:
    if args.distance is None:
        raise CalibrationError(f"{option} needs --distance (metres)")
    return float(args.distance)


def _targets(args: argparse.Namespace) -> list[tuple[float, npt.NDArray[np.int32]]]:
    targets = []
    if args.map is not None:
        targets.append((_need_distance(args, "--map"), load_map(args.map)))
    if args.backend is not None:
        distance = _need_distance(args, "--backend")
        targets.append((distance, capture_map(args.backend, args.code_length, args.code_row,
                                              **driver_settings(args))))
    if args.captures is not None:
        captures = load_capture_set(args.captures)
        targets += [(c.distance_m, load_map(captures.path(c.map))) for c in captures.verify]
    if not targets:
        raise CalibrationError("nothing to verify: give --map, or --backend, with "
                               "--distance, or --captures with [[verify]] targets")
    return targets


def run(args: argparse.Namespace) -> int:
    load_calibration(args.calibration)  # a bad file stops here, before any capture
    reports = []
    for distance, values in _targets(args):
        calibration = load_calibration(args.calibration, (values.shape[1], values.shape[0]))
        rows = find_line_rows(values, len(calibration.laser.alpha_rad))
        report = verify_flat_target(calibration, rows, distance, args.sigma_u)
        summary: dict[str, object] = dict(report.as_dict())
        plot = plot_path(args, args.calibration).with_suffix("")
        summary["plot"] = str(plot_verify(report, f"{plot}.verify_{distance:.3f}m.png"))
        reports.append(summary)
    print_result({"targets": reports} if args.json else reports[0] if len(reports) == 1
                 else {"targets": reports}, args.json)
    return 0 if all(r["passed"] for r in reports) else 1
