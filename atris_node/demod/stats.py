"""Strip sampling and the statistics of a distortion map: ambient level, gain, SNR.

Laser lines are horizontal, so statistics use every row of a few narrow column strips:
short contiguous runs of each row that touch few cache lines.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.generic]
#: columns sampled for lock, ambient level and gain statistics: strips of this width ...
STRIP_WIDTH = 8
#: ... at these fractions of the frame width (laser lines are horizontal: every row counts)
STRIP_POSITIONS = (0.25, 0.75)
#: quantisation floor of the residual delta in DN, keeps the SNR finite on noiseless data
RESIDUAL_FLOOR_DN = 0.5


@functools.lru_cache(maxsize=8)
def _strip_starts(width: int) -> tuple[int, ...]:
    return tuple(sorted({min(int(p * width), max(width - STRIP_WIDTH, 0))
                         for p in STRIP_POSITIONS}))


def strip_sample(image: Array) -> Array:
    """All rows of the sampled column strips, (H, <= 2 * STRIP_WIDTH), same dtype.

    Strips are short contiguous runs of each row, so reading them touches few cache lines;
    laser lines are horizontal, so every row is kept.
    """
    return np.concatenate([image[:, s:s + STRIP_WIDTH] for s in _strip_starts(image.shape[1])],
                          axis=1)


def strip_level(pixels: Array) -> float:
    """Mean raw level of the sampled strips of a sub-frame, in DN."""
    starts = _strip_starts(pixels.shape[1])
    total = sum(int(pixels[:, s:s + STRIP_WIDTH].sum(dtype=np.int64)) for s in starts)
    return total / (pixels.shape[0] * min(STRIP_WIDTH, pixels.shape[1]) * len(starts))


def measure_gain(values: Array, code_length: int) -> tuple[float, float, float, float]:
    """Processing gain and SNR of a distortion map (paper Eq. 5-6), measured on strips.

    The background of a map is symmetric about 0 and the laser only adds, so the noise
    scale is taken from the negative values: ``sigma^2 = 2 sum(x^2 | x < 0) / n``. Signal
    pixels are those above ``max(6 sigma, max / 4, 1 DN)``; ``I_S`` is their mean,
    ``delta = I_B`` the RMS of the others (floored at RESIDUAL_FLOOR_DN). Then
    ``l = 2 (I_S - delta) / N``, ``PG = I_S / l``, ``SNR = I_S / delta``. Returns
    (PG, SNR, I_S, delta), all finite; PG = SNR = 0.0 when no laser signal is found.
    Sums run in float32 over the strip sample (16 values a row).
    """
    sample = strip_sample(values).ravel().astype(np.float32)
    negative = np.minimum(sample, 0.0)
    sigma = math.sqrt(2.0 * float(negative @ negative) / sample.size)
    threshold = max(6.0 * sigma, 0.25 * float(np.maximum.reduce(sample)), 1.0)
    signal = sample[sample > threshold]
    background_energy = float(sample @ sample) - float(signal @ signal)
    background = sample.size - signal.size
    delta = max(math.sqrt(max(background_energy, 0.0) / background) if background else 0.0,
                RESIDUAL_FLOOR_DN)
    if not signal.size:
        return 0.0, 0.0, 0.0, delta
    i_s = float(np.add.reduce(signal)) / signal.size
    laser = 2.0 * (i_s - delta) / code_length
    if laser <= 0.0:
        return 0.0, 0.0, i_s, delta
    return i_s / laser, i_s / delta, i_s, delta
