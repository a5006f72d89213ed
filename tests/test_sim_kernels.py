"""Compiled simulator paths against the numpy steps they replace: same pixels, same
stream of random numbers, same hits."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from atris_node.sim.scene import CameraSpec
from atris_node.sim.sensor import POISSON_BELOW_E, Sensor, standard_normals

CAMERA = CameraSpec(64, 48, 50.0, 31.5, 23.5, 240.0, 1000.0, 10, 10000.0, 3.0, 1023 / 10000)


def numpy_noisy(sensor: Sensor, rng: np.random.Generator, electrons: np.ndarray) -> np.ndarray:
    """The numpy steps: table normals, scale, shift, Poisson redraw of low pixels, clip."""
    mean, sigma, low, low_mean = sensor.prepare(electrons)
    x = standard_normals(rng, mean.size).reshape(mean.shape) * sigma + mean
    if low.size:
        shot = rng.poisson(low_mean).astype(np.float32)
        read = standard_normals(rng, low.size) * sensor.read_noise_e
        x.reshape(-1)[low] = (shot + read) * sensor.gain + np.float32(0.5)
    np.clip(x, 0.0, sensor.upper_dn, out=x)
    return x.astype(sensor.dtype)


@pytest.mark.parametrize("bits", [8, 10])
@pytest.mark.parametrize("low", [False, True])
@pytest.mark.parametrize("generator", [np.random.SFC64, np.random.PCG64])
def test_feature_compiled_noise_equals_numpy_steps(bits: int, low: bool,
                                                   generator: type) -> None:
    sensor = Sensor(replace(CAMERA, bits=bits, gain_dn_per_e=((1 << bits) - 1) / 10000))
    electrons = (np.random.default_rng(3).random((37, 91)) * 12000).astype(np.float32)
    if low:
        electrons[:3, :5] = POISSON_BELOW_E / 4  # redrawn from Poisson after the normals
    expected_rng = np.random.Generator(generator(7))
    expected = numpy_noisy(sensor, expected_rng, electrons)
    expected_next = expected_rng.random()
    for draw in ("prepared", "electrons"):
        rng = np.random.Generator(generator(7))
        pixels = (sensor.noisy(rng, *sensor.prepare(electrons)) if draw == "prepared"
                  else sensor.noisy_electrons(rng, electrons.copy()))
        assert pixels.dtype == expected.dtype
        assert np.array_equal(pixels, expected), draw
        assert rng.random() == expected_next, draw  # the generator is left where numpy was


def shapes_all_kinds() -> list[Any]:
    from atris_node.sim.raycast import Box, Cylinder, Plane, Ramp, Sphere

    return [Plane(0.3, name="ground"),
            Plane(0.5, point_m=(6.0, 0.0, 0.0), normal=(-1.0, 0.2, 0.0)),
            Sphere(0.4, center_m=(3.0, 0.5, 0.6), radius_m=0.5, velocity_mps=(0.0, -2.0, 0.0)),
            Box(0.6, center_m=(2.5, -1.0, 0.5), size_m=(0.4, 0.8, 1.0), yaw_rad=0.4),
            Box(0.6, center_m=(4.0, 1.0, 0.45), size_m=(1.0, 1.0, 0.9),
                velocity_mps=(-3.0, 0.0, 0.0)),
            Cylinder(0.9, center_m=(2.0, 0.2, 0.0), radius_m=0.22, height_m=1.75,
                     velocity_mps=(0.0, -1.4, 0.0), acceleration_mps2=(0.0, 0.5, 0.0)),
            Ramp(0.4, start_m=(1.5, -0.5, 0.0), length_m=2.0, width_m=1.0, slope_rad=0.3,
                 yaw_rad=0.2)]


def random_rays(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(n, 3)) + np.array([1.5, 0.0, -0.2])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[:8] = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1], [1, 0, -0.0], [-1, 0, 0],
                [0.6, 0.8, 0.0], [0.0, 0.6, -0.8]]  # axis-aligned and level rays
    return rng.normal(size=(n, 3)) * [1.0, 1.0, 0.3] + [0.0, 0.0, 0.6], dirs


@pytest.mark.parametrize("time_s", [0.0, 0.37])
def test_feature_compiled_cast_equals_numpy_intersect(time_s: float) -> None:
    from atris_node.sim.raycast import cast, cast_reference

    shapes = shapes_all_kinds()
    origins, dirs = random_rays(20000, 5)
    for start in (origins, origins[0]):  # one origin per ray, or one for all
        for i, shape in enumerate(shapes):  # each kind alone, then all together
            got = cast([shape], start, dirs, time_s, index_offset=i)
            want = cast_reference([shape], start, dirs, time_s, index_offset=i)
            assert np.array_equal(np.isinf(got.t), np.isinf(want.t)), type(shape).__name__
            assert np.array_equal(got.shape, want.shape)
            np.testing.assert_allclose(got.t, want.t, rtol=1e-12, atol=1e-12)
            hit = np.isfinite(want.t)
            np.testing.assert_allclose(got.normal[hit], want.normal[hit], atol=1e-9)
        got, want = cast(shapes, start, dirs, time_s), cast_reference(shapes, start, dirs, time_s)
        assert np.array_equal(got.shape, want.shape)
        np.testing.assert_allclose(got.t, want.t, rtol=1e-12)


def reference_sheet_angles(pose: Any, pattern: Any, points: np.ndarray) -> tuple[np.ndarray, ...]:
    """The numpy form of :func:`atris_node.sim.optics.sheet_angles`."""
    d = pose.vehicle_to_camera(points) - np.array([0.0, -pattern.baseline_m, 0.0])
    r = np.linalg.norm(d, axis=-1)
    theta = np.arctan2(d[..., 2], d[..., 1])
    phi = np.arctan2(d[..., 0], np.hypot(d[..., 1], d[..., 2]))
    dirs = (d / np.maximum(r, 1e-12)[..., None]) @ pose.rotation.T
    return theta, phi, r, dirs


def test_feature_compiled_sheet_angles_equal_numpy() -> None:
    from atris_node.mounting import Mounting
    from atris_node.sim import LinePattern
    from atris_node.sim.optics import sheet_angles

    pose = Mounting(0.1, -0.4, 0.6, 0.02, 0.05, 0.3)
    pattern = LinePattern((1.4, 1.5), 0.5, baseline_m=0.075)
    points = np.random.default_rng(2).normal(size=(40, 50, 3)) * 3.0 + [4.0, 0.0, 0.5]
    for got, want in zip(sheet_angles(pose, pattern, points),
                         reference_sheet_angles(pose, pattern, points), strict=True):
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-15)


def reference_sheet_irradiance(pose: Any, pattern: Any, shapes: Any, *, points: np.ndarray,
                               normals: np.ndarray, hit: np.ndarray, psf_sigma_px: float,
                               time_s: float = 0.0) -> np.ndarray:
    """The whole-grid numpy form of :func:`atris_node.sim.optics.sheet_irradiance`."""
    import math

    from atris_node.sim import optics

    theta, phi, r, dirs = reference_sheet_angles(pose, pattern, points)
    theta = np.where(hit, theta, np.nan)
    profile = optics.sheet_profile(theta, pattern, optics.footprint_rad(theta), psf_sigma_px)
    in_fan = hit & (np.abs(phi) <= pattern.fan_rad / 2.0) & (theta > 0.0)
    cos_i = np.clip(-np.einsum("...i,...i->...", normals, dirs), 0.0, None)
    peak = pattern.power_w / len(pattern.alpha_rad) / (
        pattern.fan_rad * pattern.line_sigma_rad * math.sqrt(2.0 * math.pi))
    irr = np.where(in_fan, peak * profile * cos_i / np.maximum(r, 1e-3) ** 2, 0.0)
    lit = np.flatnonzero(irr.ravel() > 0.0)
    lit = lit[profile.ravel()[lit] > optics.PROFILE_CUTOFF]
    flat = irr.ravel()
    flat[np.setdiff1d(np.flatnonzero(flat > 0.0), lit, assume_unique=True)] = 0.0
    if lit.size:
        pts = points.reshape(-1, 3)[lit]
        flat[lit[optics.occluded(shapes, pts, -dirs.reshape(-1, 3)[lit], r.ravel()[lit],
                                 time_s)]] = 0.0
    return flat.reshape(irr.shape)


def use_reference_paths(monkeypatch: pytest.MonkeyPatch) -> None:
    """Render with the numpy ray casting, source angles and whole-grid laser sheets."""
    from atris_node.sim import layers, optics, raycast, render

    monkeypatch.setattr(raycast, "cast", raycast.cast_reference)
    monkeypatch.setattr(layers, "cast", raycast.cast_reference)
    monkeypatch.setattr(optics, "sheet_irradiance", reference_sheet_irradiance)
    monkeypatch.setattr(optics, "sheet_angles", reference_sheet_angles)
    monkeypatch.setattr(render, "sheet_angles", reference_sheet_angles)


@pytest.mark.parametrize(("name", "unit"), [("parking_pedestrian", 0), ("fleet", 0)])
@pytest.mark.parametrize("noise", [False, True])
def test_feature_moving_frames_equal_reference_paths(name: str, unit: int, noise: bool,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from atris_node.sim import Simulator, load_scene

    scene = replace(load_scene(name), noise=noise)
    sequences = [(0, 0), (1, 1), (40, 1), (97, 0), (97, 1)]
    fast = Simulator(scene, unit=unit)
    frames = [fast.render(s, chip).pixels for s, chip in sequences]
    assert fast.calls["motion"] == len(sequences)
    use_reference_paths(monkeypatch)
    slow = Simulator(scene, unit=unit)
    for (s, chip), pixels in zip(sequences, frames, strict=True):
        assert np.array_equal(slow.render(s, chip).pixels, pixels), (s, chip)
