"""Bright lines dimmed over a few columns: their rays partly blocked during the map.

A thin dark object crossing the lines' rays during a map's code window (a 5 cm black
pole crossing at 1 m/s moves 9 px in 16 sub-frames at 300 Hz) blocks each column's stripe
behind it for part of the window, and in part of its width: the stripes keep their rows
and lose half or more of their light over those columns, but no line has a hole for the
hole rules (:func:`atris_node.pipeline.verdicts.shadowed_columns`) to find, and the wall
behind the pole was read in its sector (4.79 m for a pole at 4.39 m). A sample of a
bright line (the upper quartile of its SNR within DIM_REACH columns on each side at
least DIM_BRIGHT·snr_min; a quartile, not the median, so that the dim's own columns on
one side do not hide it) whose SNR falls below DIM_FRACTION of both is dropped as
doubtful (never evidence of free space): its columns become the line's hole, and bright
lines stopping together over a few columns of one surface make the sector INVALID.

A dim wider than about DIM_REACH columns leaves one side's quartile inside it and is no
dim: a line crossing onto a darker surface, or a noise tile of another σ (the SNR is
against the tile's σ, tiles are 32 columns wide), changes its SNR over many more columns.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel, uncounted
from atris_node.pipeline.peaks import LineSamples

BoolArray = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: columns on each side whose samples give a line's SNR there (their upper quartile)
DIM_REACH = 16
#: samples needed on each side for a quartile
DIM_SIDE = 4
#: a dim is below this share of the line's SNR on both sides (a stripe's peak sample
#: falls to 0.73 of its maximum with its centre between two rows: no dim)
DIM_FRACTION = 0.6
#: both sides' SNR at least this many times snr_min (the hole rules' bright lines)
DIM_BRIGHT = 10.0


def dimmed(samples: LineSamples, lines: int, width: int, snr_min: float) -> BoolArray:
    """(n,) True at the samples that are dims of a bright line (module docstring)."""
    if not samples.line.size:
        return np.zeros(0, dtype=np.bool_)
    return np.asarray(_dimmed(
        np.ascontiguousarray(samples.line, dtype=np.int64),
        np.rint(samples.col_px).astype(np.int64), np.ascontiguousarray(samples.snr,
                                                                      dtype=np.float64),
        lines, width, DIM_REACH, DIM_SIDE, DIM_FRACTION, DIM_BRIGHT * snr_min))


def warm_up() -> None:
    """Type the kernel's arguments once (the first map does not wait for it)."""
    one = np.zeros(1, dtype=np.int64)
    _dimmed(one, one, np.ones(1), 1, 1, DIM_REACH, DIM_SIDE, DIM_FRACTION, 1.0)


def grid(samples: LineSamples, which: BoolArray, lines: int, width: int) -> BoolArray:
    """(K, W) True at the (line, column) of the ``which`` samples."""
    out = np.zeros((lines, width), dtype=np.bool_)
    col = np.rint(samples.col_px[which]).astype(np.int64)
    line = samples.line[which].astype(np.int64)
    inside = (line >= 0) & (line < lines) & (col >= 0) & (col < width)
    out[line[inside], col[inside]] = True
    return out


@uncounted
def _side_level(grid: FloatArray, k: int, start: int, stop: int, scratch: FloatArray,
                need: int) -> float:
    """The upper quartile (the value at rank floor(3(n - 1)/4) from the lowest) of the n
    finite values of ``grid[k, start:stop]`` (clipped to the row), sorted into
    ``scratch`` by insertion; NaN when n < ``need``."""
    n = 0
    for c in range(max(start, 0), min(stop, grid.shape[1])):
        value = grid[k, c]
        if not np.isfinite(value):
            continue
        j = n
        while j > 0 and scratch[j - 1] > value:
            scratch[j] = scratch[j - 1]
            j -= 1
        scratch[j] = value
        n += 1
    if n < need:
        return np.nan
    return scratch[(3 * (n - 1)) // 4]


@uncounted
def _window_max(grid: FloatArray, k: int, c: int, reach: int) -> float:
    """The largest finite value of ``grid[k]`` within ``reach`` columns of c, c left
    out (-inf: none)."""
    top = -np.inf
    for j in range(max(c - reach, 0), min(c + reach + 1, grid.shape[1])):
        if j != c and grid[k, j] > top:  # False for NaN
            top = grid[k, j]
    return top


@kernel()
def _dimmed(line: IntArray, column: IntArray, snr: FloatArray, lines: int, width: int,
            reach: int, need: int, fraction: float, bright: float) -> BoolArray:
    """(n,) the dims among the samples (``line``, ``column``, ``snr``; (n,) each) of
    ``lines`` lines over ``width`` columns: SNR below ``fraction`` of the upper quartile
    of the line's samples' SNR within ``reach`` columns on each side (``need`` of them at
    least), both ``bright`` or more. Columns outside [0, width) or lines outside
    [0, lines) are no dims. A sample at ``fraction`` of the largest SNR beside it or more
    is none either (no quartile is larger): the quartiles are taken only below that."""
    grid = np.full((lines, width), np.nan)
    most = np.full(lines, -np.inf)  # each line's largest SNR
    for i in range(line.size):
        if 0 <= line[i] < lines and 0 <= column[i] < width:
            grid[line[i], column[i]] = snr[i]
            most[line[i]] = max(most[line[i]], snr[i])
    scratch = np.empty(reach)
    out = np.zeros(line.size, dtype=np.bool_)
    for i in range(line.size):
        k, c = line[i], column[i]
        if not (0 <= k < lines and 0 <= c < width) or not snr[i] < fraction * most[k]:
            continue
        top = _window_max(grid, k, c, reach)
        if not (top >= bright and snr[i] < fraction * top):
            continue
        left = _side_level(grid, k, c - reach, c, scratch, need)
        right = _side_level(grid, k, c + 1, c + 1 + reach, scratch, need)
        if left >= bright and right >= bright:  # False where a side is NaN
            out[i] = snr[i] < fraction * min(left, right)
    return out
