"""Camera intrinsics from ChArUco views: focal length, principal point, distortion.

Views come from a folder of images or live from a camera backend. Corners are found with
``CharucoDetector.detectBoard`` and ``board.matchImagePoints``, then ``cv2.calibrateCamera``
fits K (square pixels: fx = fy) and five distortion coefficients (k3 fixed at 0).
Too few usable views, too few corners or an RMS reprojection error above the limit is a
:class:`CalibrationError`, never a silently poor camera file.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from atris_node.calibration import CameraModel
from atris_node.errors import CalibrationError
from calib.board import BoardDetection, BoardSpec, detect, to_gray8
from calib.progress import progress

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")
MIN_VIEWS = 5
MIN_CORNERS = 12
MAX_RMS_PX = 1.0


@dataclass(frozen=True)
class IntrinsicsResult:
    """The fitted camera, its RMS reprojection error (px) and the per-view errors (px)."""

    camera: CameraModel
    rms_px: float
    view_names: tuple[str, ...]
    view_rms_px: tuple[float, ...]
    corners_per_view: tuple[int, ...]


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


def _fit(found: list[BoardDetection], size: tuple[int, int]
         ) -> tuple[float, npt.NDArray[np.float64], npt.NDArray[np.float64], list[float]]:
    width, height = size
    guess = np.array([[float(width), 0.0, width / 2], [0.0, float(width), height / 2],
                      [0.0, 0.0, 1.0]])
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_K3
    object_points = [d.object_points.reshape(-1, 1, 3) for d in found]
    image_points = [d.image_points.reshape(-1, 1, 2) for d in found]
    rms, matrix, distortion, rvecs, tvecs = cv2.calibrateCamera(
        object_points, image_points, size, guess, np.zeros(5), flags=flags)
    view_rms = [_view_rms(d, _f64(r), _f64(t), _f64(matrix), _f64(distortion)) for d, r, t in zip(
        found, rvecs, tvecs, strict=True)]
    return float(rms), _f64(matrix), _f64(distortion).ravel(), view_rms


def _f64(array: object) -> npt.NDArray[np.float64]:
    return np.asarray(array, dtype=np.float64)


def _view_rms(detection: BoardDetection, rvec: npt.NDArray[np.float64],
              tvec: npt.NDArray[np.float64], matrix: npt.NDArray[np.float64],
              distortion: npt.NDArray[np.float64]) -> float:
    projected, _ = cv2.projectPoints(detection.object_points, rvec, tvec, matrix, distortion)
    error = projected.reshape(-1, 2) - detection.image_points
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


def calibrate_intrinsics(spec: BoardSpec, views: Iterable[tuple[str, npt.NDArray[np.uint8]]],
                         min_views: int = MIN_VIEWS, min_corners: int = MIN_CORNERS,
                         max_rms_px: float = MAX_RMS_PX) -> IntrinsicsResult:
    """Fit the camera to ChArUco ``views`` ((name, (H, W) uint8 image) pairs).

    Raises :class:`CalibrationError` for fewer than ``min_views`` views with at least
    ``min_corners`` corners each, or an RMS reprojection error above ``max_rms_px``.
    """
    names, found, size = _detections(spec, views, max(min_corners, 6))
    if len(found) < min_views:
        raise CalibrationError(f"only {len(found)} usable board views (with >= "
                               f"{min_corners} corners); at least {min_views} are needed")
    rms, matrix, distortion, view_rms = _fit(found, size)
    logger.info("intrinsics from %d views: f = %.2f px, RMS %.3f px", len(found),
                matrix[0, 0], rms)
    if not np.isfinite(rms) or rms > max_rms_px:
        raise CalibrationError(f"RMS reprojection error {rms:.3f} px is above the accepted "
                               f"{max_rms_px} px; check the board size and the views")
    camera = CameraModel(size[0], size[1], float((matrix[0, 0] + matrix[1, 1]) / 2),
                         float(matrix[0, 2]), float(matrix[1, 2]),
                         tuple(float(c) for c in distortion))
    return IntrinsicsResult(camera, rms, tuple(names), tuple(view_rms),
                            tuple(d.count for d in found))


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
