"""The sensor: electrons in, raw DN out, with shot noise, read noise, quantisation, saturation.

Per pixel with mean signal ``m`` electrons:

    e  = m + sqrt(m + σ_read²) · n,   n ~ N(0, 1)        (m >= POISSON_BELOW_E)
    e  = Poisson(m) + σ_read · n                          (0 < m < POISSON_BELOW_E)
    DN = min(round(e · gain), round(full_well · gain), 2**bits - 1), at least 0

The normal approximation of Poisson shot noise is used from ``POISSON_BELOW_E`` = 20
electrons up (skewness 1/√m ≤ 0.22 there, and the read noise adds to it); fewer
electrons are drawn from a true Poisson law.

Standard normals come from a 16-bit inverse-CDF table: 16 random bits pick one of 65536
equally likely normal quantiles (rescaled to unit variance; tails cut at ±4.2σ, where a
normal has 3·10⁻⁵ of its mass). Four samples per 64-bit draw of the bit generator make
this about 3× faster than ``standard_normal(dtype=float32)`` on this project's machines.
With the simulator's ``SFC64`` generators the draw, scaling, clipping and cast run as one
compiled loop (:mod:`atris_node.sim.sensor_kernels`) giving the same pixels as the numpy
steps, which stay for any other bit generator.
"""

from __future__ import annotations

from statistics import NormalDist
from typing import cast

import numpy as np
import numpy.typing as npt

from atris_node.sim import sensor_kernels
from atris_node.sim.scene import CameraSpec

Float32Array = npt.NDArray[np.float32]
Pixels = npt.NDArray[np.uint8] | npt.NDArray[np.uint16]
#: below this mean electron count shot noise is drawn from a Poisson law
POISSON_BELOW_E = 20.0


def _normal_table() -> Float32Array:
    p = (np.arange(65536) + 0.5) / 65536.0
    dist = NormalDist()
    table = np.array([dist.inv_cdf(float(x)) for x in p], dtype=np.float64)
    return (table / table.std()).astype(np.float32)


NORMAL_TABLE: Float32Array = _normal_table()


def standard_normals(rng: np.random.Generator, count: int) -> Float32Array:
    """``count`` standard normal float32 samples from the 16-bit quantile table."""
    raw = rng.bit_generator.random_raw((count + 3) // 4)
    index = np.asarray(raw).view(np.uint16)[:count]
    return NORMAL_TABLE[index]


def _flat(values: Float32Array) -> Float32Array:
    """``values`` as the kernels take them: flat, C-contiguous float32 (a view if it can)."""
    return np.ascontiguousarray(values, dtype=np.float32).reshape(-1)


def _sfc64_state(rng: np.random.Generator) -> npt.NDArray[np.uint64] | None:
    """The four state words of an SFC64 generator (a copy), None for other generators."""
    if not isinstance(rng.bit_generator, np.random.SFC64):
        return None
    return np.array(rng.bit_generator.state["state"]["state"], dtype=np.uint64)


def _set_sfc64_state(rng: np.random.Generator, words: npt.NDArray[np.uint64]) -> None:
    state = rng.bit_generator.state
    state["state"]["state"] = words
    rng.bit_generator.state = state


class Sensor:
    """Converts mean electrons (float32, any shape) into raw pixels of ``camera.bits``."""

    def __init__(self, camera: CameraSpec) -> None:
        self.gain = np.float32(camera.gain_dn_per_e)
        self.read_var_e2 = np.float32(camera.read_noise_e**2)
        self.read_noise_e = np.float32(camera.read_noise_e)
        full_scale = (1 << camera.bits) - 1
        well_dn = round(camera.full_well_e * camera.gain_dn_per_e)
        self.upper_dn = np.float32(min(full_scale, well_dn))
        self.dtype = np.uint8 if camera.bits <= 8 else np.uint16

    def quantise(self, electrons: Float32Array) -> Pixels:
        """Noise-free pixels: round, clip at the full well and full scale."""
        x = electrons * self.gain
        x += np.float32(0.5)
        np.clip(x, 0.0, self.upper_dn, out=x)
        return cast(Pixels, x.astype(self.dtype))

    def mean_dn(self, electrons: Float32Array) -> Float32Array:
        """``m · gain + 0.5`` (the rounding offset folded in), float32."""
        x = electrons * self.gain
        x += np.float32(0.5)
        return x

    def sigma_dn(self, electrons: Float32Array) -> Float32Array:
        """Standard deviation of shot plus read noise, in DN, float32."""
        x = np.maximum(electrons, np.float32(0.0))
        x += self.read_var_e2
        np.sqrt(x, out=x)
        x *= self.gain
        return x

    def noisy(self, rng: np.random.Generator, mean_dn: Float32Array, sigma_dn: Float32Array,
              low: npt.NDArray[np.intp], low_mean_e: Float32Array) -> Pixels:
        """Noisy pixels from precomputed ``mean_dn`` / ``sigma_dn`` (same shape).

        ``low`` are flat indices of pixels with ``0 < m < POISSON_BELOW_E`` and
        ``low_mean_e`` their means: those are redrawn from a Poisson law.
        """
        words = _sfc64_state(rng)
        if words is None:
            x = standard_normals(rng, mean_dn.size).reshape(mean_dn.shape)
            x *= sigma_dn
            x += mean_dn
            np.clip(x, 0.0, self.upper_dn, out=x)
            pixels = x.astype(self.dtype)
        else:
            pixels = np.empty(mean_dn.shape, self.dtype)
            sensor_kernels.noisy_from_prepared(words, NORMAL_TABLE, _flat(mean_dn),
                                               _flat(sigma_dn), self.upper_dn,
                                               pixels.reshape(-1))
            _set_sfc64_state(rng, words)
        if low.size:
            shot = rng.poisson(low_mean_e).astype(np.float32)
            read = standard_normals(rng, low.size) * self.read_noise_e
            x_low = (shot + read) * self.gain + np.float32(0.5)
            np.clip(x_low, 0.0, self.upper_dn, out=x_low)
            pixels.reshape(-1)[low] = x_low
        return cast(Pixels, pixels)

    def noisy_electrons(self, rng: np.random.Generator, electrons: Float32Array) -> Pixels:
        """Noisy pixels straight from a mean image that changes every sub-frame.

        ``electrons`` is used as scratch space (its values are destroyed). The Poisson
        redraw is done only when some pixel is below POISSON_BELOW_E.
        """
        flat = _flat(electrons)
        if sensor_kernels.any_below(flat, np.float32(POISSON_BELOW_E)):
            return self.noisy(rng, *self.prepare(electrons))
        words = _sfc64_state(rng)
        if words is not None:
            pixels = np.empty(electrons.shape, self.dtype)
            sensor_kernels.noisy_from_electrons(words, NORMAL_TABLE, flat, self.gain,
                                                self.read_var_e2, self.upper_dn,
                                                pixels.reshape(-1))
            _set_sfc64_state(rng, words)
            return cast(Pixels, pixels)
        sigma = self.sigma_dn(electrons)
        x = standard_normals(rng, electrons.size).reshape(electrons.shape)
        x *= sigma
        electrons *= self.gain
        electrons += np.float32(0.5)
        x += electrons
        np.clip(x, 0.0, self.upper_dn, out=x)
        return cast(Pixels, x.astype(self.dtype))

    def prepare(self, electrons: Float32Array) -> tuple[Float32Array, Float32Array,
                                                        npt.NDArray[np.intp], Float32Array]:
        """Everything :meth:`noisy` needs for one mean image (cache it for static scenes)."""
        flat = electrons.reshape(-1)
        low = np.flatnonzero((flat > 0.0) & (flat < POISSON_BELOW_E))
        return self.mean_dn(electrons), self.sigma_dn(electrons), low, flat[low].copy()
