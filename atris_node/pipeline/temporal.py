"""Whether a peak's time course over the window can be the unit's own strobed light.

The map holds ``D = sum_i s_i F_i``. Ambient light that stays constant over the window
cancels; ambient light that changes does not. An intensity edge of the scene that moves
during the window (the top of an approaching car against the sky) changes the pixels it
crosses, and its residual in ``D`` is a sharp stripe as strong as a line: it can complete
a comb one line off (docs/pipeline.md "Moving edges").

Own light is on the ON sub-frames only and never negative, whatever its course (still,
moving, crossing the pixel within one sub-frame); the OFF sub-frames hold ambient light
alone. So the own light of ON sub-frame ``i`` is measured against the ambient light
interpolated in time between the nearest OFF sub-frames before and after it (the last OFF
sub-frame before the window stands in on the left when the demodulator kept it; at an end
with no OFF neighbour the one on the other side is taken as is):

    L_i = F_i - A_i,    D_local = sum_(i ON) L_i = sum_j u_j F_j

``D_local`` equals the own light's share of ``D`` for ambient light that changes linearly
(exactly) or not at all, and is 0 for a linear change alone. An ambient step between two
sub-frames reaches ``D_local`` through the one ON sub-frame next to it, at most half the
step, while ``D`` holds all of it. A peak with ``D_local < LOCAL_SHARE * D - LOCAL_SIGMAS *
sigma_local`` is not own light and is set aside (counted as doubtful in its column, so the
column is evidence of nothing). A peak that holds own light and an ambient step (a stripe
that a walking pedestrian then covers) keeps its own light in ``D_local`` and stays.

Both sums are linear in the window's sub-frames, so the test statistic is ``sum_j (u_j -
LOCAL_SHARE s_j) F_j`` (constant light cancels in it) and its noise ``sigma_test =
sigma_pixel * |u - LOCAL_SHARE s|``: for own light it sits at ``(1 - LOCAL_SHARE) D``, many
σ above the limit. The pixel's σ is the largest of the tile's (σ of
D over sqrt N), the rounding's and the shot noise of its own level, ``gain * level``, with
the gain (DN² per DN) taken per map as the lower quartile of the peaks' OFF variance over
their level (a photon transfer estimate; it holds while a quarter of the peaks are lines or
noise on still ambient). The tile's σ alone is far below a bright pixel's noise.
Known limit: ambient light that drops right after an ON first sub-frame of the first window
(no sub-frame before it) looks exactly like own light seen on that sub-frame alone.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node.pipeline import peaks_kernels
from atris_node.pipeline.noise import NOISE_TILE_PX, NoiseMap
from atris_node.types import WindowFrames

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: share of D that own light must account for (an ambient step gives at most half)
LOCAL_SHARE = 0.75
#: noise margin, in σ of D_local
LOCAL_SIGMAS = 4.0
#: quantile of the peaks' OFF variance / level ratios taken as the map's shot-noise gain
SHOT_QUANTILE = 0.25
#: σ of rounding a pixel to whole DN: no pixel is less noisy (a dark tile's σ of the sum,
#: from quantised values, can come out below it)
QUANTIZATION_DN = 1.0 / math.sqrt(12.0)


def local_weights(signs: tuple[int, ...], before: int | None = None) -> FloatArray:
    """(N + 1,) weights ``u`` of ``D_local = u[0] F_before + sum_j u[j + 1] F_j`` (``u[0]``
    is 0 without a sub-frame before the window; ``before`` is its time, < 0)."""
    n = len(signs)
    u = np.zeros(n + 1)
    off = [j for j in range(n) if signs[j] < 0]
    left_times = ([before] if before is not None else []) + off
    for i in (i for i in range(n) if signs[i] > 0):
        left = max((t for t in left_times if t < i), default=None)
        right = min((t for t in off if t > i), default=None)
        u[i + 1] += 1.0
        for t, share in _interpolation(i, left, right):
            u[t + 1 if t >= 0 else 0] -= share
    return u


def _interpolation(i: int, left: int | None, right: int | None) -> list[tuple[int, float]]:
    """The OFF sub-frames and weights that interpolate the ambient at time ``i``."""
    if left is None:
        return [] if right is None else [(right, 1.0)]
    if right is None:
        return [(left, 1.0)]
    share = (i - left) / (right - left)
    return [(left, 1.0 - share), (right, share)]


def not_own_light(peaks: IntArray, window: WindowFrames | None, local: NoiseMap) -> BoolArray:
    """(M, W) True for the peaks (rows, -1 padding) whose time course is not own light
    (module docstring). All False when the map has no window (read back from a
    recording) or the code has no OFF sub-frame. The peak pixels and the OFF sub-frames'
    statistics come from compiled passes (:func:`atris_node.pipeline.peaks_kernels.peak_pixels`,
    :func:`atris_node.pipeline.peaks_kernels.ambient_level`)."""
    out = np.zeros(peaks.shape, dtype=bool)
    if window is None or len(window.pixels) != len(window.signs) or not peaks.size:
        return out
    m, c, flat, tile_sigma = peaks_kernels.peak_pixels(
        np.ascontiguousarray(peaks, dtype=np.int64), local.tile_row, local.sigma_tiles,
        NOISE_TILE_PX)
    if not m.size or min(window.signs) > 0:
        return out
    before = window.before
    test, norm = _test_weights(tuple(window.signs), None if before is None else before[0])
    frames = ((before[1],) if before is not None else ()) + window.pixels
    series = _series(frames, flat)  # (n, P), DN
    sigma = _pixel_sigma(series, window, tile_sigma)
    out[m, c] = test @ series < -LOCAL_SIGMAS * sigma * norm
    return out


@functools.lru_cache(maxsize=64)
def _test_weights(signs: tuple[int, ...], before: int | None) -> tuple[FloatArray, float]:
    """The weights of the test statistic ``sum_j (u_j - LOCAL_SHARE s_j) F_j`` over the
    frames read ((N + 1,) with a sub-frame before the window at time ``before``, else
    (N,)), read-only, and their Euclidean norm. Kept per code and lag: a unit's windows
    repeat a few of them."""
    u = local_weights(signs, before)
    test = u - LOCAL_SHARE * np.concatenate([[0.0], np.asarray(signs, np.float64)])
    if before is None:
        test = test[1:]
    test.setflags(write=False)
    return test, float(np.linalg.norm(test))


def _series(frames: tuple[npt.NDArray[Any], ...], flat: IntArray) -> FloatArray:
    """(n, P) float64 the value of each frame at the flat pixel indices ``flat``, DN (one
    ``take`` per frame: several times faster than 2-D fancy indexing)."""
    out = np.empty((len(frames), flat.size), dtype=np.float64)
    for i, frame in enumerate(frames):
        out[i] = np.ravel(frame).take(flat)
    return out


def _pixel_sigma(series: FloatArray, window: WindowFrames,
                 sigma_tiles: npt.NDArray[np.float32]) -> FloatArray:
    """(P,) each peak pixel's σ per sub-frame, DN: the largest of the tile's, the
    rounding's and the shot noise of its level (the map's photon-transfer gain). The
    level and the OFF variance over it in one compiled pass
    (:func:`atris_node.pipeline.peaks_kernels.ambient_level`)."""
    offs = np.flatnonzero(np.asarray(window.signs) < 0) + (window.before is not None)
    level, ratio = peaks_kernels.ambient_level(series, offs.astype(np.int64))
    gain = quantile(ratio, SHOT_QUANTILE)
    tile = sigma_tiles.astype(np.float64) / math.sqrt(len(window.signs))
    # the largest of the three, as np.maximum.reduce over them (maximum is exact)
    return np.sqrt(np.maximum(np.maximum(np.square(tile), QUANTIZATION_DN ** 2),
                              gain * level))


def quantile(values: FloatArray, q: float) -> float:
    """``float(np.quantile(values, q))`` of a non-empty (n,) float64 array (numpy's
    default, linear interpolation between the order statistics at (n - 1)·q, computed
    as numpy computes it) without np.quantile's overhead: one partition at the two
    order statistics. NaN in ``values`` is left to np.quantile."""
    n = values.size
    position = (n - 1) * q
    if position >= n - 1:
        low = high = n - 1
    else:
        low = math.floor(position)
        high = low + 1
    if np.isnan(values).any():
        return float(np.quantile(values, q))
    ordered = np.partition(values, (low, high))
    a, b = float(ordered[low]), float(ordered[high])
    gamma = position - low
    diff = b - a
    return b - diff * (1.0 - gamma) if gamma >= 0.5 else a + diff * gamma
