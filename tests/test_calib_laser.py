"""Laser calibration maths: flat-target and board-plane fits on synthetic ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.errors import CalibrationError
from calib.board import BoardSpec, estimate_pose
from calib.laser import board_plane, fit_board_planes, fit_flat_target
from calib.peaks import LineRows, find_line_rows
from calib.synthetic import laser_rows_on_board, random_poses, render_board_view, render_line_map

CAMERA = CameraModel(1280, 800, 763.0, 641.3, 398.2)
LASER = LaserCalibration(0.075, tuple(np.radians([92.0, 90.0, 88.0])))
SPEC = BoardSpec()


def _flat_rows(distance_m: float, rng: np.random.Generator, noise_px: float = 0.1,
               outliers: float = 0.0) -> LineRows:
    """Exact Eq. 1 rows of every line on a wall at ``distance_m``, with noise and outliers."""
    f, b = CAMERA.focal_px, LASER.baseline_m
    rows = np.array([CAMERA.cy_px + f / np.tan(a) - f * b / distance_m for a in LASER.alpha_rad])
    rows = np.repeat(rows[:, None], CAMERA.width_px, axis=1)
    rows += rng.normal(0.0, noise_px, rows.shape)
    wild = rng.random(rows.shape) < outliers
    rows[wild] += rng.uniform(-40.0, 40.0, int(wild.sum()))
    return LineRows(rows, np.ones(rows.shape, dtype=bool))


def _assert_close(laser: LaserCalibration) -> None:
    assert laser.baseline_m == pytest.approx(LASER.baseline_m, rel=0.005)
    assert np.degrees(np.abs(np.subtract(laser.alpha_rad, LASER.alpha_rad))).max() < 0.05


def test_flat_target_fit_is_robust_to_outlier_columns() -> None:
    rng = np.random.default_rng(1)
    captures = [(z, _flat_rows(z, rng, outliers=0.1)) for z in (0.5, 0.8, 1.2, 2.0)]
    fit = fit_flat_target(CAMERA, captures)
    _assert_close(fit.laser)
    assert 0.85 < fit.inlier.mean() < 0.95
    assert fit.residual_rms_px == pytest.approx(0.1, rel=0.3)
    assert 0.0 < fit.laser.baseline_sigma_m < 0.001
    assert all(0.0 < s < np.radians(0.05) for s in fit.laser.alpha_sigma_rad)


def test_plain_least_squares_would_fail_on_these_outliers() -> None:
    rng = np.random.default_rng(1)
    captures = [(z, _flat_rows(z, rng, outliers=0.1)) for z in (0.5, 0.8, 1.2, 2.0)]
    u = np.concatenate([r.rows.ravel() for _, r in captures]) - CAMERA.cy_px
    inv_z = np.concatenate([np.full(r.rows.size, 1 / z) for z, r in captures])
    slope = np.polyfit(inv_z, u, 1)[0]  # one line for all, outliers included
    robust = fit_flat_target(CAMERA, captures).laser.baseline_m
    assert abs(-slope / CAMERA.focal_px - LASER.baseline_m) > abs(robust - LASER.baseline_m)


def test_flat_target_from_rendered_maps_with_bright_spots() -> None:
    rng = np.random.default_rng(2)
    captures = []
    for z in (0.6, 1.0, 1.6, 2.5):
        rows = _flat_rows(z, rng, noise_px=0.0).rows
        distortion_map = render_line_map(rows, CAMERA.height_px, rng)
        spots = rng.integers(0, distortion_map.size, 40)
        distortion_map.ravel()[spots] += 3000  # specular glints
        captures.append((z, find_line_rows(distortion_map, 3)))
    fit = fit_flat_target(CAMERA, captures)
    _assert_close(fit.laser)
    assert fit.residual_rms_px < 0.1


def test_board_planes_give_b_and_alpha_and_a_plane_check() -> None:
    rng = np.random.default_rng(3)
    views = []
    for pose in random_poses(SPEC, CAMERA, 5, rng, distance_m=(0.5, 1.1), tilt_deg=20.0):
        image = render_board_view(SPEC, CAMERA, pose, rng)
        rvec, tvec = estimate_pose(SPEC, CAMERA.matrix, np.zeros(5), image)
        rows = laser_rows_on_board(SPEC, CAMERA, LASER, pose)
        views.append((board_plane(rvec, tvec),
                      find_line_rows(render_line_map(rows, CAMERA.height_px, rng), 3)))
    fit = fit_board_planes(CAMERA, views)
    _assert_close(fit.laser)
    assert len(fit.planes) == 3
    for plane, alpha in zip(fit.planes, LASER.alpha_rad, strict=True):
        assert abs(np.degrees(plane.tilt_rad)) < 0.05
        assert abs(np.degrees(plane.alpha_rad - alpha)) < 0.05
    assert fit.residual_rms_mm < 2.0


def test_a_single_distance_is_rejected() -> None:
    rng = np.random.default_rng(4)
    with pytest.raises(CalibrationError, match="at least 3 different distances"):
        fit_flat_target(CAMERA, [(1.0, _flat_rows(1.0, rng)), (1.0, _flat_rows(1.0, rng))])


def test_lines_not_found_are_rejected() -> None:
    rng = np.random.default_rng(5)
    quiet = rng.normal(0.0, 5.0, (CAMERA.height_px, CAMERA.width_px))
    captures = [(z, find_line_rows(quiet, 3)) for z in (0.6, 1.0, 2.0)]
    with pytest.raises(CalibrationError, match="lines not found"):
        fit_flat_target(CAMERA, captures)


def test_too_few_points_are_rejected() -> None:
    rng = np.random.default_rng(6)
    captures = []
    for z in (0.6, 1.0, 2.0):
        rows = _flat_rows(z, rng)
        valid = np.zeros_like(rows.valid)
        valid[:, :5] = True
        captures.append((z, LineRows(rows.rows, valid)))
    with pytest.raises(CalibrationError, match="at least 20"):
        fit_flat_target(CAMERA, captures)


def test_too_few_board_poses_are_rejected() -> None:
    plane = board_plane(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    rows = _flat_rows(1.0, np.random.default_rng(7))
    with pytest.raises(CalibrationError, match="at least 3 board poses"):
        fit_board_planes(CAMERA, [(plane, rows), (plane, rows)])


def test_lens_distortion_is_rendered_and_recovered() -> None:
    from calib.intrinsics import calibrate_intrinsics

    camera = CameraModel(640, 400, 381.0, 319.5, 199.5, (-0.2, 0.08, 0.0, 0.0, 0.0))
    rng = np.random.default_rng(8)
    poses = random_poses(SPEC, camera, 8, rng, distance_m=(0.33, 0.7))
    fitted = calibrate_intrinsics(SPEC, [(f"v{i}", render_board_view(SPEC, camera, p, rng))
                                         for i, p in enumerate(poses)]).camera
    assert fitted.focal_px == pytest.approx(381.0, rel=0.005)
    assert fitted.distortion[0] == pytest.approx(-0.2, abs=0.01)
    views = []
    for pose in random_poses(SPEC, camera, 4, rng, distance_m=(0.35, 0.6), tilt_deg=20.0):
        image = render_board_view(SPEC, camera, pose, rng)
        rvec, tvec = estimate_pose(SPEC, fitted.matrix, np.asarray(fitted.distortion), image)
        rows = laser_rows_on_board(SPEC, camera, LASER, pose)
        views.append((board_plane(rvec, tvec),
                      find_line_rows(render_line_map(rows, camera.height_px, rng), 3)))
    _assert_close(fit_board_planes(fitted, views).laser)


def test_standard_errors_see_errors_shared_by_a_capture() -> None:
    def fit(distance_noise: float) -> LaserCalibration:
        rng = np.random.default_rng(9)
        distances = np.linspace(0.5, 2.5, 8)
        measured = distances * (1.0 + rng.normal(0.0, distance_noise, distances.size))
        return fit_flat_target(CAMERA, [(float(m), _flat_rows(float(z), rng))
                                        for z, m in zip(distances, measured, strict=True)]).laser

    exact, taped = fit(0.0), fit(0.01)  # distances as measured with a 1 % error each
    assert taped.baseline_sigma_m > 20 * exact.baseline_sigma_m
    assert min(taped.alpha_sigma_rad) > 5 * max(exact.alpha_sigma_rad)
    assert abs(exact.baseline_m - LASER.baseline_m) < 3.0 * exact.baseline_sigma_m
