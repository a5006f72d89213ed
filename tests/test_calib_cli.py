"""The whole calibration workflow through ``atris calib`` on a capture set of the
simulator's ``indoor_lab`` scene (640×400, f = 381 px, b = 75 mm, eight lines)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from atris_node.cli import main
from calib.files import load_calibration, load_camera_file

TRUE_ALPHA_DEG = np.array([97.0, 94.0, 91.0, 88.0, 85.0, 82.0, 79.0, 76.0])
SIZE = (640, 400)


def _atris(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def capture_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("captures")
    code = main(["calib", "simulate", "indoor_lab", "--out", str(root), "--seed", "3",
                 "--views", "8", "--poses", "4", "--distances", "0.6,1.0,1.7"])
    assert code == 0
    return root


@pytest.fixture(scope="module")
def camera_file(capture_set: Path) -> Path:
    out = capture_set / "out" / "camera.toml"
    assert main(["calib", "intrinsics", "--captures", str(capture_set), "--out", str(out)]) == 0
    return out


def test_simulate_writes_captures_and_truth(capture_set: Path) -> None:
    truth = load_calibration(capture_set / "truth.calib.toml", expected_size=SIZE)
    assert np.degrees(truth.laser.alpha_rad) == pytest.approx(TRUE_ALPHA_DEG)
    assert len(list((capture_set / "intrinsics").glob("*.png"))) == 8
    assert len(list((capture_set / "flat").glob("*.npy"))) == 3
    assert len(list((capture_set / "board_laser").glob("*.npy"))) == 4


def test_intrinsics_focal_length_within_half_a_percent(camera_file: Path) -> None:
    camera = load_camera_file(camera_file, expected_size=SIZE)
    assert camera.camera.focal_px == pytest.approx(381.0, rel=0.005)
    assert 0.0 < camera.sigma.focal_px < 1.0 and 0.0 < camera.sigma.cy_px < 1.0
    assert 0.0 < camera.rms_px < 0.3
    assert camera_file.with_name("camera.residuals.png").stat().st_size > 1000


@pytest.mark.parametrize("method", ["flat", "board"])
def test_laser_round_trip_with_noise_and_outliers(capsys: pytest.CaptureFixture[str],
                                                capture_set: Path, camera_file: Path,
                                                method: str) -> None:
    out = capture_set / "out" / f"unit_{method}.calib.toml"
    code, text, _ = _atris(capsys, "calib", "laser", "--method", method, "--camera",
                           str(camera_file), "--captures", str(capture_set), "--out", str(out),
                           "--json")
    assert code == 0
    result = json.loads(text)
    assert result["baseline_m"] == pytest.approx(0.075, rel=0.005)
    assert np.abs(np.array(result["alpha_deg"]) - TRUE_ALPHA_DEG).max() < 0.05
    assert result["inliers"] < 0.99 * result["samples"] or method == "board"  # the pole
    assert all(0.0 < s < 0.05 for s in result["alpha_sigma_deg"])
    saved = load_calibration(out, expected_size=SIZE)
    assert saved.laser.baseline_m == result["baseline_m"]
    assert Path(result["plot"]).stat().st_size > 1000


def test_verify_reports_the_error_beside_its_bound(capsys: pytest.CaptureFixture[str],
                                                   capture_set: Path, camera_file: Path) -> None:
    unit = capture_set / "out" / "unit_verify.calib.toml"
    assert main(["calib", "laser", "--camera", str(camera_file), "--captures",
                 str(capture_set), "--out", str(unit)]) == 0
    capsys.readouterr()
    code, text, _ = _atris(capsys, "calib", "verify", "--calibration", str(unit),
                           "--captures", str(capture_set), "--json")
    report = json.loads(text)["targets"][0]
    assert code == 0 and report["passed"]
    assert report["distance_m"] == 1.75
    expected = 1.75**2 * 0.1 / (381.0 * 0.075)  # z²·σ_u/(f·b)
    assert report["expected_sigma_z_m"] == pytest.approx(expected, rel=0.01)
    assert abs(report["bias_m"]) < report["expected_sigma_z_m"]


def test_verify_fails_with_a_wrong_baseline(capsys: pytest.CaptureFixture[str],
                                            capture_set: Path) -> None:
    wrong = capture_set / "out" / "wrong.calib.toml"
    text = (capture_set / "truth.calib.toml").read_text()
    wrong.write_text(text.replace("baseline_m = 0.075", "baseline_m = 0.08"))
    code, out, _ = _atris(capsys, "calib", "verify", "--calibration", str(wrong),
                          "--captures", str(capture_set), "--json")
    assert code == 1
    assert not json.loads(out)["targets"][0]["passed"]


def test_corrupt_calibration_is_an_error_at_start(capsys: pytest.CaptureFixture[str],
                                                  capture_set: Path) -> None:
    corrupt = capture_set / "out" / "corrupt.calib.toml"
    corrupt.write_text('format = "atris-calibration"\nversion = 1\nkind = "unit"\n[camera\n')
    code, _, err = _atris(capsys, "calib", "verify", "--calibration", str(corrupt),
                          "--captures", str(capture_set))
    assert code == 1 and "error:" in err and "not valid TOML" in err


def test_camera_file_for_another_resolution_is_refused(capsys: pytest.CaptureFixture[str],
                                                       capture_set: Path,
                                                       camera_file: Path) -> None:
    small = capture_set / "out" / "small_camera.toml"
    text = camera_file.read_text().replace("width_px = 640", "width_px = 320")
    text = re.sub(r"(?m)^cx_px = .*$", "cx_px = 160.0", text)
    text = re.sub(r"(?m)^cy_px = .*$", "cy_px = 100.0", text)
    small.write_text(text.replace("height_px = 400", "height_px = 200"))
    code, _, err = _atris(capsys, "calib", "laser", "--camera", str(small), "--captures",
                          str(capture_set), "--out", str(capture_set / "out" / "x.toml"))
    assert code == 1 and "320x200 images" in err


def test_a_single_distance_is_refused(capsys: pytest.CaptureFixture[str], capture_set: Path,
                                      camera_file: Path) -> None:
    flat = str(capture_set / "flat" / "z_1.000m.npy")
    code, _, err = _atris(capsys, "calib", "laser", "--camera", str(camera_file), "--lines",
                          "8", "--flat", f"0.9={flat}", "--flat", f"0.9={flat}", "--out",
                          str(capture_set / "out" / "y.toml"))
    assert code == 1 and "at least 3 different distances" in err


def test_board_command_writes_png_and_pdf(capsys: pytest.CaptureFixture[str],
                                          tmp_path: Path) -> None:
    code, out, _ = _atris(capsys, "calib", "board", "--out", str(tmp_path / "b.png"),
                          "--dpi", "100")
    assert code == 0 and "400 x 280 mm" in out
    assert (tmp_path / "b.pdf").read_bytes().startswith(b"%PDF")
