"""Camera intrinsics from ChArUco views: focal length, principal point, distortion.

Views come from a folder of images or live from a camera backend. Corners are found with
``CharucoDetector.detectBoard`` and ``board.matchImagePoints``, then ``cv2.calibrateCamera``
fits K (square pixels: fx = fy) and the distortion k1, k2 (k3 and, by default, the
tangential p1, p2 held at 0).
Too few usable views, too few corners or an RMS reprojection error above the limit is a
:class:`CalibrationError`, never a silently poor camera file.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from atris_node.calibration import CameraModel
from atris_node.errors import CalibrationError
from atris_node.progress import progress
from calib.board import BoardDetection, BoardSpec, detect, to_gray8
from calib.files import IntrinsicsSigma

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")
MIN_VIEWS = 5
MIN_CORNERS = 12
MAX_RMS_PX = 1.0


@dataclass(frozen=True)
class IntrinsicsResult:
    """The fitted camera, its RMS reprojection error (px), the per-view errors (px) and
    the standard deviations of f, cx, cy (px)."""

    camera: CameraModel
    rms_px: float
    view_names: tuple[str, ...]
    view_rms_px: tuple[float, ...]
    corners_per_view: tuple[int, ...]
    sigma: IntrinsicsSigma = field(default_factory=IntrinsicsSigma)


def image_files(folder: str | Path) -> list[Path]:
    """Image files of ``folder`` (png, jpg, bmp, tif, pgm), sorted by name."""
    root = Path(folder)
    if not root.is_dir():
        raise CalibrationError(f"image folder {root} does not exist")
    return sorted(p for p in root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def read_images(paths: Iterable[Path]) -> Iterator[tuple[str, npt.NDArray[np.uint8]]]:
    """(name, (H, W) uint8 image) for each readable file; unreadable files are skipped."""
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            logger.warning("cannot read %s; skipped", path)
            continue
        yield path.name, to_gray8(image)


def _detections(spec: BoardSpec, views: Iterable[tuple[str, npt.NDArray[np.uint8]]],
                min_corners: int) -> tuple[list[str], list[BoardDetection], tuple[int, int]]:
    board = spec.make_board()
    names: list[str] = []
    found: list[BoardDetection] = []
    size = (0, 0)
    for name, image in progress(views, "board views", "view"):
        size = _same_size(size, image, name)
        detection = detect(spec, image, board)
        count = 0 if detection is None else detection.count
        if detection is None or count < min_corners:
            logger.warning("%s: %d board corners (need %d); view skipped", name, count,
                           min_corners)
            continue
        names.append(name)
        found.append(detection)
    return names, found, size


def _same_size(size: tuple[int, int], image: npt.NDArray[np.uint8],
               name: str) -> tuple[int, int]:
    here = (int(image.shape[1]), int(image.shape[0]))
    if size not in ((0, 0), here):
        raise CalibrationError(f"{name} is {here[0]}x{here[1]} but earlier views are "
                               f"{size[0]}x{size[1]}; all views must have one size")
    return here


@dataclass(frozen=True)
class _Fit:
    rms_px: float
    matrix: npt.NDArray[np.float64]
    distortion: npt.NDArray[np.float64]
    sigma: npt.NDArray[np.float64]  # standard deviations of fx, fy, cx, cy, ... (px)
    view_rms_px: list[float]


def _fit(found: list[BoardDetection], size: tuple[int, int], tangential: bool) -> _Fit:
    width, height = size
    guess = np.array([[float(width), 0.0, width / 2], [0.0, float(width), height / 2],
                      [0.0, 0.0, 1.0]])
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_K3
    flags |= 0 if tangential else cv2.CALIB_ZERO_TANGENT_DIST
    object_points = [d.object_points.reshape(-1, 1, 3) for d in found]
    image_points = [d.image_points.reshape(-1, 1, 2) for d in found]
    rms, matrix, distortion, _, _, sigma, _, per_view = cv2.calibrateCameraExtended(
        object_points, image_points, size, guess, np.zeros(5), flags=flags)
    return _Fit(float(rms), _f64(matrix), _f64(distortion).ravel(), _f64(sigma).ravel(),
                [float(e) for e in _f64(per_view).ravel()])


def _f64(array: object) -> npt.NDArray[np.float64]:
    return np.asarray(array, dtype=np.float64)


def calibrate_intrinsics(spec: BoardSpec, views: Iterable[tuple[str, npt.NDArray[np.uint8]]],
                         min_views: int = MIN_VIEWS, min_corners: int = MIN_CORNERS,
                         max_rms_px: float = MAX_RMS_PX, *,
                         tangential: bool = False) -> IntrinsicsResult:
    """Fit the camera to ChArUco ``views`` ((name, (H, W) uint8 image) pairs).

    Raises :class:`CalibrationError` for fewer than ``min_views`` views with at least
    ``min_corners`` corners each, or an RMS reprojection error above ``max_rms_px``.
    Tangential distortion (p1, p2) is held at 0 unless ``tangential``: free, it trades
    off against the principal point, whose row error becomes an error in every α_k.
    """
    names, found, size = _detections(spec, views, max(min_corners, 6))
    if len(found) < min_views:
        raise CalibrationError(f"only {len(found)} usable board views (with >= "
                               f"{min_corners} corners); at least {min_views} are needed")
    fit = _fit(found, size, tangential)
    logger.info("intrinsics from %d views: f = %.2f px, RMS %.3f px", len(found),
                fit.matrix[0, 0], fit.rms_px)
    if not np.isfinite(fit.rms_px) or fit.rms_px > max_rms_px:
        raise CalibrationError(f"RMS reprojection error {fit.rms_px:.3f} px is above the "
                               f"accepted {max_rms_px} px; check the board size and the views")
    matrix = fit.matrix
    camera = CameraModel(size[0], size[1], float((matrix[0, 0] + matrix[1, 1]) / 2),
                         float(matrix[0, 2]), float(matrix[1, 2]),
                         tuple(float(c) for c in fit.distortion))
    values = np.nan_to_num(fit.sigma[:4], nan=0.0, posinf=0.0)
    sigma = IntrinsicsSigma(float(max(values[0], values[1])), float(values[2]), float(values[3]))
    return IntrinsicsResult(camera, fit.rms_px, tuple(names), tuple(fit.view_rms_px),
                            tuple(d.count for d in found), sigma)


def live_views(backend: str, count: int, every: int = 10, **settings: object
               ) -> list[tuple[str, npt.NDArray[np.uint8]]]:
    """``count`` views from a camera backend, one every ``every`` sub-frames, projector off."""
    import drivers

    camera, projector = drivers.open_backend(backend, **settings)
    views: list[tuple[str, npt.NDArray[np.uint8]]] = []
    with camera, projector:
        projector.off()
        for index in progress(range(count * every), "live views", "sub-frame"):
            sub_frame = camera.read(timeout_s=2.0)
            if index % every == every - 1:
                views.append((f"live_{sub_frame.sequence:06d}", to_gray8(sub_frame.pixels)))
    return views
