"""``atris calib verify --backend sim``: a wall at a known distance captured live, strobed
and demodulated, measured with a calibration file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from atris_node.calibration import Calibration, LaserCalibration
from atris_node.cli import main
from atris_node.sim import Simulator, load_scene
from calib.files import save_calibration

WALL_SCENE = """
[scene]
description = "calibration wall 1.2 m ahead"
[camera]
width_px = 320
height_px = 200
focal_px = 190.0
rate_hz = 240.0
exposure_us = 1000.0
[projector]
baseline_m = 0.075
alpha_deg = [86.0, 90.0, 94.0]
power_w = 0.08
[ground]
enabled = false
[[plane]]
name = "wall"
point_m = [1.2, 0.0, 0.0]
normal = [-1.0, 0.0, 0.0]
albedo = 0.7
"""


@pytest.fixture
def wall(tmp_path: Path) -> tuple[Path, Calibration]:
    scene = tmp_path / "wall.toml"
    scene.write_text(WALL_SCENE)
    return scene, Simulator(load_scene(scene)).calibration()


def _verify(capsys: pytest.CaptureFixture[str], calibration: Path, scene: Path,
            *extra: str) -> tuple[int, dict]:
    code = main(["calib", "verify", "--calibration", str(calibration), "--backend", "sim",
                 "--driver-option", f"scene={scene}", "--driver-option", "seed=3",
                 "--distance", "1.2", "--json", *extra])
    out, _ = capsys.readouterr()
    return code, json.loads(out)["targets"][0]


def test_live_target_with_the_true_calibration_passes(capsys: pytest.CaptureFixture[str],
                                                      tmp_path: Path, wall: tuple) -> None:
    scene, truth = wall
    path = save_calibration(tmp_path / "unit.calib.toml", truth, {})
    code, report = _verify(capsys, path, scene)
    assert code == 0 and report["passed"]
    assert abs(report["bias_m"]) < 0.25 * report["expected_sigma_z_m"]
    assert report["samples"] > 500


def test_live_target_with_a_wrong_baseline_fails(capsys: pytest.CaptureFixture[str],
                                                 tmp_path: Path, wall: tuple) -> None:
    scene, truth = wall
    wrong = Calibration(truth.camera, LaserCalibration(0.08, truth.laser.alpha_rad))
    path = save_calibration(tmp_path / "wrong.calib.toml", wrong, {})
    code, report = _verify(capsys, path, scene)
    assert code == 1 and not report["passed"]
    assert report["bias_m"] == pytest.approx(1.2 * 0.005 / 0.075, rel=0.2)  # z·Δb/b


def test_calibration_for_another_resolution_stops_the_live_check(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, wall: tuple) -> None:
    scene, truth = wall
    camera = truth.camera
    bigger = Calibration(type(camera)(640, 400, camera.focal_px, camera.cx_px, camera.cy_px),
                         truth.laser)
    path = save_calibration(tmp_path / "big.calib.toml", bigger, {})
    code = main(["calib", "verify", "--calibration", str(path), "--backend", "sim",
                 "--driver-option", f"scene={scene}", "--distance", "1.2"])
    assert code == 1
    assert "640x400 images but the camera delivers 320x200" in capsys.readouterr().err


def test_radiometry_from_a_live_target_matches_the_renderer(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, wall: tuple) -> None:
    """``atris calib radiometry`` on the simulated wall (albedo 0.7 at 1.2 m, noise on):
    the measured return_dn_m2 is the simulator's own within 10 %, the stripes' width its
    own within 10 %, and the written file keeps the laser planes and holds both."""
    from dataclasses import replace

    from calib.files import load_calibration

    scene, truth = wall
    bare = replace(truth, laser=replace(truth.laser, return_dn_m2=0.0, return_exposure_us=0.0,
                                        stripe_sigma_px=0.0))
    path = save_calibration(tmp_path / "unit.calib.toml", bare, {"rms_px": 0.2})
    out = tmp_path / "with_return.calib.toml"
    code = main(["calib", "radiometry", "--calibration", str(path), "--backend", "sim",
                 "--driver-option", f"scene={scene}", "--driver-option", "seed=3",
                 "--distance", "1.2", "--albedo", "0.7", "--exposure-us", "1000",
                 "--out", str(out), "--json"])
    report = json.loads(capsys.readouterr()[0])
    assert code == 0 and report["samples"] > 100
    assert report["return_dn_m2"] == pytest.approx(truth.laser.return_dn_m2, rel=0.1)
    written = load_calibration(out)
    assert written.laser.alpha_rad == truth.laser.alpha_rad
    assert written.laser.return_dn_m2 == pytest.approx(report["return_dn_m2"])
    assert written.laser.return_exposure_us == 1000.0
    assert truth.laser.stripe_sigma_px > 0.0
    assert report["stripe_sigma_px"] == pytest.approx(truth.laser.stripe_sigma_px, rel=0.1)
    assert written.laser.stripe_sigma_px == pytest.approx(report["stripe_sigma_px"])


def test_radiometry_needs_a_target(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                   wall: tuple) -> None:
    """Neither --map nor --backend, or a bad albedo: a clear error, no file written."""
    _, truth = wall
    path = save_calibration(tmp_path / "unit.calib.toml", truth, {})
    out = tmp_path / "out.calib.toml"
    base = ["calib", "radiometry", "--calibration", str(path), "--distance", "1.2",
            "--exposure-us", "1000", "--out", str(out)]
    assert main([*base, "--albedo", "0.7"]) != 0
    assert "--map FILE or --backend NAME" in capsys.readouterr()[1]
    assert not out.exists()
