"""Whether a peak's time course over the window can be the unit's own strobed light.

The map holds ``D = sum_i s_i F_i``. Ambient light that stays constant over the window
cancels; ambient light that changes linearly does not when the code correlates with time
(``sum_i s_i t_i != 0``, true of every Walsh row). An intensity edge of the scene that moves
during the window (the top of an approaching car against the sky) changes its pixels
almost linearly, and its residual in ``D`` is a sharp stripe as strong as a line: it can
complete a comb one line off (docs/pipeline.md "Moving edges").

Fitting each pixel's time course with a linear trend beside the code separates the two.
With centred times ``w_i = 2i - (N - 1)`` and ``beta = (sum s_i w_i) / (sum w_i^2)``, the
de-trended sum ``D' = sum_i (s_i - beta w_i) F_i`` is zero for any linear change and
``sum_(i ON) (1 - beta w_i) L_i`` for own light ``L_i >= 0`` on the ON sub-frames (OFF
ones dark), whatever its course (a moving stripe included). So own light always has
``D' >= g D`` with ``g = min_(i ON) (1 - beta w_i)``, the code's *trend margin*. A peak with
``D' < g D - TREND_SIGMAS * sigma'`` cannot be own light; it is set aside (counted as
doubtful in its column, so the column is not evidence of anything).

``g`` depends on the code: 0.82 for the alternating Walsh row of N = 16, but negative for
rows whose ON chips bunch at one end (the half-ON, half-OFF row): those codes cannot tell
a linear change from their own light, and the check is not run for them (``g <=
MIN_TREND_MARGIN``). Noise: ``sigma' = sigma_D * sqrt(sum (s_i - beta w_i)^2 / N)`` from
the tile's background σ of ``D`` (shot noise of a bright line is not added: the margin
``D' - g D`` of static own light is ``(1 - rho^2 - g) D``, far above it).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from atris_node.pipeline.noise import NOISE_TILE_PX, NoiseMap
from atris_node.types import WindowFrames

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

#: a peak is set aside when D' is this many σ' below the least own light can give
TREND_SIGMAS = 4.0
#: chi-square margin (in its standard deviations) of the OFF sub-frames' departure from a line
OFF_SIGMAS = 8.0
#: quantile of the peaks' OFF variance / level ratios taken as the map's shot-noise gain
SHOT_QUANTILE = 0.25
#: σ of rounding a pixel to whole DN: no pixel is less noisy (a dark tile's σ of the sum,
#: from quantised values, can come out below it)
QUANTIZATION_DN = 1.0 / math.sqrt(12.0)
#: the OFF sub-frames' residual must also reach this share of the peak's sum (root of the
#: squared residual against the sum): the tile's σ underestimates a bright pixel's own
#: shot noise, while ambient light that made the peak departs by a large part of it
OFF_SHARE = 0.25
#: codes with a trend margin g at or below this cannot tell a moving edge from own light
MIN_TREND_MARGIN = 0.25


def trend_weights(signs: tuple[int, ...]) -> tuple[npt.NDArray[np.float64], float, float]:
    """(N,) de-trended weights ``s_i - beta w_i``, the trend margin ``g`` and the noise
    factor ``sqrt(sum (s_i - beta w_i)^2 / N)`` of a window's signs (oldest first)."""
    s = np.asarray(signs, dtype=np.float64)
    n = s.size
    w = 2.0 * np.arange(n, dtype=np.float64) - (n - 1)
    beta = float(s @ w) / float(w @ w) if n > 1 else 0.0
    weights = s - beta * w
    on = s > 0
    margin = float((1.0 - beta * w[on]).min()) if on.any() else 0.0
    return weights, margin, math.sqrt(float(weights @ weights) / max(n, 1))


def off_projection(signs: tuple[int, ...], before: int | None = None
                   ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64] | None]:
    """(N,) mask of the window's OFF sub-frames and the (n, n) projection that leaves the
    part of their values a straight line in time does not explain (None when n < 3:
    nothing left to test). With ``before`` (the time of the last OFF sub-frame before the
    window, < 0), that sub-frame is the first of the n."""
    off = np.asarray(signs) < 0
    t = np.flatnonzero(off).astype(np.float64)
    if before is not None:
        t = np.concatenate([[float(before)], t])
    n = t.size
    if n < 3:
        return off, None
    design = np.stack([np.ones(n), t - t.mean()], axis=1)
    projection = np.eye(n) - design @ np.linalg.pinv(design)
    return off, projection


def not_own_light(peaks: IntArray, values: npt.NDArray[np.generic], window: WindowFrames | None,
                  local: NoiseMap, sigmas: float = TREND_SIGMAS) -> BoolArray:
    """(M, W) True for the peaks (rows, -1 padding) whose time course is not own light:
    the OFF sub-frames are not ambient light changing at most linearly, or the de-trended
    sum is below what own light gives.

    All False when the map has no window (read back from a recording); the de-trended
    test is left out for codes whose trend margin is too small to tell (module docstring).
    """
    out = np.zeros(peaks.shape, dtype=bool)
    if window is None or len(window.pixels) != len(window.signs) or not peaks.size:
        return out
    m, c = np.nonzero(peaks >= 0)
    if not m.size:
        return out
    r = peaks[m, c]
    series = np.stack([frame[r, c] for frame in window.pixels]).astype(np.float64)  # (N, P)
    tile_row, tile_col = local.tile_row[r], c // NOISE_TILE_PX
    sigma_sum = local.sigma_tiles[tile_row, tile_col].astype(np.float64)  # σ of D, DN
    summed = values[r, c].astype(np.float64) - local.background_tiles[tile_row, tile_col]
    out[m, c] = _ambient_not_linear(series, window, r, c, summed, sigma_sum)
    weights, margin, noise = trend_weights(window.signs)
    if margin > MIN_TREND_MARGIN:
        below = weights @ series < margin * np.maximum(summed, 0.0) - sigmas * noise * sigma_sum
        out[m, c] |= below
    return out


def _off_residual(series: npt.NDArray[np.float64], window: WindowFrames, r: IntArray,
                  c: IntArray) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], int]:
    """(P,) squared residual of the OFF sub-frames (with the last one before the window
    when known) about a straight line in time, (P,) their mean level (DN), and the degrees
    of freedom (0: nothing to test)."""
    before = window.before
    off, projection = off_projection(window.signs, None if before is None else before[0])
    if projection is None:
        return np.zeros(series.shape[1]), np.zeros(series.shape[1]), 0
    ambient = series[off]
    if before is not None:
        ambient = np.concatenate([before[1][r, c][None, :].astype(np.float64), ambient])
    residual = projection @ ambient
    return (residual * residual).sum(axis=0), ambient.mean(axis=0), projection.shape[0] - 2


def _ambient_not_linear(series: npt.NDArray[np.float64], window: WindowFrames, r: IntArray,
                        c: IntArray, summed: npt.NDArray[np.float64],
                        sigma_sum: npt.NDArray[np.float64]) -> BoolArray:
    """(P,) True where the OFF sub-frames (no own light) depart from a straight line in
    time: their squared residual is above the noise bound ``dof + OFF_SIGMAS * sqrt(2
    dof)`` times the pixel's variance, and above ``(OFF_SHARE * D)^2``.

    The pixel's variance is the largest of the tile's (σ of D over N), the rounding's and
    the shot noise of its own level: ``shot_gain * level``, with the gain (DN² per DN) the
    lower quartile of the ratios of the peaks' OFF variance to their level in this map (a
    photon transfer estimate that holds while at least a quarter of the peaks are lines or
    noise on still ambient). The sub-frame before the
    window is what tells ambient light that dropped right after an ON first sub-frame
    from own light seen on that sub-frame alone."""
    squared, level, dof = _off_residual(series, window, r, c)
    if dof < 1:
        return np.zeros(series.shape[1], dtype=bool)
    level = np.maximum(level, 1.0)
    shot_gain = float(np.quantile(squared / dof / level, SHOT_QUANTILE))
    variance = np.maximum.reduce([np.square(sigma_sum) / len(window.signs),
                                  np.full_like(level, QUANTIZATION_DN ** 2),
                                  shot_gain * level])
    limit = np.maximum((dof + OFF_SIGMAS * math.sqrt(2.0 * dof)) * variance,
                       np.square(OFF_SHARE * summed))
    return np.asarray(squared > limit)
