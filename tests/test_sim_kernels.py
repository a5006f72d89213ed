"""Compiled simulator paths against the numpy steps they replace: same pixels, same
stream of random numbers, same hits."""

from __future__ import annotations

from dataclasses import replace

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
