"""ChArUco board and intrinsics on synthetic views rendered with a known camera."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from atris_node.calibration import CameraModel
from atris_node.errors import CalibrationError
from calib.board import BoardSpec, detect, write_printable
from calib.intrinsics import calibrate_intrinsics
from calib.synthetic import random_poses, render_board_view

SPEC = BoardSpec()
TRUE_CAMERA = CameraModel(1280, 800, 763.0, 641.3, 398.2)


@pytest.fixture(scope="module")
def views() -> list[tuple[str, np.ndarray]]:
    rng = np.random.default_rng(7)
    poses = random_poses(SPEC, TRUE_CAMERA, 9, rng)
    return [(f"view_{i}", render_board_view(SPEC, TRUE_CAMERA, p, rng, noise_dn=3.0))
            for i, p in enumerate(poses)]


def test_focal_length_and_principal_point_round_trip(views: list) -> None:
    result = calibrate_intrinsics(SPEC, views)
    assert result.camera.focal_px == pytest.approx(TRUE_CAMERA.focal_px, rel=0.005)
    assert result.camera.cx_px == pytest.approx(TRUE_CAMERA.cx_px, abs=3.0)
    assert result.camera.cy_px == pytest.approx(TRUE_CAMERA.cy_px, abs=3.0)
    assert (result.camera.width_px, result.camera.height_px) == (1280, 800)
    assert result.rms_px < 0.3
    assert len(result.view_rms_px) == 9


def test_too_few_views_is_refused(views: list) -> None:
    with pytest.raises(CalibrationError, match="only 3 usable board views"):
        calibrate_intrinsics(SPEC, views[:3])


def test_too_few_corners_is_refused(views: list) -> None:
    with pytest.raises(CalibrationError, match="only 0 usable board views"):
        calibrate_intrinsics(SPEC, views, min_corners=SPEC.corner_count + 1)


def test_rms_above_threshold_is_refused(views: list) -> None:
    with pytest.raises(CalibrationError, match=r"RMS reprojection error .* above"):
        calibrate_intrinsics(SPEC, views, max_rms_px=0.001)


def test_views_of_different_sizes_are_refused(views: list) -> None:
    mixed = [*views[:5], ("small", cv2.resize(views[5][1], (640, 400)))]
    with pytest.raises(CalibrationError, match="all views must have one size"):
        calibrate_intrinsics(SPEC, mixed)


def test_printable_board_is_detected_with_every_corner(tmp_path: Path) -> None:
    png, pdf = write_printable(SPEC, tmp_path / "board.png", tmp_path / "board.pdf", dpi=72)
    assert pdf is not None and pdf.read_bytes().startswith(b"%PDF")
    image = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    square_px = round(SPEC.square_m * 1000 / 25.4 * 72)
    margin = 2 * (square_px // 2)  # half a square of white on each side
    assert image.shape == (SPEC.squares_y * square_px + margin,
                           SPEC.squares_x * square_px + margin)
    detection = detect(SPEC, image)
    assert detection is not None and detection.count == SPEC.corner_count


def test_invalid_board_is_a_clear_error() -> None:
    with pytest.raises(CalibrationError, match="marker_m must be in"):
        BoardSpec(square_m=0.03, marker_m=0.04)
    with pytest.raises(CalibrationError, match="unknown ArUco dictionary"):
        BoardSpec(dictionary="DICT_9X9_1")


def test_live_views_come_from_a_camera_backend_with_the_projector_off() -> None:
    from calib.intrinsics import live_views

    views = live_views("sim", 3, every=2, scene="indoor_lab", seed=1)
    assert [v.shape for _, v in views] == [(400, 640)] * 3
    assert all(v.dtype == np.uint8 and v.max() > 0 for _, v in views)
    assert len({name for name, _ in views}) == 3


def test_live_scene_without_a_board_is_refused(capsys: pytest.CaptureFixture[str],
                                                tmp_path: Path) -> None:
    from atris_node.cli import main

    code = main(["calib", "intrinsics", "--backend", "sim", "--driver-option",
                 "scene=indoor_lab", "--views", "5", "--every", "1", "--out",
                 str(tmp_path / "camera.toml")])
    assert code == 1
    assert "only 0 usable board views" in capsys.readouterr().err
    assert not (tmp_path / "camera.toml").exists()
