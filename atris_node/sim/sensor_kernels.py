"""Compiled noise draw of the sensor (numba, ``nopython``): one pass per sub-frame.

The numpy steps of :meth:`atris_node.sim.sensor.Sensor.noisy` (draw the raw 64-bit
words, pick table quantiles, scale, shift, clip, cast) made six passes and four
temporaries over the frame; at 2048×1088 they took about 7 ms. Here one loop does them
all, with the same arithmetic in the same float32 order, so the pixels are bit-identical
to the numpy steps.

The random words are those of numpy's ``SFC64`` bit generator, stepped here from its
state (``state`` below, the four uint64 words ``a, b, c, counter`` of
``bit_generator.state["state"]["state"]``; the caller writes the advanced state back).
Each 64-bit word gives four 16-bit table indices, lowest bits first, as numpy's
``random_raw(...).view(np.uint16)`` does on a little-endian machine; a frame of n pixels
takes ``ceil(n / 4)`` words, like ``standard_normals``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from numba import types

from atris_node.jit import kernel

U64Array = npt.NDArray[np.uint64]
Float32Array = npt.NDArray[np.float32]
Pixels = npt.NDArray[np.uint8] | npt.NDArray[np.uint16]


@kernel()
def sfc64_next(state: U64Array) -> np.uint64:
    """The next 64-bit word of SFC64 (numpy's ``sfc64_next``); advances ``state``."""
    a, b, c, counter = state[0], state[1], state[2], state[3]
    word = a + b + counter
    state[3] = counter + np.uint64(1)
    state[0] = b ^ (b >> np.uint64(11))
    state[1] = c + (c << np.uint64(3))
    state[2] = ((c << np.uint64(24)) | (c >> np.uint64(40))) + word
    return word


def _signatures(with_electrons: bool) -> list[Any]:
    u64, f32 = types.Array(types.uint64, 1, "C"), types.float32
    f32_1 = types.Array(f32, 1, "C")
    values = (f32_1, f32, f32, f32) if with_electrons else (f32_1, f32_1, f32)
    return [types.void(u64, f32_1, *values, types.Array(dtype, 1, "C"))
            for dtype in (types.uint8, types.uint16)]


@kernel(_signatures(False))
def noisy_from_prepared(state: U64Array, table: Float32Array, mean_dn: Float32Array,
                        sigma_dn: Float32Array, upper_dn: np.float32, out: Pixels) -> None:
    """``out = clip(table[index] · sigma_dn + mean_dn, 0, upper_dn)`` cast to out's type."""
    zero = np.float32(0.0)
    word = np.uint64(0)
    for i in range(out.size):
        if i % 4 == 0:
            word = sfc64_next(state)
        x = table[(word >> np.uint64(16 * (i % 4))) & np.uint64(0xFFFF)] * sigma_dn[i]
        x = x + mean_dn[i]
        out[i] = min(max(x, zero), upper_dn)


@kernel(_signatures(True))
def noisy_from_electrons(state: U64Array, table: Float32Array, electrons: Float32Array,
                         gain: np.float32, read_var_e2: np.float32, upper_dn: np.float32,
                         out: Pixels) -> None:
    """As :func:`noisy_from_prepared` with ``mean_dn = e · gain + 0.5`` and
    ``sigma_dn = sqrt(max(e, 0) + read_var_e2) · gain`` computed on the way."""
    zero, half = np.float32(0.0), np.float32(0.5)
    word = np.uint64(0)
    for i in range(out.size):
        if i % 4 == 0:
            word = sfc64_next(state)
        e = electrons[i]
        sigma = np.sqrt(max(e, zero) + read_var_e2) * gain
        x = table[(word >> np.uint64(16 * (i % 4))) & np.uint64(0xFFFF)] * sigma
        x = x + (e * gain + half)
        out[i] = min(max(x, zero), upper_dn)


@kernel(types.boolean(types.Array(types.float32, 1, "C"), types.float32))
def any_below(values: Float32Array, limit: np.float32) -> bool:
    """True when some value is below ``limit`` (stops at the first)."""
    for i in range(values.size):  # noqa: SIM110 (a generator does not compile)
        if values[i] < limit:
            return True
    return False
