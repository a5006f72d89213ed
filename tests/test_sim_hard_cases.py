"""The scene format's hard cases (docs/scenes.md): several lamps, a per-scene z_max, ramps,
retro-reflective and glossy finishes, accelerating shapes and a calibration error handed to
the pipeline. Each loads, is checked by the loader, and renders or scores as stated."""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pytest

from atris_node.errors import ConfigError
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim import Simulator, layers, load_scene
from atris_node.sim.optics import finish_factor
from atris_node.sim.raycast import Ramp
from atris_node.sim.scene import Lamp, parse_scene
from atris_node.sim.strobe import flicker_factor, lamps_factor

LAYOUT = SectorLayout(8, math.radians(70.0))
SMALL: dict[str, Any] = {
    "camera": {"width_px": 64, "height_px": 48, "focal_px": 40.0, "rate_hz": 240.0,
               "exposure_us": 1000.0},
    "projector": {"baseline_m": 0.075, "alpha_deg": [86.0, 92.0, 89.0], "power_w": 0.1},
    "plane": [{"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "albedo": 0.5}],
    "ambient": {"lamp": {"lux": 100.0}},
    "noise": {"enabled": False},
}


def small(**tables: Any) -> dict[str, Any]:
    data = copy.deepcopy(SMALL)
    data.update(copy.deepcopy(tables))
    return data


# ------------------------------------------------------------------ lamps
def test_feature_several_lamps_add_and_flicker_by_their_lux() -> None:
    lamps = [{"lux": 300.0, "flicker_hz": 100.0, "flicker_depth": 0.6},
             {"lux": 100.0, "flicker_hz": 120.0, "flicker_depth": 1.0}]
    scene = parse_scene(small(ambient={"lamp": {"lux": 50.0}, "lamps": lamps}))
    assert [lamp.lux for lamp in scene.ambient.all_lamps] == [50.0, 300.0, 100.0]
    assert scene.ambient.lamp_lux == 450.0
    expected = (50.0 + 300.0 * flicker_factor(100.0, 0.6, 0.001, 0.002)
                + 100.0 * flicker_factor(120.0, 1.0, 0.001, 0.002)) / 450.0
    assert lamps_factor(scene.ambient.all_lamps, 0.001, 0.002) == pytest.approx(expected)
    assert Simulator(scene).flickers


def test_feature_lamps_render_as_one_lamp_of_their_summed_lux() -> None:
    """Steady lamps given as a list light the scene exactly as one lamp of their sum."""
    one = Simulator(parse_scene(small(ambient={"lamp": {"lux": 300.0}})))
    two = Simulator(parse_scene(small(ambient={"lamps": [{"lux": 100.0}, {"lux": 200.0}]})))
    assert np.array_equal(one.render(0, chip=0).pixels, two.render(0, chip=0).pixels)
    assert lamps_factor((Lamp(0.0),), 0.0, 1.0) == 1.0


@pytest.mark.parametrize(("lamps", "match"), [
    ({"lux": 1.0}, r"ambient\.lamps: must be a list"),
    ([{"lux": 1.0}, {"lux": 2.0, "flicker_depth": 1.5}],
     r"ambient\.lamps\[1\]\.flicker_depth: must be in \[0\.0, 1\.0\]"),
    ([{"flicker_hz": 100.0}], r"ambient\.lamps\[0\]\.lux: required key is missing"),
])
def test_exception_bad_lamps_name_key(lamps: Any, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_scene(small(ambient={"lamps": lamps}))


# ------------------------------------------------------------------ z_max
def test_feature_scene_z_max_reaches_the_pipeline_and_the_scorer() -> None:
    from atris_node.bench.safety import scene_settings

    scene = load_scene("short_range_zmax_3m")
    assert scene.z_max_m == 3.0 and scene_settings(scene) == {"z_max_m": 3.0}
    assert parse_scene(small()).z_max_m is None and scene_settings(parse_scene(small())) == {}


def test_exception_bad_z_max_names_key() -> None:
    with pytest.raises(ConfigError, match=r"scene\.z_max_m: must be in \[0\.5, 200\.0\]"):
        parse_scene(small(scene={"z_max_m": 0.2}))


# ------------------------------------------------------------------ ramps
def test_feature_ramp_is_hit_where_its_plane_rises_and_missed_past_its_edges() -> None:
    ramp = Ramp(albedo=0.5, start_m=(2.0, 0.0, 0.0), length_m=2.0, width_m=1.0,
                slope_rad=math.radians(30.0))
    origin = np.array([0.0, 0.0, 0.5])
    dirs = np.array([[1.0, 0.0, 0.0], [1.0, 0.6, 0.0], [1.0, 0.0, 0.3]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t, normals = ramp.intersect(origin, dirs)
    # level ray at 0.5 m meets the surface where (x - 2) tan 30 = 0.5
    assert t[0] == pytest.approx(2.0 + 0.5 / math.tan(math.radians(30.0)))
    assert normals[0] @ dirs[0] < 0 and normals[0][2] > 0
    assert np.isinf(t[1]) and np.isinf(t[2])  # past its side, over its top edge
    lo, hi = ramp.bounds(0.0)  # type: ignore[misc]
    assert hi[2] == pytest.approx(1.0) and lo[0] == pytest.approx(2.0)


def test_feature_ramp_truth_starts_ten_centimetres_up() -> None:
    """In ramp_and_kerb line 82° meets the 10° ramp 14.8 cm up at 3.04 m (its sectors'
    truth); lines 76° and 79° meet it lower, 1.25 and 7 cm up, which is ground."""
    truth = Simulator(load_scene("ramp_and_kerb")).truth(0, LAYOUT).sector_distance_m
    assert truth[4] == pytest.approx(3.04, abs=0.02)
    assert min(t for t in truth[4:] if t is not None) > 3.0
    assert truth[2] == pytest.approx(1.82, abs=0.02)  # the kerb face, 12.7 cm up


def _kerb_scene(height_m: float, front_m: float = 1.8) -> Any:
    """ramp_and_kerb with its kerb ``height_m`` tall, its face at ``front_m``."""
    from dataclasses import replace

    scene = load_scene("ramp_and_kerb")
    shapes = tuple(replace(s, center_m=(front_m + 0.5 * s.size_m[0], s.center_m[1],
                                        0.5 * height_m),
                           size_m=(s.size_m[0], s.size_m[1], height_m))
                   if s.name.startswith("kerb") else s for s in scene.shapes)
    return replace(scene, shapes=shapes)


def test_feature_shape_below_the_clearance_is_no_obstacle() -> None:
    """A 9 cm kerb is cleared by the vehicle (clearance 10 cm): not sector truth; the
    same kerb 15 cm tall is, at its face. Checked to fail with CLEARANCE_M = -1 (every
    shape an obstacle, the truth before): the 9 cm kerb was truth at 1.82 m."""
    low = Simulator(_kerb_scene(0.09)).truth(0, LAYOUT).sector_distance_m
    tall = Simulator(_kerb_scene(0.15)).truth(0, LAYOUT).sector_distance_m
    assert tall[2] == pytest.approx(1.82, abs=0.02)
    assert low[2] is None or low[2] > 2.0


def test_exception_bad_ramp_names_key() -> None:
    ramp = {"start_m": [2.0, 0.0, 0.0], "length_m": 1.0, "width_m": 1.0, "slope_deg": 95.0}
    with pytest.raises(ConfigError, match=r"ramp\[0\]\.slope_deg: must be in \[0\.1, 90\.0\]"):
        parse_scene(small(ramp=[ramp]))


# ------------------------------------------------------------------ finishes
def test_feature_finish_factor_peaks_as_stated() -> None:
    lobe, gloss = math.radians(1.0), math.radians(2.0)
    finish = {"retro_gain": np.array([300.0, 300.0, 0.0]), "retro_lobe_rad": np.full(3, lobe),
              "mirror": np.array([0.0, 0.0, 0.8]), "gloss_rad": np.full(3, gloss)}
    normal = np.array([[-1.0, 0.0, 0.0]] * 3)
    incoming = np.array([[1.0, 0.0, 0.0]] * 3)
    eye = np.array([[-1.0, 0.0, 0.0], [-math.cos(lobe), math.sin(lobe), 0.0], [-1.0, 0.0, 0.0]])
    factor = finish_factor(finish, normal, incoming, eye)
    assert factor[0] == pytest.approx(300.0 / math.pi)
    assert factor[1] == pytest.approx(300.0 / math.pi * math.exp(-0.5))
    assert factor[2] == pytest.approx(0.8 / (2.0 * math.pi * gloss**2))


def _laser(plane: dict[str, Any], x_m: float = 2.0) -> np.ndarray:
    """Own-laser electron rates (H, W) of a scene with one wall at ``x_m``."""
    scene = parse_scene(small(plane=[{"point_m": [x_m, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0],
                                      **plane}], ambient={}))
    sim = Simulator(scene)
    dirs = layers.camera_rays(scene.camera, sim.true_mounting)[1]
    surface = layers.see(scene.shapes, sim.true_mounting.translation, dirs)
    return layers.sheet_rates(scene.camera, sim.true_mounting, scene.projector, surface,
                              scene.shapes).astype(float)


def test_feature_retro_wall_returns_gain_times_exp_of_its_angle() -> None:
    """A retro-reflective wall at 2 m, b = 7.5 cm: β ≈ 2.1° at the lines, so a gain of 4
    with a 2° lobe returns 1 + 4 exp(−β²/2σ²)/albedo times a plain wall of that albedo."""
    plain = _laser({"albedo": 0.2})
    retro = _laser({"albedo": 0.2, "retro_gain": 4.0, "retro_lobe_deg": 2.0})
    beta = 0.075 / 2.0
    ratio = 1.0 + 4.0 * math.exp(-0.5 * (beta / math.radians(2.0)) ** 2) / 0.2
    lit = plain > 0.2 * plain.max()
    assert np.median(retro[lit] / plain[lit]) == pytest.approx(ratio, rel=0.08)


def test_feature_glossy_wall_turned_away_returns_only_its_diffuse_part() -> None:
    turned = {"normal": [-1.0, 0.5, 0.0], "albedo": 0.8}
    plain = _laser(turned)
    glossy = _laser({**turned, "specular": 0.9, "gloss_deg": 2.0})
    lit = plain > 0.2 * plain.max()
    assert np.median(glossy[lit] / plain[lit]) == pytest.approx(0.1, rel=0.1)


@pytest.mark.parametrize(("key", "value", "match"), [
    ("specular", 1.5, r"plane\[0\]\.specular: must be in \[0\.0, 1\.0\]"),
    ("retro_gain", -1.0, r"plane\[0\]\.retro_gain: must be in"),
    ("gloss_deg", 0.0, r"plane\[0\]\.gloss_deg: must be in \[0\.1, 30\.0\]"),
])
def test_exception_bad_finish_names_key(key: str, value: float, match: str) -> None:
    plane = {"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], key: value}
    with pytest.raises(ConfigError, match=match):
        parse_scene(small(plane=[plane]))


# ------------------------------------------------------------------ acceleration
def test_feature_accelerating_shape_truth_at_the_sub_frame_mid_time() -> None:
    """accelerating_approach: the rear face at 6 m − 10 m/s² · t², t the exposure
    mid-time of the sub-frame, in both the truth and the rendered depth."""
    sim = Simulator(load_scene("accelerating_approach"))
    for sequence in (0, 48, 95):
        t0, t1 = sim.window(sequence)
        t = 0.5 * (t0 + t1)
        truth = sim.truth(sequence, LAYOUT)
        assert truth.time_s == pytest.approx(t)
        assert min(d for d in truth.sector_distance_m if d is not None) == pytest.approx(
            6.0 - 10.0 * t * t, abs=0.01)
    assert sim.moving_shapes and sim.moving_shapes[0].offset(0.4)[0] == pytest.approx(-1.6)


def test_exception_bad_acceleration_names_key() -> None:
    plane = {"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0],
             "acceleration_mps2": [1.0, 2.0]}
    with pytest.raises(ConfigError, match=r"plane\[0\]\.acceleration_mps2: must be 3 numbers"):
        parse_scene(small(plane=[plane]))


# ------------------------------------------------------------------ miscalibration
def test_feature_miscalibration_reaches_the_pipeline_not_the_renderer() -> None:
    wrong = {"baseline_scale": 1.01, "alpha_offset_deg": [0.1, -0.1, 0.05],
             "focal_offset_px": 2.0, "cx_offset_px": -1.0, "cy_offset_px": 0.5,
             "mounting_z_offset_m": 0.02, "mounting_pitch_offset_deg": -1.0}
    true_sim = Simulator(parse_scene(small()))
    sim = Simulator(parse_scene(small(miscalibration=wrong)))
    cal, truth = sim.calibration(), sim.true_calibration()
    assert truth == true_sim.calibration()
    assert cal.laser.baseline_m == pytest.approx(0.075 * 1.01)
    # file order 86, 92, 89 is calibration order 92, 89, 86 (top of the image first)
    offsets = np.degrees(np.subtract(cal.laser.alpha_rad, truth.laser.alpha_rad))
    assert offsets == pytest.approx([-0.1, 0.05, 0.1])
    assert (cal.camera.focal_px, cal.camera.cx_px, cal.camera.cy_px) == (
        truth.camera.focal_px + 2.0, truth.camera.cx_px - 1.0, truth.camera.cy_px + 0.5)
    assert sim.mounting.z_m == pytest.approx(0.52)
    assert sim.mounting.pitch_rad == pytest.approx(math.radians(-1.0))
    assert sim.true_mounting == true_sim.mounting
    assert np.array_equal(sim.render(0, chip=1).pixels, true_sim.render(0, chip=1).pixels)
    assert sim.truth(0, LAYOUT).sector_distance_m == true_sim.truth(0, LAYOUT).sector_distance_m


def test_feature_the_sim_driver_hands_the_node_the_erred_calibration() -> None:
    from drivers.sim import open_backend

    scene = parse_scene(small(miscalibration={"baseline_scale": 1.01}))
    camera, projector = open_backend(scene)
    with camera, projector:
        assert camera.factory_calibration() == camera.simulator.calibration()
        assert camera.factory_calibration().laser.baseline_m == pytest.approx(0.07575)
        assert camera.mounting == camera.simulator.mounting


@pytest.mark.parametrize(("wrong", "match"), [
    ({"alpha_offset_deg": [0.1, 0.1]}, r"alpha_offset_deg: must be one number or one per line"),
    ({"alpha_offset_deg": 2.0}, r"alpha_offset_deg: must be in \[-1\.0, 1\.0\]"),
    ({"baseline_scale": 0.1}, r"miscalibration\.baseline_scale: must be in \[0\.5, 2\.0\]"),
    ({"baseline_offset_m": -0.08}, r"baseline_offset_m: must leave the baseline > 0"),
    ({"roll_deg": 1.0}, r"miscalibration\.roll_deg: unknown key; accepted: .*alpha"),
])
def test_exception_bad_miscalibration_names_key(wrong: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_scene(small(miscalibration=wrong))


def test_exception_alpha_offsets_that_swap_lines_are_refused() -> None:
    projector = {"baseline_m": 0.075, "alpha_deg": [88.0, 88.5], "power_w": 0.1}
    with pytest.raises(ConfigError, match=r"alpha_offset_deg: must keep .* their order"):
        parse_scene(small(projector=projector,
                          miscalibration={"alpha_offset_deg": [0.6, -0.6]}))


def test_feature_a_group_of_lines_keeps_its_own_calibration_errors() -> None:
    """bench safety --groups renders a subset of the lines; each keeps its own α error
    (lines are numbered top of the image first: 97, 94, ..., 76 deg here)."""
    from atris_node.bench.safety import _group

    scene = load_scene("calib_alpha_per_line")
    group = _group(scene, 1, 2)
    sim = Simulator(group)
    offsets = np.degrees(np.subtract(sim.calibration().laser.alpha_rad,
                                     sim.true_calibration().laser.alpha_rad))
    assert offsets == pytest.approx([0.05, 0.1, 0.05, 0.1])  # lines 94, 88, 82, 76 deg
    assert Simulator(_group(load_scene("indoor_lab"), 0, 2)).calibration().laser.alpha_rad
