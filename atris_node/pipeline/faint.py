"""Faint returns: a line under the peak threshold in every column may still show as a
stripe when its columns are averaged along the line.

NO_RETURN says that no line meets anything within z_max in a sector. A line that meets
nothing in the obstacle-free scene (the upper sheets) earns that only where a return
would have stood out (:mod:`atris_node.pipeline.evidence`); a dark surface near z_max
returns less than the per-column threshold, and the sector read free while a wall stood
at 8.9 m of a 9.9 m range (random scene q9_073: the top sheet's stripe on the wall 8-10
DN over a noise σ of 2.5 DN, SNR 3-4 in each column). Averaged over FAINT_COLUMNS
columns such a stripe stands at 10 σ or more of the averaged noise, while noise alone
does not. So, only in a sector about to be published as NO_RETURN (nowhere else: the
pass is left out when no sector is free), every line with no sample in at least
FAINT_COLUMNS of its columns is looked for in the column-averaged map over its band:
where its maximum (away from every other line's samples) stands SCREEN_SIGMAS standard
deviations over the band's mean and FAINT_SIGMAS robust σ over its median in
``min_points`` or more columns, the sector is INVALID, not free. What stands there is
not known; it is not nothing.

Units: map values in DN (any integer or float dtype, read as float32); the averaged
profile's σ is 1.4826 × its median absolute deviation over the band's rows.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from atris_node.pipeline.bands import Band
from atris_node.pipeline.peaks import LineSamples, seen_lines

#: columns averaged along a line (a stripe's row changes slowly from column to column)
FAINT_COLUMNS = 9
#: a faint stripe's averaged maximum over the band's median, in robust σ of the band
FAINT_SIGMAS = 6.0
#: the cheap screen before it: the maximum over the profile's mean, in its std
SCREEN_SIGMAS = 4.0
#: rows around another line's sample left out of a band (its stripe is no faint return)
EXCLUDE_PX = 4

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]


def faint_columns(values: npt.NDArray[Any], band: Band, samples: LineSamples,
                  columns: IntArray) -> int:
    """How many of ``columns`` (sorted, line ``band.line`` has no sample in them) hold a
    faint stripe of that line (:func:`faint_mask`)."""
    return int(np.count_nonzero(faint_mask(values, band, samples, columns)))


def faint_mask(values: npt.NDArray[Any], band: Band, samples: LineSamples,
               columns: IntArray) -> BoolArray:
    """(n,) True where column ``columns[i]`` (sorted) holds a faint stripe of line
    ``band.line``: in the map averaged over FAINT_COLUMNS columns, a maximum within the
    band, at least EXCLUDE_PX rows from any other line's sample in the column,
    SCREEN_SIGMAS standard deviations over the band's mean and FAINT_SIGMAS robust σ
    over its median."""
    height, width = values.shape
    lo, hi = max(band.row_lo, 0), min(band.row_hi, height)
    out = np.zeros(columns.size, dtype=np.bool_)
    if hi - lo < 8 or columns.size < FAINT_COLUMNS:
        return out
    left, right = max(int(columns[0]) - FAINT_COLUMNS, 0), min(
        int(columns[-1]) + FAINT_COLUMNS + 1, width)
    block = np.asarray(values[lo:hi, left:right], dtype=np.float32)
    averaged = cv2.blur(block, (FAINT_COLUMNS, 1), borderType=cv2.BORDER_REFLECT)
    cols = columns - left
    profile = np.ascontiguousarray(averaged[:, cols].T)  # (columns, rows): rows contiguous
    other = _other_lines(samples, band.line, (lo, hi), (left, right))[:, cols].T
    peak = np.where(other, -np.inf, profile).max(axis=1)
    # the mean and standard deviation first (cheap): only columns whose maximum stands
    # out of them are tested against the median and MAD (a partition each)
    screen = (peak - profile.mean(axis=1)) >= SCREEN_SIGMAS * profile.std(axis=1)
    screen &= np.isfinite(peak)
    if not screen.any():
        return out
    chosen = profile[screen]
    median = np.median(chosen, axis=1)
    sigma = 1.4826 * np.median(np.abs(chosen - median[:, None]), axis=1)
    out[screen] = (peak[screen] - median) >= FAINT_SIGMAS * np.maximum(sigma, 1e-6)
    return out


def _other_lines(samples: LineSamples, line: int, rows: tuple[int, int],
                 cols: tuple[int, int]) -> BoolArray:
    """(rows, cols) mask of the block: True within EXCLUDE_PX rows of a sample of a line
    other than ``line`` in its column (or within FAINT_COLUMNS // 2 columns of it)."""
    lo, hi = rows
    left, right = cols
    mask = np.zeros((hi - lo, right - left), dtype=np.bool_)
    other = samples.line != line
    row = np.rint(samples.row_px[other]).astype(np.int64) - lo
    col = np.rint(samples.col_px[other]).astype(np.int64) - left
    keep = (col >= 0) & (col < right - left) & (row >= -EXCLUDE_PX) & (
        row < hi - lo + EXCLUDE_PX)
    half = FAINT_COLUMNS // 2
    for r, c in zip(row[keep], col[keep], strict=True):
        mask[max(r - EXCLUDE_PX, 0):max(r + EXCLUDE_PX + 1, 0),
             max(c - half, 0):c + half + 1] = True
    return mask


def faint_sectors(values: npt.NDArray[Any], bands: tuple[Band, ...],
                  samples: LineSamples, column_sector: IntArray, free: set[int],
                  min_points: int) -> set[int]:
    """The sectors of ``free`` (about to be NO_RETURN) in which a line with no sample
    shows a faint stripe in ``min_points`` or more columns (:func:`faint_mask`), each
    line's band averaged once over every free column; ``column_sector`` (W,) gives each
    column's sector (-1 outside). The map is not read when nothing is free."""
    if not free:
        return set()
    seen = seen_lines(samples, len(bands), column_sector.size)
    looked = np.isin(column_sector, sorted(free))
    counts = np.zeros(int(column_sector.max()) + 1, dtype=np.int64)
    for band in bands:
        if band.empty:
            continue
        columns = np.flatnonzero(looked & ~seen[band.line]).astype(np.int64)
        faint = faint_mask(values, band, samples, columns)
        counts += np.bincount(column_sector[columns[faint]], minlength=counts.size)
    return {int(s) for s in np.flatnonzero(counts >= min_points) if int(s) in free}
