"""Rendering: sub-frame fields, noise statistics, saturation, radiometric laws, skipped work."""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pytest

from atris_node.mounting import Mounting
from atris_node.sim import Simulator
from atris_node.sim.scene import LinePattern, parse_scene
from atris_node.sim.sensor import NORMAL_TABLE, POISSON_BELOW_E
from atris_node.sim.strobe import always_on, code_strobe, flicker_factor

WALL: dict[str, Any] = {
    "camera": {"width_px": 96, "height_px": 64, "focal_px": 60.0, "rate_hz": 240.0,
               "exposure_us": 1000.0, "bits": 10, "full_well_e": 10000.0,
               "read_noise_e": 3.0},
    "projector": {"baseline_m": 0.075, "alpha_deg": [84.0, 88.0], "power_w": 0.05},
    "mounting": {"z_m": 0.5},
    "plane": [{"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "albedo": 0.5}],
    "ambient": {"lamp": {"lux": 300.0}},
}


def scene(**changes: Any) -> Any:
    data = copy.deepcopy(WALL)
    for dotted, value in changes.items():
        table, key = dotted.split("__")
        data.setdefault(table, {})[key] = value
    return parse_scene(data)


def test_smoke_sub_frame_fields() -> None:
    sim = Simulator(scene(), seed=3)
    sub = sim.render(5, chip=1)
    assert sub.pixels.shape == (64, 96) and sub.pixels.dtype == np.uint16
    assert (sub.sequence, sub.chip, sub.bits, sub.exposure_us) == (5, 1, 10, 1000.0)
    assert sub.device_time_s == pytest.approx(5 / 240.0 + 0.0005)
    assert sim.render(6).chip == int(sim.chips[6 % sim.chips.size])
    eight_bit = Simulator(scene(camera__bits=8)).render(0, 0)
    assert eight_bit.pixels.dtype == np.uint8


def test_feature_fixed_seed_is_bit_identical_in_any_order() -> None:
    a, b = Simulator(scene(), seed=11), Simulator(scene(), seed=11)
    first = [a.render(s, s & 1).pixels for s in range(4)]
    second = [b.render(s, s & 1).pixels for s in reversed(range(4))][::-1]
    assert all(np.array_equal(x, y) for x, y in zip(first, second, strict=True))
    other = Simulator(scene(), seed=12).render(0, 0).pixels
    assert not np.array_equal(first[0], other)
    flicker = {"lux": 300.0, "flicker_hz": 100.0, "flicker_depth": 0.5}
    c, d = (Simulator(scene(ambient__lamp=flicker), seed=11) for _ in range(2))
    assert c.dynamic
    assert np.array_equal(c.render(7).pixels, d.render(7).pixels)


def test_feature_static_noise_free_scene_skips_work() -> None:
    sim = Simulator(scene(noise__enabled=False))
    frames = [sim.render(s, s & 1).pixels for s in range(6)]
    assert not sim.dynamic
    assert sim.calls == {"static_render": 1}
    assert np.array_equal(frames[0], frames[2]) and frames[0] is not frames[2]
    noisy = Simulator(scene(), seed=1)
    noisy.render(0, 0)
    noisy.render(1, 0)
    assert noisy.calls == {"static_render": 1, "noise": 2}


def test_feature_dynamic_parts_are_counted_only_when_present() -> None:
    sim = Simulator(scene(ambient__lamp={"lux": 300.0, "flicker_hz": 100.0,
                                         "flicker_depth": 0.5}), seed=1)
    sim.add_interferer(Mounting(y_m=0.5), LinePattern((math.radians(85.0),), 0.05), always_on)
    for s in range(3):
        sim.render(s)
    assert sim.calls["flicker"] == 3 and sim.calls["interferer"] == 3
    assert "motion" not in sim.calls


def test_feature_noise_statistics_match_shot_and_read_noise() -> None:
    sim = Simulator(scene(projector__power_w=0.0, camera__gain_dn_per_e=1.0,
                          camera__full_well_e=60000.0, camera__bits=16), seed=5)
    mean_e = sim._mean_electrons(0)
    pixels = np.stack([sim.render(s, 0).pixels for s in range(8)]).astype(np.float64)
    flat = mean_e.ravel() > 100
    residual = (pixels - mean_e[None]).reshape(8, -1)[:, flat]
    expected_var = (mean_e.ravel()[flat] + 9.0).mean() + 1.0 / 12.0
    assert abs(residual.mean()) < 0.5
    assert residual.var() == pytest.approx(expected_var, rel=0.05)


def test_feature_low_counts_are_poisson() -> None:
    sim = Simulator(scene(projector__power_w=0.0, ambient__lamp={"lux": 0.2},
                          camera__gain_dn_per_e=1.0, camera__read_noise_e=0.0), seed=2)
    mean_e = sim._mean_electrons(0).ravel()
    assert 0.5 < mean_e.mean() < POISSON_BELOW_E
    values = np.concatenate([sim.render(s, 0).pixels.ravel() for s in range(20)])
    lam = np.tile(mean_e, 20)
    assert np.mean(values == 0) == pytest.approx(np.mean(np.exp(-lam)), abs=0.01)


def test_feature_saturation_at_full_well_and_full_scale() -> None:
    bright = Simulator(scene(ambient__lamp={"lux": 50000.0}), seed=1).render(0, 0)
    assert bright.pixels.max() == 1023 and np.mean(bright.pixels == 1023) > 0.9
    shallow = Simulator(scene(ambient__lamp={"lux": 50000.0}, camera__full_well_e=5000.0,
                              camera__gain_dn_per_e=0.1023), seed=1).render(0, 0)
    assert shallow.pixels.max() == round(5000.0 * 0.1023)


def test_feature_normal_table_is_unit_normal() -> None:
    assert NORMAL_TABLE.size == 65536
    assert float(NORMAL_TABLE.astype(np.float64).std()) == pytest.approx(1.0, abs=1e-6)
    assert abs(float(NORMAL_TABLE.mean())) < 1e-6 and NORMAL_TABLE.max() > 4.0


def column_energy(distance_m: float) -> float:
    """Laser electrons summed over the rows of 16 central columns (the whole stripe)."""
    data = copy.deepcopy(WALL)
    data["plane"][0]["point_m"] = [distance_m, 0.0, 0.0]
    data["ground"] = {"enabled": False}
    laser = Simulator(parse_scene(data))._static_layer().laser
    return float(laser[:, 40:56].sum())


def test_feature_laser_falls_with_inverse_square_of_distance() -> None:
    # the stripe's power per column is fixed by the fan; the camera collects 1/r² of it
    ratio = column_energy(2.0) / column_energy(4.0)
    assert ratio == pytest.approx(4.0, rel=0.05)


def test_feature_lambertian_albedo_and_incidence() -> None:
    def steady(albedo: float, normal: list[float]) -> float:
        data = copy.deepcopy(WALL)
        data["plane"] = [{"point_m": [2.0, 0.0, 0.0], "normal": normal, "albedo": albedo}]
        data["ground"] = {"enabled": False}
        data["ambient"] = {"sun": {"lux": 1000.0, "azimuth_deg": 180.0,
                                   "elevation_deg": 0.0}}
        return float(Simulator(parse_scene(data))._static_layer().steady[32, 48])
    assert steady(0.8, [-1.0, 0.0, 0.0]) == pytest.approx(2 * steady(0.4, [-1.0, 0.0, 0.0]))
    tilted = [-math.cos(math.radians(60)), math.sin(math.radians(60)), 0.0]
    assert steady(0.8, tilted) == pytest.approx(0.5 * steady(0.8, [-1.0, 0.0, 0.0]), rel=1e-3)


def test_feature_strobe_is_integrated_over_the_exposure() -> None:
    strobe = code_strobe([1, 0], rate_hz=100.0, phase_sub_frames=0.25, on_s=0.01)
    assert strobe(0.0, 0.01) == pytest.approx(0.75)  # lit from 2.5 ms to 10 ms, off after
    assert strobe(0.0025, 0.0125) == pytest.approx(1.0)
    assert strobe(0.0125, 0.0225) == pytest.approx(0.0)
    short = code_strobe([1, 1, 0, 0], rate_hz=200.0, phase_sub_frames=0.0, on_s=0.001)
    assert short(0.0, 0.02) == pytest.approx(0.002 / 0.02)
    assert always_on(3.0, 4.0) == 1.0


def test_feature_flicker_factor_is_the_window_mean() -> None:
    t = np.linspace(0.001, 0.003, 20001)
    numeric = float(np.mean(1.0 + 0.6 * np.cos(2 * np.pi * 100.0 * t)))
    assert flicker_factor(100.0, 0.6, 0.001, 0.003) == pytest.approx(numeric, abs=1e-4)
    assert flicker_factor(0.0, 0.6, 0.0, 1.0) == 1.0


def test_feature_moving_shape_changes_pixels_and_leaves_trails() -> None:
    data = copy.deepcopy(WALL)
    data["noise"] = {"enabled": False}
    data["sphere"] = [{"center_m": [1.5, 0.3, 0.5], "radius_m": 0.15, "albedo": 0.9,
                       "velocity_mps": [0.0, -3.0, 0.0]}]
    sim = Simulator(parse_scene(data))
    a, b = sim.render(0, 0).pixels, sim.render(24, 0).pixels
    assert sim.calls["motion"] == 2
    assert np.count_nonzero(a != b) > 20
    still = copy.deepcopy(data)
    still["sphere"][0]["velocity_mps"] = [0.0, 0.0, 0.0]
    static = Simulator(parse_scene(still))
    assert np.array_equal(static.render(0, 0).pixels, static.render(24, 0).pixels)
    assert "motion" not in static.calls


def test_exception_bad_unit_chip_and_exposure() -> None:
    from atris_node.errors import ConfigError

    with pytest.raises(ConfigError, match="unit 1 has no mounting"):
        Simulator(scene(), unit=1)
    sim = Simulator(scene())
    with pytest.raises(ValueError, match="chip must be 0 or 1"):
        sim.render(0, chip=2)
    with pytest.raises(ConfigError, match="exposure_us must be in"):
        sim.set_exposure_us(10000.0)


def test_feature_interferers_attach_while_rendering() -> None:
    import threading

    sim = Simulator(scene(), seed=1)
    errors: list[BaseException] = []

    def attach() -> None:
        try:
            for i in range(3):
                sim.add_interferer(Mounting(y_m=0.2 * i), LinePattern((1.5,), 0.05),
                                   always_on)
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    worker = threading.Thread(target=attach, name="attach")
    worker.start()
    frames = [sim.render(s) for s in range(30)]
    worker.join()
    assert not errors and len(frames) == 30
    assert len(sim.sources) == 3 and len(sim._static_layer().interferers) == 3
    alone = Simulator(scene(), seed=1).render(30, 0).pixels.astype(np.int64)
    assert (sim.render(30, 0).pixels - alone).sum() > 1000  # their lines add light
