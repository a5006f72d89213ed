"""Baseline b and angle α_k of each projected line, with standard errors.

Both methods end in the same linear model. Paper Eq. 1 for line k gives
``1/z = cot α_k / b − u / (f·b)``, i.e. a line in (u, 1/z). The noise is in the measured
row u (pixels) while the range is known, so the same line is fitted as

    u = A_k + B · (1/z),   A_k = f·cot α_k,   B = −f·b,

one shared slope B and one intercept A_k per line, by iteratively reweighted least
squares with Huber weights against each capture's own robust noise scale (outlier columns
get small weights, far and faint targets count less). Then ``b = −B/f`` and
``α_k = atan2(f, A_k)`` in (0, π); standard errors come from the weighted covariance.

- Flat target (:func:`fit_flat_target`): a wall perpendicular to the optical axis at
  ≥ 3 known distances; every line sample of a capture has that z.
- Board planes (:func:`fit_board_planes`): a ChArUco board at several poses; the board
  pose (``solvePnP``) gives the board plane, each laser pixel's ray meets it at a 3D point
  whose z enters the same fit. Each line's points are also fitted with an SVD plane as a
  check of the model (a light plane parallel to the camera x axis).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.errors import CalibrationError
from calib.files import IntrinsicsSigma
from calib.peaks import LineRows

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
HUBER_K = 1.345
MIN_DISTANCES = 3
MIN_SAMPLES_PER_LINE = 20


@dataclass(frozen=True)
class LineSamples:
    """Fit input: per sample the row ``u_px`` from the principal point, the known
    ``inv_z`` (1/m), the line index and the capture (distance or pose) it came from."""

    u_px: FloatArray
    inv_z: FloatArray
    line: npt.NDArray[np.int64]
    capture: npt.NDArray[np.int64]


@dataclass(frozen=True)
class PlaneCheck:
    """SVD plane of one line's 3D points: its own b (m), α (rad) and tilt about z (rad)."""

    baseline_m: float
    alpha_rad: float
    tilt_rad: float
    rms_mm: float


@dataclass(frozen=True)
class LaserFit:
    """Result of a laser calibration: values with standard errors and the residuals.

    ``residual_px`` and ``residual_mm`` are per sample (u measured − u model, and range
    from Eq. 1 − known range); ``inlier`` marks the samples the fit kept.
    """

    laser: LaserCalibration
    residual_rms_px: float
    residual_rms_mm: float
    samples: LineSamples
    residual_px: FloatArray
    residual_mm: FloatArray
    inlier: npt.NDArray[np.bool_]
    planes: tuple[PlaneCheck, ...] = field(default_factory=tuple)


def _design(samples: LineSamples, lines: int) -> FloatArray:
    """(n, 1 + K) design matrix: 1/z, then one indicator column per line."""
    indicators = np.eye(lines)[samples.line]
    return np.column_stack([samples.inv_z, indicators])


def _robust_weights(residual: FloatArray, capture: npt.NDArray[np.int64]
                    ) -> tuple[FloatArray, FloatArray]:
    """(weights, huber) per sample: ``huber`` in (0, 1] against the sample's own capture's
    robust scale (far targets are noisier), ``weights = huber / scale²``."""
    scale = np.empty_like(residual)
    for group in np.unique(capture):
        here = capture == group
        scale[here] = max(1.4826 * float(np.median(np.abs(residual[here]))), 1e-6)
    ratio = np.abs(residual) / (HUBER_K * scale)
    huber = np.where(ratio <= 1.0, 1.0, 1.0 / np.maximum(ratio, 1e-12))
    return huber / scale**2, huber


def _irls(design: FloatArray, u_px: FloatArray, capture: npt.NDArray[np.int64],
          iterations: int = 30) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Huber IRLS with a noise scale per capture: (parameters (p,), weights (n,),
    Huber factors (n,), 1 for inliers)."""
    weights, huber = np.ones_like(u_px), np.ones_like(u_px)
    params = np.zeros(design.shape[1])
    for _ in range(iterations):
        root = np.sqrt(weights)
        params = np.asarray(np.linalg.lstsq(design * root[:, None], u_px * root,
                                            rcond=None)[0], dtype=np.float64)
        new, huber = _robust_weights(u_px - design @ params, capture)
        if np.allclose(new / new.max(), weights / weights.max(), atol=1e-6):
            break
        weights = new
    return params, weights, huber


def _covariance(design: FloatArray, u_px: FloatArray, params: FloatArray,
                weights: FloatArray, capture: npt.NDArray[np.int64]) -> FloatArray:
    """(p, p) covariance of the fit: per parameter the larger of the classical estimate
    and the jackknife over captures (leave one capture out, refit). The samples of one
    capture share its errors (target distance, board pose), which the classical estimate
    from the per-sample scatter does not see."""
    residual = u_px - design @ params
    bread = np.linalg.inv(design.T @ (design * weights[:, None]))
    dof = max(len(residual) - design.shape[1], 1)
    classical = float(np.sum(weights * residual**2)) / dof * bread
    groups = np.unique(capture)
    if len(groups) < 3:
        return classical
    refits = np.array([_irls(design[capture != g], u_px[capture != g], capture[capture != g])[0]
                       for g in groups])
    spread = refits - refits.mean(axis=0)
    jackknife = spread.T @ spread * (len(groups) - 1) / len(groups)
    scale = np.sqrt(np.maximum(np.diag(jackknife), np.diag(classical)) / np.diag(classical))
    return classical * np.outer(scale, scale)


def _check_samples(samples: LineSamples, lines: int) -> None:
    counts = np.bincount(samples.line, minlength=lines)
    if counts.min() < MIN_SAMPLES_PER_LINE:
        raise CalibrationError(f"lines not found: samples per line {counts.tolist()}; each "
                               f"line needs at least {MIN_SAMPLES_PER_LINE}")
    for k in range(lines):
        captures = len(np.unique(samples.capture[samples.line == k]))
        if captures < MIN_DISTANCES:
            raise CalibrationError(f"line {k} was found in {captures} captures; at least "
                                   f"{MIN_DISTANCES} distances or poses are needed")
    if np.ptp(samples.inv_z) < 0.05 * np.max(samples.inv_z):
        raise CalibrationError("the samples span too small a range of distances; the "
                               "baseline needs targets spread over depth")


def _to_laser(params: FloatArray, covariance: FloatArray, focal_px: float,
              sigma: IntrinsicsSigma) -> LaserCalibration:
    """b = −B/f and α_k = atan2(f, A_k), with standard errors from the fit's covariance
    and the intrinsics' σ_f and σ_cy (a shift of cy shifts every A_k)."""
    slope, intercepts = params[0], params[1:]
    if slope >= 0:
        raise CalibrationError(f"the line rows do not move up with range (slope {slope:.3g} "
                               "px·m); the captures do not fit a projector above the camera")
    baseline = -slope / focal_px
    baseline_sigma = float(np.hypot(np.sqrt(covariance[0, 0]) / focal_px,
                                    baseline * sigma.focal_px / focal_px))
    alpha = np.arctan2(focal_px, intercepts)
    spread = focal_px**2 + intercepts**2
    alpha_sigma = np.sqrt((focal_px / spread) ** 2 * (np.diag(covariance)[1:] + sigma.cy_px**2)
                          + (intercepts / spread) ** 2 * sigma.focal_px**2)
    return LaserCalibration(float(baseline), tuple(float(a) for a in alpha),
                            baseline_sigma, tuple(float(s) for s in alpha_sigma))


def _range_residual_mm(samples: LineSamples, laser: LaserCalibration,
                       focal_px: float) -> FloatArray:
    """Eq. 1 range from u minus the known range, mm; 0.0 where Eq. 1 has no return."""
    singular = focal_px / np.tan(np.asarray(laser.alpha_rad))[samples.line]
    denominator = singular - samples.u_px
    ok = denominator > 1e-6
    z_model = focal_px * laser.baseline_m / np.where(ok, denominator, 1.0)
    return np.where(ok, (z_model - 1.0 / samples.inv_z) * 1000.0, 0.0)


def fit_lines(samples: LineSamples, lines: int, focal_px: float,
              sigma: IntrinsicsSigma | None = None) -> LaserFit:
    """Fit b and α_k to ``samples`` of ``lines`` lines (see the module text); ``sigma``
    are the intrinsics' standard deviations, added to the standard errors."""
    _check_samples(samples, lines)
    design = _design(samples, lines)
    params, weights, huber = _irls(design, samples.u_px, samples.capture)
    residual_px = samples.u_px - design @ params
    covariance = _covariance(design, samples.u_px, params, weights, samples.capture)
    laser = _to_laser(params, covariance, focal_px, sigma or IntrinsicsSigma())
    residual_mm = _range_residual_mm(samples, laser, focal_px)
    inlier = huber >= 0.5
    rms_px = float(np.sqrt(np.mean(residual_px[inlier] ** 2)))
    rms_mm = float(np.sqrt(np.mean(residual_mm[inlier] ** 2)))
    logger.info("laser fit: b = %.5f m, alpha = %s deg, RMS %.3f px / %.2f mm, %d of %d inliers",
                laser.baseline_m, np.round(np.degrees(laser.alpha_rad), 4).tolist(), rms_px,
                rms_mm, int(inlier.sum()), len(inlier))
    return LaserFit(laser, rms_px, rms_mm, samples, residual_px, residual_mm, inlier)


# ---------------------------------------------------------------- pixels to samples


def normalized_rays(camera: CameraModel, columns: FloatArray, rows: FloatArray) -> FloatArray:
    """(n, 2) undistorted normalised coordinates (x/z, y/z) of pixels (column, row)."""
    pixels = np.column_stack([columns, rows]).reshape(-1, 1, 2).astype(np.float64)
    if not any(camera.distortion):
        return (pixels.reshape(-1, 2) - [camera.cx_px, camera.cy_px]) / camera.focal_px
    undistorted = cv2.undistortPoints(pixels, camera.matrix, np.asarray(camera.distortion))
    return np.asarray(undistorted, dtype=np.float64).reshape(-1, 2)


def _valid_pixels(line_rows: LineRows) -> tuple[FloatArray, FloatArray, npt.NDArray[np.int64]]:
    line, column = np.nonzero(line_rows.valid)
    return column.astype(np.float64), line_rows.rows[line, column], line.astype(np.int64)


def flat_target_samples(camera: CameraModel, captures: list[tuple[float, LineRows]]
                        ) -> LineSamples:
    """Samples from flat-target captures: (distance z in m, line rows) pairs."""
    parts: list[tuple[FloatArray, FloatArray, npt.NDArray[np.int64], npt.NDArray[np.int64]]] = []
    for index, (distance_m, line_rows) in enumerate(captures):
        columns, rows, line = _valid_pixels(line_rows)
        u_px = normalized_rays(camera, columns, rows)[:, 1] * camera.focal_px
        parts.append((u_px, np.full(len(u_px), 1.0 / distance_m), line,
                      np.full(len(u_px), index, dtype=np.int64)))
    return LineSamples(*(np.concatenate(p) for p in zip(*parts, strict=True)))


def fit_flat_target(camera: CameraModel, captures: list[tuple[float, LineRows]],
                    sigma: IntrinsicsSigma | None = None) -> LaserFit:
    """Method (a): b and α_k from a flat target at ≥ 3 known distances (m)."""
    distances = sorted({round(d, 4) for d, _ in captures})
    if len(distances) < MIN_DISTANCES:
        raise CalibrationError(f"flat-target calibration needs at least {MIN_DISTANCES} "
                               f"different distances, got {distances}")
    if any(not (0.05 < d < 100.0) for d in distances):
        raise CalibrationError(f"target distances must be in metres within (0.05, 100), "
                               f"got {distances}")
    lines = _line_count(captures)
    return fit_lines(flat_target_samples(camera, captures), lines, camera.focal_px, sigma)


def _line_count(captures: Sequence[tuple[object, LineRows]]) -> int:
    counts = {rows.line_count for _, rows in captures}
    if len(counts) != 1:
        raise CalibrationError(f"captures disagree on the number of lines: {sorted(counts)}")
    return counts.pop()


# ---------------------------------------------------------------- board planes


@dataclass(frozen=True)
class BoardPlane:
    """The board plane of one pose in the camera frame: unit normal (3,) and d (m), n·X = d."""

    normal: FloatArray
    d_m: float


def board_plane(rvec: FloatArray, tvec: FloatArray) -> BoardPlane:
    """The plane of a board whose pose (board to camera) is ``rvec``, ``tvec`` (m)."""
    normal = np.asarray(cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0],
                        dtype=np.float64)[:, 2]
    return BoardPlane(normal, float(normal @ np.asarray(tvec, dtype=np.float64).ravel()))


def board_points(camera: CameraModel, plane: BoardPlane, line_rows: LineRows
                 ) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    """3D camera-frame points (n, 3) in metres where the laser pixels' rays meet the board,
    with their line indices (n,)."""
    columns, rows, line = _valid_pixels(line_rows)
    rays = np.column_stack([normalized_rays(camera, columns, rows), np.ones(len(rows))])
    along = rays @ plane.normal
    ok = along > 1e-6
    points = rays[ok] * (plane.d_m / along[ok])[:, None]
    return points, line[ok]


def svd_plane(points: FloatArray) -> PlaneCheck:
    """Least-squares plane through (n, 3) points, read as the light-plane model."""
    centroid = points.mean(axis=0)
    normal = np.linalg.svd(points - centroid, full_matrices=False)[2][-1]
    normal = normal if normal[1] > 0 else -normal
    rms_mm = float(np.sqrt(np.mean(((points - centroid) @ normal) ** 2))) * 1000.0
    scale = np.hypot(normal[1], normal[2])
    d = float(normal @ centroid)
    return PlaneCheck(baseline_m=float(-d / scale),
                      alpha_rad=float(np.arctan2(normal[1], -normal[2])),
                      tilt_rad=float(np.arcsin(np.clip(normal[0], -1.0, 1.0))), rms_mm=rms_mm)


def fit_board_planes(camera: CameraModel, views: list[tuple[BoardPlane, LineRows]],
                     sigma: IntrinsicsSigma | None = None) -> LaserFit:
    """Method (b): b and α_k from laser lines on a board at ≥ 3 poses."""
    if len(views) < MIN_DISTANCES:
        raise CalibrationError(f"board-plane calibration needs at least {MIN_DISTANCES} "
                               f"board poses, got {len(views)}")
    lines = _line_count(views)
    per_view = [board_points(camera, plane, rows) for plane, rows in views]
    points = np.concatenate([p for p, _ in per_view])
    line = np.concatenate([k for _, k in per_view])
    capture = np.concatenate([np.full(len(k), i) for i, (_, k) in enumerate(per_view)])
    samples = LineSamples(points[:, 1] / points[:, 2] * camera.focal_px, 1.0 / points[:, 2],
                          line, capture.astype(np.int64))
    fit = fit_lines(samples, lines, camera.focal_px, sigma)
    planes = tuple(svd_plane(points[(line == k) & fit.inlier]) for k in range(lines))
    return LaserFit(fit.laser, fit.residual_rms_px, fit.residual_rms_mm, samples,
                    fit.residual_px, fit.residual_mm, fit.inlier, planes)
