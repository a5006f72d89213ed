"""``atris calib intrinsics``: camera file from ChArUco views (folder, capture set or live)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import numpy.typing as npt

from atris_node.errors import CalibrationError
from calib import intrinsics
from calib.board import BoardSpec
from calib.captures import load_capture_set
from calib.commands.common import (
    add_board_arguments,
    add_driver_arguments,
    add_output_arguments,
    board_from_args,
    driver_settings,
    plot_path,
    print_result,
)
from calib.files import save_camera_file
from calib.plots import plot_intrinsics

Views = list[tuple[str, npt.NDArray[np.uint8]]]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--images", type=Path, help="folder of board images")
    source.add_argument("--captures", type=Path,
                        help="capture set folder (its board views and board description)")
    source.add_argument("--backend", help="camera backend to capture from live (sim, depthai)")
    add_driver_arguments(parser)
    parser.add_argument("--views", type=int, default=15, help="live: views to capture")
    parser.add_argument("--every", type=int, default=10, help="live: keep one sub-frame in N")
    add_board_arguments(parser)
    parser.add_argument("--out", type=Path, required=True, help="camera file to write (TOML)")
    parser.add_argument("--min-views", type=int, default=intrinsics.MIN_VIEWS)
    parser.add_argument("--min-corners", type=int, default=intrinsics.MIN_CORNERS)
    parser.add_argument("--max-rms", type=float, default=intrinsics.MAX_RMS_PX,
                        help="largest accepted RMS reprojection error, px")
    parser.add_argument("--tangential", action="store_true",
                        help="also fit tangential distortion p1, p2 (default: held at 0)")
    add_output_arguments(parser)


def _views(args: argparse.Namespace) -> tuple[BoardSpec, Views]:
    if args.captures is not None:
        captures = load_capture_set(args.captures)
        paths = [captures.path(name) for name in captures.intrinsics]
        return captures.board, list(intrinsics.read_images(paths))
    spec = board_from_args(args)
    if args.images is not None:
        return spec, list(intrinsics.read_images(intrinsics.image_files(args.images)))
    return spec, list(intrinsics.live_views(args.backend, args.views, args.every,
                                            **driver_settings(args)))


def run(args: argparse.Namespace) -> int:
    spec, views = _views(args)
    if not views:
        raise CalibrationError("no board views were found; accepted: png, jpg, bmp, tif, pgm")
    result = intrinsics.calibrate_intrinsics(spec, views, args.min_views, args.min_corners,
                                             args.max_rms, tangential=args.tangential)
    save_camera_file(args.out, result.camera, result.rms_px, spec.as_dict(),
                     {"views": len(result.view_names), "method": "charuco"},
                     sigma=result.sigma)
    plot = plot_intrinsics(result, plot_path(args, args.out))
    camera = result.camera
    print_result({"camera_file": str(args.out), "focal_px": camera.focal_px,
                  "focal_sigma_px": result.sigma.focal_px, "cx_px": camera.cx_px,
                  "cy_px": camera.cy_px, "cy_sigma_px": result.sigma.cy_px,
                  "distortion": list(camera.distortion), "rms_px": result.rms_px,
                  "views": len(result.view_names), "plot": str(plot)}, args.json)
    return 0
