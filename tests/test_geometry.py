"""Triangulation (paper Eq. 1), lens distortion, no-return handling and error propagation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from pipeline_scenes import Box, Scene, oak_calibration, render

from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.mounting import Mounting
from atris_node.pipeline.bands import line_bands
from atris_node.pipeline.geometry import (
    distort_pixels,
    range_sigma,
    singular_rows,
    triangulate,
    undistort_pixels,
)
from atris_node.pipeline.peaks import ExtractorSettings, extract_lines

CAMERA = CameraModel(1280, 800, 763.0, 639.5, 399.5, (-0.12, 0.05, 0.001, -0.0005, 0.0))
LASER = LaserCalibration(0.075, tuple(np.deg2rad([70.0, 80.0, 90.0, 100.0])))


def _points_on_planes(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n camera-frame points on the light planes y = z·cot α_k - b; returns (xyz, line)."""
    line = rng.integers(0, len(LASER.alpha_rad), n)
    z = rng.uniform(0.5, 10.0, n)
    x = rng.uniform(-0.5, 0.5, n) * z
    y = z / np.tan(np.asarray(LASER.alpha_rad)[line]) - LASER.baseline_m
    return np.stack([x, y, z], axis=1), line


def test_eq1_recovers_points_on_every_light_plane() -> None:
    xyz, line = _points_on_planes(np.random.default_rng(1), 500)
    u = CAMERA.focal_px * xyz[:, 1] / xyz[:, 2]
    v = CAMERA.focal_px * xyz[:, 0] / xyz[:, 2]
    pts = triangulate(u, v, line, CAMERA, LASER, z_max_m=20.0)
    assert pts.valid.all()
    np.testing.assert_allclose(pts.xyz_m, xyz, rtol=1e-10, atol=1e-12)
    assert pts.xyz_m.dtype == np.float64


def test_distortion_model_matches_opencv_and_inverts() -> None:
    xyz, _ = _points_on_planes(np.random.default_rng(2), 400)
    image, _ = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), CAMERA.matrix,
                                 np.array(CAMERA.distortion))
    col, row = image[:, 0, 0], image[:, 0, 1]
    ideal_row = CAMERA.focal_px * xyz[:, 1] / xyz[:, 2] + CAMERA.cy_px
    ideal_col = CAMERA.focal_px * xyz[:, 0] / xyz[:, 2] + CAMERA.cx_px
    r, c = distort_pixels(ideal_row, ideal_col, CAMERA)
    np.testing.assert_allclose(r, row, atol=1e-6)
    np.testing.assert_allclose(c, col, atol=1e-6)
    u, v = undistort_pixels(row, col, CAMERA)
    np.testing.assert_allclose(u, ideal_row - CAMERA.cy_px, atol=1e-5)
    np.testing.assert_allclose(v, ideal_col - CAMERA.cx_px, atol=1e-5)


def test_singular_row_and_beyond_are_no_return_never_inf() -> None:
    sing = singular_rows(CAMERA, LASER)
    u = np.array([sing[2], sing[2] + 5.0, sing[2] - 1e-9, sing[2] - 1.0, -300.0])
    pts = triangulate(u, np.zeros(5), np.full(5, 2), CAMERA, LASER, z_max_m=10.0,
                      sigma_u_px=0.1)
    assert pts.valid.tolist() == [False, False, False, False, True]
    assert np.isfinite(pts.xyz_m).all() and np.isfinite(pts.sigma_z_m).all()
    assert (pts.xyz_m[:, 2] > 0).all()
    assert (pts.sigma_z_m[~pts.valid] == 0).all()


def test_propagated_sigma_matches_the_handbook_example() -> None:
    sigma = range_sigma([5.0, 10.0], 0.1, 763.0, 0.075)
    np.testing.assert_allclose(sigma, [0.0437, 0.1747], atol=5e-4)


@pytest.mark.parametrize("z_m", [0.5, 1.0, 2.0, 4.0, 7.0, 10.0])
def test_range_rmse_is_within_the_propagated_bound(z_m: float) -> None:
    """A wall at z: RMSE of the triangulated range <= 1.5 × z²·σ_u/(f·b), σ_u being both
    the measured line-centre RMS and the σ_u the extraction reports."""
    cal = oak_calibration((90.0,), distortion=(-0.05, 0.01, 0.0, 0.0))
    scene = Scene(cal, Mounting(z_m=1.0), boxes=(Box(z_m, -50.0, 50.0, 5.0),), ground=False,
                  amplitude_dn=600.0, noise_dn=20.0, sigma_px=1.2)
    dmap, truth = render(scene, np.random.default_rng(int(z_m * 10)))
    cam, laser = cal.camera, cal.laser
    bands = line_bands(cam, laser, 0.4, 12.0, 3.0)
    ex = extract_lines(dmap.values, dmap.saturated, bands,
                       ExtractorSettings("steger", stripe_sigma_px=1.2))
    s = ex.samples
    assert len(s) > 600
    u, v = undistort_pixels(s.row_px, s.col_px, cam)
    pts = triangulate(u, v, s.line, cam, laser, z_max_m=12.0, sigma_u_px=s.sigma_u_px)
    rmse = float(np.sqrt(np.mean((pts.xyz_m[:, 2] - z_m) ** 2)))
    centre_rms = float(np.sqrt(np.mean((s.row_px - truth.line_rows[0, s.col_px.astype(int)])
                                       ** 2)))
    bound = float(range_sigma(z_m, centre_rms, cam.focal_px, laser.baseline_m))
    reported = float(np.sqrt(np.mean(pts.sigma_z_m**2)))
    assert rmse <= 1.5 * bound
    assert rmse <= 1.5 * reported
