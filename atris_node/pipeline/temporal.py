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
from numba import types

from atris_node.jit import kernel
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
    recording) or the code has no OFF sub-frame. The peak pixels, the OFF sub-frames'
    statistics and the test come from compiled passes
    (:func:`atris_node.pipeline.peaks_kernels.peak_pixels`, :func:`_series`,
    :func:`atris_node.pipeline.peaks_kernels.ambient_level`, :func:`_mark_not_own`)."""
    out = np.zeros(peaks.shape, dtype=bool)
    if window is None or not peaks.size or (
            window.gather is None and len(window.pixels) != len(window.signs)):
        return out
    m, c, flat, tile_sigma = peaks_kernels.peak_pixels(
        np.ascontiguousarray(peaks, dtype=np.int64), local.tile_row, local.sigma_tiles,
        NOISE_TILE_PX)
    if not m.size or min(window.signs) > 0:
        return out
    before = window.before
    test, norm = _test_weights(tuple(window.signs), None if before is None else before[0])
    series = window_series(window, flat)  # (n, P), DN
    level, gain = _ambient(series, window)
    _mark_not_own(out, m, c, test @ series, tile_sigma, level, gain,
                  math.sqrt(len(window.signs)), norm)
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


def window_series(window: WindowFrames, flat: IntArray) -> FloatArray:
    """(n, P) float64 the value of each frame of ``window`` (the OFF frame before it first,
    when there is one) at the flat pixel indices ``flat``, DN; from ``window.gather`` when
    its pixels are in another process."""
    if window.gather is not None:
        return window.gather(flat)
    before = window.before
    return _series(((before[1],) if before is not None else ()) + window.pixels, flat)


def _series(frames: tuple[npt.NDArray[Any], ...], flat: IntArray) -> FloatArray:
    """(n, P) float64 the value of each frame at the flat pixel indices ``flat``, DN: one
    compiled gather per uint8 or uint16 frame (:func:`_gather`, straight into the float64
    row: no gathered copy in the frame's dtype to convert), ``take`` for other dtypes."""
    out = np.empty((len(frames), flat.size), dtype=np.float64)
    index = np.ascontiguousarray(flat, dtype=np.int64)
    for i, frame in enumerate(frames):
        pixels = np.ravel(frame)
        if pixels.dtype in (np.uint8, np.uint16):
            _gather(pixels, index, out[i])
        else:
            out[i] = pixels.take(index)
    return out


def _gather_signatures() -> list[Any]:
    """Signatures of :func:`_gather`: a uint8 or uint16 frame, writable or read-only (a
    driver's buffer), contiguous (as ``np.ravel`` gives it)."""
    return [types.void(types.Array(dtype, 1, "C", readonly=readonly),
                       types.Array(types.int64, 1, "C"), types.Array(types.float64, 1, "C"))
            for dtype in (types.uint8, types.uint16) for readonly in (False, True)]


@kernel(_gather_signatures())
def _gather(pixels: npt.NDArray[Any], flat: IntArray, out: FloatArray) -> None:
    """``out[p] = pixels[flat[p]]`` (P,) as float64, DN, for the (H·W,) ``pixels`` of one
    frame (an index out of the frame raises IndexError, a negative one counts from the
    end, as ``take`` does)."""
    size = pixels.size
    for p in range(flat.size):
        i = flat[p] + size if flat[p] < 0 else flat[p]
        if i < 0 or i >= size:
            raise IndexError("a pixel index beyond the frame")
        out[p] = pixels[i]


def _ambient(series: FloatArray, window: WindowFrames) -> tuple[FloatArray, float]:
    """(P,) each peak pixel's ambient level, DN (at least 1), and the map's
    photon-transfer gain, DN² per DN (the SHOT_QUANTILE quantile of the OFF variance over
    the level): the level and the OFF variance over it in one compiled pass
    (:func:`atris_node.pipeline.peaks_kernels.ambient_level`)."""
    offs = np.array(_off_rows(tuple(window.signs), window.before is not None), dtype=np.int64)
    level, ratio = peaks_kernels.ambient_level(series, offs)
    return level, quantile(ratio, SHOT_QUANTILE)


#: the rounding's variance, DN² (computed here, in Python's arithmetic)
_QUANTIZATION_VAR = QUANTIZATION_DN ** 2


@kernel("float64(float64, float64)")
def _maximum(a: float, b: float) -> float:
    """``np.maximum`` of two floats: the first NaN, else the larger (``a`` when equal)."""
    return a if (a >= b or np.isnan(a)) else b


@kernel("void(boolean[:, ::1], int64[:], int64[:], float64[:], float32[:], float64[:], "
        "float64, float64, float64)")
def _mark_not_own(out: BoolArray, slot: IntArray, col: IntArray, statistic: FloatArray,
                  tile_sigma: npt.NDArray[np.float32], level: FloatArray, gain: float,
                  root_n: float, norm: float) -> None:
    """``out[slot[p], col[p]]`` (M, W) True where the peak pixel p's test ``statistic``
    (P,) lies under -LOCAL_SIGMAS·σ·``norm``. σ, DN per sub-frame, is the largest of the
    tile's (``tile_sigma`` (P,), σ of the map, over √N ``root_n``), the rounding's and
    the shot noise of the pixel's ``level`` (P,) at the map's ``gain``: the square root
    of ``np.maximum(np.maximum(tile², QUANTIZATION_DN²), gain·level)``, NaN kept as
    numpy's maximum keeps it."""
    for p in range(slot.size):
        tile = np.float64(tile_sigma[p]) / root_n
        sigma = np.sqrt(_maximum(_maximum(tile * tile, _QUANTIZATION_VAR), gain * level[p]))
        out[slot[p], col[p]] = statistic[p] < -LOCAL_SIGMAS * sigma * norm


@functools.lru_cache(maxsize=64)
def _off_rows(signs: tuple[int, ...], before: bool) -> tuple[int, ...]:
    """The rows of the series read (with the sub-frame ``before`` the window first, when
    read) that hold the window's OFF sub-frames. Kept per code and lag, as
    :func:`_test_weights`."""
    return tuple(i + int(before) for i, sign in enumerate(signs) if sign < 0)


def quantile(values: FloatArray, q: float) -> float:
    """``float(np.quantile(values, q))`` of a non-empty (n,) float64 array (numpy's
    default, linear interpolation between the order statistics at (n - 1)·q, computed
    as numpy computes it) without np.quantile's overhead: one partition at the upper of
    the two order statistics (the lower is the greatest value before it; a partition at
    both costs twice that at 4000 values). NaN in ``values`` is left to np.quantile."""
    n = values.size
    position = (n - 1) * q
    if position >= n - 1:
        low = high = n - 1
    else:
        low = math.floor(position)
        high = low + 1
    if np.isnan(values).any():
        return float(np.quantile(values, q))
    # one selection, at the upper statistic: the lower one is the greatest before it
    ordered = np.partition(values, high)
    b = float(ordered[high])
    a = b if low == high else float(ordered[:high].max())
    gamma = position - low
    diff = b - a
    return b - diff * (1.0 - gamma) if gamma >= 0.5 else a + diff * gamma
