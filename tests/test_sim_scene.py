"""Scene files: shipped scenes load, every bad key or value is a ConfigError naming it."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest

from atris_node.errors import ConfigError
from atris_node.sim.scene import load_scene, parse_scene, resolve_scene, shipped_scenes

REQUIRED_SCENES = ("indoor_lab", "jammer_line", "window_sun", "two_units_nonorthogonal",
                   "two_units_orthogonal", "outdoor_medium_sun", "outdoor_strong_sun",
                   "parking_pedestrian", "flicker_100hz", "fleet")

MINIMAL: dict[str, Any] = {
    "camera": {"width_px": 64, "height_px": 40, "focal_px": 38.0, "rate_hz": 240.0,
               "exposure_us": 1000.0},
    "projector": {"baseline_m": 0.075, "alpha_deg": [80.0, 90.0], "power_w": 0.05},
}


def with_value(table: str, key: str, value: Any) -> dict[str, Any]:
    data = copy.deepcopy(MINIMAL)
    data.setdefault(table, {})[key] = value
    return data


def test_smoke_minimal_scene_has_defaults() -> None:
    scene = parse_scene(MINIMAL)
    assert scene.camera.cx_px == 31.5 and scene.camera.cy_px == 19.5
    assert scene.camera.gain_dn_per_e == pytest.approx(1023 / 10000.0)
    assert scene.noise and scene.shapes[0].name == "ground"
    assert not scene.shapes[0].obstacle


@pytest.mark.parametrize("name", REQUIRED_SCENES)
def test_feature_shipped_scene_loads(name: str) -> None:
    scene = load_scene(name)
    assert (scene.camera.width_px, scene.camera.height_px) == (640, 400)
    # the fleet demo runs three units in real time on two cores: a 30 Hz sub-frame clock
    low = 30.0 if name == "fleet" else 240.0
    assert low <= scene.camera.rate_hz <= 480.0
    assert scene.description


def test_feature_lines_numbered_top_of_image_first() -> None:
    scene = parse_scene(with_value("projector", "alpha_deg", [80.0, 95.0, 88.0]))
    singular = [scene.camera.focal_px / math.tan(a) for a in scene.projector.alpha_rad]
    assert singular == sorted(singular)
    assert scene.projector.alpha_rad[0] == pytest.approx(math.radians(95.0))


def test_feature_scene_by_path_and_by_name(tmp_path: Path) -> None:
    path = resolve_scene("indoor_lab")
    assert path.name == "indoor_lab.toml" and path.parent.name == "scenes"
    copy_path = tmp_path / "mine.toml"
    copy_path.write_text(path.read_text())
    assert load_scene(copy_path).name == "mine"
    assert load_scene(str(copy_path)).camera == load_scene("indoor_lab").camera
    assert set(REQUIRED_SCENES) <= set(shipped_scenes())


def test_exception_negative_exposure_names_key() -> None:
    with pytest.raises(ConfigError, match=r"^scene camera\.exposure_us: must be > 0, got -3"):
        parse_scene(with_value("camera", "exposure_us", -3))


@pytest.mark.parametrize(("table", "key", "value", "match"), [
    ("camera", "exposure_usec", 10.0, r"camera\.exposure_usec: unknown key"),
    ("camera", "bits", 20, r"camera\.bits: must be in \[8, 16\]"),
    ("camera", "bits", 10.5, r"camera\.bits: must be an integer"),
    ("camera", "exposure_us", 5000.0, r"camera\.exposure_us: must fit the sub-frame period"),
    ("camera", "distortion", [0.1, "x"], r"camera\.distortion\[1\]: must be a number"),
    ("projector", "alpha_deg", [80.0, 190.0], r"projector\.alpha_deg: must be in"),
    ("projector", "baseline_m", 0.0, r"projector\.baseline_m: must be > 0"),
    ("projector", "filter_factor", 1.5, r"projector\.filter_factor: must be in \[0.0, 1.0\]"),
    ("ambient", "lamp", {"lux": 10.0, "flicker_depth": 2.0}, r"ambient\.lamp\.flicker_depth"),
    ("ambient", "sun", {"lux": -1.0}, r"ambient\.sun\.lux: must be >= 0"),
    ("noise", "enabled", "yes", r"noise\.enabled: must be a bool"),
])
def test_exception_bad_values_name_key(table: str, key: str, value: Any, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_scene(with_value(table, key, value))


def test_exception_bad_shapes_and_interferers_name_key() -> None:
    data = copy.deepcopy(MINIMAL)
    data["sphere"] = [{"center_m": [1.0, 0.0, 0.5], "radius_m": 0.2},
                      {"center_m": [1.0, 0.0], "radius_m": 0.2}]
    with pytest.raises(ConfigError, match=r"sphere\[1\]\.center_m: must be 3 numbers"):
        parse_scene(data)
    data = copy.deepcopy(MINIMAL)
    data["interferer"] = [{"pose": {"x_m": 1.0}, "alpha_deg": [90.0], "power_w": 0.1,
                           "strobe": "code", "code_length": 8, "code_row": 9}]
    with pytest.raises(ConfigError, match=r"interferer\[0\]\.code_row: must be in 1\.\.8"):
        parse_scene(data)
    data["interferer"][0]["pose"] = {"x_m": 1.0, "heading": 3.0}
    with pytest.raises(ConfigError, match=r"interferer\[0\]\.pose\.heading: unknown key"):
        parse_scene(data)


def test_exception_unknown_table_and_missing_key() -> None:
    with pytest.raises(ConfigError, match=r"scene lights: unknown table"):
        parse_scene({**MINIMAL, "lights": {}})
    data = copy.deepcopy(MINIMAL)
    del data["camera"]["focal_px"]
    with pytest.raises(ConfigError, match=r"camera\.focal_px: required key is missing"):
        parse_scene(data)


def test_exception_unknown_scene_name_lists_shipped() -> None:
    with pytest.raises(ConfigError, match=r"no scene named 'atlantis'; shipped: .*indoor_lab"):
        load_scene("atlantis")
    with pytest.raises(ConfigError, match="does not exist"):
        load_scene("nowhere/atlantis.toml")
