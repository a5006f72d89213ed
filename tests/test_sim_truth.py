"""Ground truth: depth, sub-pixel line rows against Eq. 1, sector distances, calibration."""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pytest

from atris_node.pipeline.geometry import line_row_at_range
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim import Simulator
from atris_node.sim.scene import parse_scene

LAYOUT = SectorLayout(8, math.radians(70.0))
BASE: dict[str, Any] = {
    "camera": {"width_px": 128, "height_px": 80, "focal_px": 76.0, "rate_hz": 240.0,
               "exposure_us": 1000.0},
    "projector": {"baseline_m": 0.075, "alpha_deg": [84.0, 88.0, 92.0], "power_w": 0.05,
                  "fan_deg": 120.0},
    "mounting": {"z_m": 0.5},
    "ambient": {"lamp": {"lux": 300.0}},
    "noise": {"enabled": False},
}


def make(**tables: Any) -> Simulator:
    data = copy.deepcopy(BASE)
    data.update(tables)
    return Simulator(parse_scene(data))


def test_feature_wall_rows_match_eq1_and_depth() -> None:
    sim = make(plane=[{"point_m": [2.5, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0]}])
    truth = sim.truth(0, LAYOUT)
    cal = sim.calibration()
    assert truth.depth_m[40, 64] == pytest.approx(2.5)
    assert truth.line_visible.all()
    for k in range(3):
        expected = cal.camera.cy_px + line_row_at_range(k, 2.5, cal.camera, cal.laser)
        assert np.abs(truth.line_rows[k] - expected).max() < 1e-3
    assert truth.line_points_m[1, :, 2] == pytest.approx(2.5, rel=1e-4)
    assert truth.line_obstacle.all()


def test_feature_sector_distance_is_horizontal_range_of_nearest_lit_obstacle() -> None:
    sim = make(plane=[{"point_m": [3.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0]}],
               box=[{"center_m": [1.5, 0.0, 0.5], "size_m": [0.4, 0.3, 1.0]}])
    truth = sim.truth(0, LAYOUT)
    ahead = truth.sector_distance_m[3:5]
    assert ahead == pytest.approx((1.3, 1.3), abs=1e-4)
    assert truth.sector_distance_m[0] == pytest.approx(3.0 / math.cos(math.radians(26.25)),
                                                       rel=0.02)


def test_feature_ground_is_not_an_obstacle() -> None:
    truth = make(ambient={"sky_lux": 1000.0}).truth(0, LAYOUT)
    assert truth.line_visible.any()  # lines 84° and 88° reach the ground
    assert not truth.line_obstacle.any()
    assert truth.sector_distance_m == (None,) * 8


def test_feature_nearest_surface_wins_and_shadows_hide() -> None:
    # a thin rod at projector height intercepts line 1 in front of the wall
    sim = make(plane=[{"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0]}],
               box=[{"center_m": [0.3, -0.2, 0.575], "size_m": [0.05, 0.05, 0.03]}])
    truth = sim.truth(0, LAYOUT)
    z = truth.line_points_m[1, :, 2]
    on_rod = truth.line_visible[1] & (z < 1.0)
    assert 0 < on_rod.sum() < 30 and np.all((z[on_rod] > 0.274) & (z[on_rod] < 0.326))
    nearest = min(d for d in truth.sector_distance_m if d is not None)
    assert nearest == pytest.approx(math.hypot(0.275, 0.175), abs=0.03)
    from atris_node.sim.truth import _reached

    behind = sim.mounting.vehicle_to_camera(np.array([[2.0, -0.2 * 2.0 / 0.3, 0.575]]))
    assert not _reached(sim.scene, sim.mounting, behind, 0.0).any()
    # nor when the rendered pixels' points are the same shadowed point
    world = sim.mounting.camera_to_vehicle(behind)
    assert not _reached(sim.scene, sim.mounting, behind, 0.0, (world, world)).any()


def test_feature_rendered_stripe_is_centred_on_the_true_row() -> None:
    sim = make(plane=[{"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.2, 0.0]}])
    truth = sim.truth(0, LAYOUT)
    lit = sim.render(0, 1).pixels.astype(np.float64) - sim.render(1, 0).pixels
    assert lit[np.rint(truth.line_rows[1]).astype(int), np.arange(128)].min() >= 3
    diff = sim._static_layer().laser.astype(np.float64)  # the same stripe before rounding
    for col in (20, 64, 100):
        row = truth.line_rows[1, col]
        peak = round(row)
        a, b, c = np.log(diff[peak - 1:peak + 2, col])
        centre = peak + 0.5 * (a - c) / (a - 2.0 * b + c)  # 3-point Gaussian
        assert centre == pytest.approx(row, abs=0.1)


def test_feature_moving_obstacle_truth_follows_time() -> None:
    sim = make(plane=[{"point_m": [4.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0]}],
               cylinder=[{"center_m": [2.0, 1.5, 0.0], "radius_m": 0.2, "height_m": 1.8,
                          "velocity_mps": [0.0, -1.5, 0.0]}])
    early, late = sim.truth(0, LAYOUT), sim.truth(480, LAYOUT)
    assert early.sector_distance_m[7] is not None and early.sector_distance_m[7] < 3.0
    assert late.time_s == pytest.approx(2.0 + 0.0005)
    assert late.sector_distance_m[0] is not None and late.sector_distance_m[0] < 3.0
    assert late.sector_distance_m[7] != early.sector_distance_m[7]


def test_feature_calibration_is_the_scene_truth() -> None:
    sim = make(camera={**BASE["camera"], "distortion": [-0.1, 0.02]})
    cal = sim.calibration()
    assert cal.camera.distortion == (-0.1, 0.02)
    assert cal.laser.baseline_m == 0.075
    assert cal.laser.alpha_rad == pytest.approx(tuple(map(math.radians, (92.0, 88.0, 84.0))))


def test_feature_lens_distortion_bends_true_rows() -> None:
    flat = make(plane=[{"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0]}])
    bent = make(plane=[{"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0]}],
                camera={**BASE["camera"], "distortion": [-0.2]})
    rows_flat, rows_bent = flat.truth(0, LAYOUT).line_rows[2], bent.truth(0, LAYOUT).line_rows[2]
    assert np.ptp(rows_flat) < 1e-3
    assert np.ptp(rows_bent) > 0.5  # barrel distortion bends the off-centre line


def test_feature_a_sheet_grazing_a_kerb_top_reaches_it() -> None:
    """A sheet 4.15 deg down from a projector 0.41 m up meets a 21 cm kerb's top at 4 deg
    incidence, 2.8 m out: the stripe is rendered on the top and the pipeline reads it
    (2.90 m in a random scene), so the truth must count the kerb. Its Eq. 1 points lie
    ~1 mm under the top, and their rays to the projector ran inside the kerb for 14 mm,
    past the shadow test's clearance: the truth had no obstacle at all and scored the
    correct reading as a near phantom. REMOVAL CHECK: with ``_reached`` testing the Eq. 1
    point alone (the fallback to the rendered pixels' shadow test removed), every sector
    was None here (no line point on the kerb)."""
    sim = Simulator(parse_scene({
        "camera": {"width_px": 640, "height_px": 400, "focal_px": 385.91, "rate_hz": 240.0,
                   "exposure_us": 1000.0},
        "projector": {"baseline_m": 0.1212, "alpha_deg": [85.852], "power_w": 0.08,
                      "fan_deg": 70.0},
        "mounting": {"z_m": 0.285},
        "ambient": {"lamp": {"lux": 300.0}},
        "noise": {"enabled": False},
        "box": [{"center_m": [3.024, -0.3454, 0.1028], "size_m": [0.4353, 1.9726, 0.2057]}],
    }))
    truth = sim.truth(0, LAYOUT)
    assert truth.sector_distance_m[2:6] == pytest.approx((2.851, 2.818, 2.818, 2.851),
                                                          abs=0.01)
    lit = sim._static_layer().laser.astype(np.float64)
    rows = np.rint(truth.line_rows[0]).astype(int)
    on_kerb = np.flatnonzero(truth.line_obstacle[0])
    assert lit[rows[on_kerb], on_kerb].min() > 0.0
