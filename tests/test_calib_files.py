"""Calibration files: round trip, and every invalid file is a clear error at load."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from atris_node.calibration import Calibration, CameraModel, LaserCalibration
from atris_node.errors import CalibrationError
from calib.files import load_calibration, load_camera_file, save_calibration, save_camera_file


def _calibration() -> Calibration:
    camera = CameraModel(1280, 800, 763.25, 641.5, 399.75, (0.01, -0.02, 0.0, 0.0, 0.001))
    laser = LaserCalibration(0.075, (1.45, 1.52), 1e-4, (2e-4, 3e-4))
    return Calibration(camera=camera, laser=laser)


@pytest.fixture
def unit_file(tmp_path: Path) -> Path:
    return save_calibration(tmp_path / "unit.calib.toml", _calibration(),
                            {"method": "flat-target", "rms_px": 0.2, "residual_rms_px": 0.05})


def _edit(path: Path, old: str, new: str) -> Path:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    return path


def test_unit_file_round_trip(unit_file: Path) -> None:
    assert load_calibration(unit_file, expected_size=(1280, 800)) == _calibration()


def test_camera_file_round_trip(tmp_path: Path) -> None:
    camera = _calibration().camera
    path = save_camera_file(tmp_path / "cam.toml", camera, 0.31,
                            {"squares_x": 9, "square_m": 0.03}, {"views": 12})
    loaded = load_camera_file(path, expected_size=(1280, 800))
    assert loaded.camera == camera
    assert loaded.rms_px == 0.31
    assert loaded.board["squares_x"] == 9
    assert loaded.meta["views"] == 12
    assert "created" in loaded.meta


def test_camera_file_is_not_a_unit_calibration(tmp_path: Path) -> None:
    path = save_camera_file(tmp_path / "cam.toml", _calibration().camera, 0.3, {}, {})
    with pytest.raises(CalibrationError, match="unit calibration"):
        load_calibration(path)


def test_other_resolution_is_rejected(unit_file: Path) -> None:
    with pytest.raises(CalibrationError, match="1280x800 images but the camera delivers 640x400"):
        load_calibration(unit_file, expected_size=(640, 400))


@pytest.mark.parametrize(("old", "new", "message"), [
    ("baseline_m = 0.075", "baseline_m = 75.0", "baseline_m = 75.0 is outside"),
    ("alpha_rad = [1.45, 1.52]", "alpha_rad = [83.1, 87.1]", "alpha_rad = 83.1 is outside"),
    ("alpha_rad = [1.45, 1.52]", "alpha_rad = []", "at least one line"),
    ("alpha_rad = [1.45, 1.52]", "alpha_rad = [1.45]", "one per line"),
    ("focal_px = 763.25", 'focal_px = "763"', "focal_px must be a number"),
    ("focal_px = 763.25", "focal_px = nan", "outside the accepted range"),
    ("width_px = 1280", "width_px = 0", "positive integer"),
    ("baseline_m = 0.075", "baseline_mm = 75.0", "unknown keys in \\[laser\\]"),
    ("version = 1", "version = 7", "version 7 is not supported"),
    ('format = "atris-calibration"', 'format = "other"', "format must be"),
    ("[laser]", "[lasers]", "the \\[laser\\] table is missing"),
    ("cx_px = 641.5", "cx_px = 9000.0", "cx_px = 9000.0 is outside"),
])
def test_invalid_file_is_a_clear_error(unit_file: Path, old: str, new: str,
                                       message: str) -> None:
    with pytest.raises(CalibrationError, match=message):
        load_calibration(_edit(unit_file, old, new))


def test_corrupt_file_is_a_clear_error(unit_file: Path) -> None:
    unit_file.write_bytes(unit_file.read_bytes()[:120] + b"\x00\xff[[")
    with pytest.raises(CalibrationError, match="not valid TOML"):
        load_calibration(unit_file)


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="does not exist"):
        load_calibration(tmp_path / "nothing.toml")


def test_non_finite_value_is_never_written(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="finite"):
        save_camera_file(tmp_path / "c.toml", _calibration().camera, math.inf, {}, {})


@pytest.mark.parametrize(("key", "given", "written", "bad"), [
    ("return_dn_m2", {"return_dn_m2": 641.25, "return_exposure_us": 800.0},
     "return_dn_m2 = 641.25", "return_dn_m2 = -3.0"),
    ("stripe_sigma_px", {"stripe_sigma_px": 0.66}, "stripe_sigma_px = 0.66",
     "stripe_sigma_px = -1.0"),
])
def test_optional_laser_values_round_trip(tmp_path: Path, key: str, given: dict[str, float],
                                          written: str, bad: str) -> None:
    """The radiometric calibration (return_dn_m2 and its exposure) and the stripes' width
    (stripe_sigma_px) are written when measured and read back; a file without them loads
    as not measured (0), and a negative value is a clear error naming the key."""
    calibration = _calibration()
    measured = Calibration(calibration.camera, LaserCalibration(
        0.075, (1.45, 1.52), 1e-4, (2e-4, 3e-4), **given))
    path = save_calibration(tmp_path / "unit.calib.toml", measured, {})
    assert written in path.read_text()
    assert load_calibration(path) == measured
    bare = save_calibration(tmp_path / "bare.calib.toml", calibration, {})
    assert key not in bare.read_text()
    assert getattr(load_calibration(bare).laser, key) == 0.0
    with pytest.raises(CalibrationError, match=key):
        load_calibration(_edit(path, written, bad))
