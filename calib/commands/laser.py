"""``atris calib laser``: baseline b and angle α per line into the unit's calibration file.

Method ``flat``: distortion maps of a flat target at >= 3 known distances. Method
``board``: board views (projector off) and maps at >= 3 board poses. Inputs come from a
capture set (``--captures``) or from explicit pairs (``--flat Z=MAP``,
``--board-view IMAGE=MAP``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from atris_node.calibration import Calibration, CameraModel
from atris_node.errors import CalibrationError
from atris_node.progress import progress
from calib import laser
from calib.board import BoardSpec, estimate_pose
from calib.captures import CaptureSet, load_capture_set, load_map
from calib.commands.common import (
    add_board_arguments,
    add_output_arguments,
    board_from_args,
    plot_path,
    print_result,
    split_pair,
)
from calib.files import CameraFile, load_camera_file, save_calibration
from calib.peaks import LineRows, find_line_rows
from calib.plots import plot_laser


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--camera", type=Path, required=True,
                        help="camera file from 'atris calib intrinsics' (or a unit file)")
    parser.add_argument("--method", choices=("flat", "board"), default="flat")
    parser.add_argument("--captures", type=Path, help="capture set folder (captures.toml)")
    parser.add_argument("--flat", action="append", default=[], metavar="Z_M=MAP.npy",
                        help="flat target at Z_M metres and its distortion map (repeatable)")
    parser.add_argument("--board-view", action="append", default=[], metavar="IMAGE=MAP.npy",
                        help="board view (projector off) and its distortion map (repeatable)")
    parser.add_argument("--lines", type=int, default=None,
                        help="projected lines on the target (default: from the capture set)")
    add_board_arguments(parser)
    parser.add_argument("--out", type=Path, required=True, help="unit calibration file to write")
    add_output_arguments(parser)


def _line_rows(map_path: Path, lines: int, camera: CameraModel) -> LineRows:
    values = load_map(map_path)
    if values.shape != (camera.height_px, camera.width_px):
        raise CalibrationError(
            f"{map_path} is {values.shape[1]}x{values.shape[0]} but the camera file is for "
            f"{camera.width_px}x{camera.height_px} images")
    return find_line_rows(values, lines)


def _inputs(args: argparse.Namespace) -> tuple[CaptureSet | None, int, BoardSpec]:
    captures = load_capture_set(args.captures) if args.captures is not None else None
    lines = args.lines if args.lines is not None else (captures.lines if captures else None)
    if lines is None:
        raise CalibrationError("the number of lines is unknown: give --lines or --captures")
    return captures, lines, captures.board if captures else board_from_args(args)


def _flat_fit(args: argparse.Namespace, camera_file: CameraFile) -> laser.LaserFit:
    captures, lines, _ = _inputs(args)
    camera = camera_file.camera
    pairs = [(float(z), Path(m)) for z, m in (split_pair(t, "--flat") for t in args.flat)]
    if captures is not None:
        pairs += [(c.distance_m, captures.path(c.map)) for c in captures.flat]
    rows = [(z, _line_rows(path, lines, camera))
            for z, path in progress(pairs, "flat target", "capture")]
    return laser.fit_flat_target(camera, rows, camera_file.sigma)


def _board_fit(args: argparse.Namespace, camera_file: CameraFile) -> laser.LaserFit:
    captures, lines, spec = _inputs(args)
    camera = camera_file.camera
    pairs = [(Path(i), Path(m)) for i, m in (split_pair(t, "--board-view")
                                             for t in args.board_view)]
    if captures is not None:
        pairs += [(captures.path(c.image), captures.path(c.map)) for c in captures.board_laser]
    views = []
    for image_path, map_path in progress(pairs, "board poses", "pose"):
        image = cv2.imread(str(image_path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise CalibrationError(f"cannot read board view {image_path}")
        rvec, tvec = estimate_pose(spec, camera.matrix, np.asarray(camera.distortion), image)
        views.append((laser.board_plane(rvec, tvec), _line_rows(map_path, lines, camera)))
    return laser.fit_board_planes(camera, views, camera_file.sigma)


def result_values(fit: laser.LaserFit, out: Path) -> dict[str, object]:
    """The numbers ``--json`` prints: b, α per line (degrees), errors, residual RMS."""
    values: dict[str, object] = {
        "calibration_file": str(out), "baseline_m": fit.laser.baseline_m,
        "baseline_sigma_m": fit.laser.baseline_sigma_m,
        "alpha_deg": [float(np.degrees(a)) for a in fit.laser.alpha_rad],
        "alpha_sigma_deg": [float(np.degrees(s)) for s in fit.laser.alpha_sigma_rad],
        "residual_rms_px": fit.residual_rms_px, "residual_rms_mm": fit.residual_rms_mm,
        "samples": len(fit.inlier), "inliers": int(fit.inlier.sum())}
    if fit.planes:
        values["plane_check"] = [{"baseline_m": p.baseline_m,
                                  "alpha_deg": float(np.degrees(p.alpha_rad)),
                                  "tilt_deg": float(np.degrees(p.tilt_rad)), "rms_mm": p.rms_mm}
                                 for p in fit.planes]
    return values


def run(args: argparse.Namespace) -> int:
    camera_file = load_camera_file(args.camera)
    fit = (_flat_fit if args.method == "flat" else _board_fit)(args, camera_file)
    save_calibration(args.out, Calibration(camera=camera_file.camera, laser=fit.laser),
                     {"method": f"laser-{args.method}", "rms_px": camera_file.rms_px,
                      "residual_rms_px": fit.residual_rms_px,
                      "residual_rms_mm": fit.residual_rms_mm}, sigma=camera_file.sigma)
    values = result_values(fit, args.out)
    values["plot"] = str(plot_laser(fit, plot_path(args, args.out)))
    print_result(values, args.json)
    return 0
