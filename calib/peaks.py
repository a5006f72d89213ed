"""Per-column sub-pixel line rows on a distortion map, for calibration captures.

Calibration cannot use the pipeline's line bands (they come from the calibration), so
each column is searched over its full height: the ``count`` strongest maxima at least
``separation_px`` apart, each above ``snr_min`` robust noise floors, refined to a
sub-pixel row by the 3-point Gaussian (parabola through the logarithms). A column where
fewer than ``count`` lines stand out is marked invalid for every line, so the index k
(top of the image first) always means the same projected line. Lines are continuous
across columns while glints and speckle are not: a column in which any line's row is more
than ``max_jump_px`` from the running median of its neighbours, or whose neighbourhood is
mostly invalid, is dropped as well.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.errors import CalibrationError

logger = logging.getLogger(__name__)

#: columns over which a line's running median row is taken (glint rejection)
CONTINUITY_WINDOW = 31
CONTINUITY_PASSES = 2


@dataclass(frozen=True)
class LineRows:
    """Line rows per column: ``rows`` (K, W) float64 absolute image rows in pixels (0.0
    where not valid) and ``valid`` (K, W) bool."""

    rows: npt.NDArray[np.float64]
    valid: npt.NDArray[np.bool_]

    @property
    def line_count(self) -> int:
        """K, the number of lines."""
        return int(self.rows.shape[0])


def noise_sigma(values: npt.NDArray[np.generic]) -> float:
    """Robust noise standard deviation of a map (1.4826·MAD), in its units; at least 1."""
    flat = np.asarray(values, dtype=np.float64).ravel()[::7]
    return max(1.4826 * float(np.median(np.abs(flat - np.median(flat)))), 1.0)


def _strongest_rows(values: npt.NDArray[np.float64], count: int,
                    separation_px: int) -> npt.NDArray[np.int64]:
    """(count, W) rows of the ``count`` strongest maxima per column, ``separation_px`` apart."""
    work = values.copy()
    height = work.shape[0]
    found = np.zeros((count, work.shape[1]), dtype=np.int64)
    columns = np.arange(work.shape[1])
    for k in range(count):
        found[k] = np.argmax(work, axis=0)
        for offset in range(-separation_px, separation_px + 1):
            work[np.clip(found[k] + offset, 0, height - 1), columns] = -np.inf
    return found


def _gaussian_offset(values: npt.NDArray[np.float64], rows: npt.NDArray[np.int64]
                     ) -> npt.NDArray[np.float64]:
    """Sub-pixel offset in (-0.5, 0.5) of each maximum at ``rows`` (K, W)."""
    columns = np.broadcast_to(np.arange(values.shape[1]), rows.shape)
    inner = np.clip(rows, 1, values.shape[0] - 2)
    logs = [np.log(np.maximum(values[inner + d, columns], 1e-3)) for d in (-1, 0, 1)]
    denominator = logs[0] - 2.0 * logs[1] + logs[2]
    safe = np.where(denominator < -1e-9, denominator, -1.0)
    offset = np.where(denominator < -1e-9, 0.5 * (logs[0] - logs[2]) / safe, 0.0)
    return inner - rows + np.clip(offset, -0.5, 0.5)


def _continuous(rows: npt.NDArray[np.float64], valid: npt.NDArray[np.bool_],
                max_jump_px: float, window: int = CONTINUITY_WINDOW) -> npt.NDArray[np.bool_]:
    """(W,) True for columns where every line is within ``max_jump_px`` of its running
    median over ``window`` columns, and more than half of that window is valid."""
    if not valid.any():
        return np.zeros(rows.shape[1], dtype=bool)
    half = window // 2
    padded = np.pad(np.where(valid, rows, np.nan), ((0, 0), (half, half)),
                    constant_values=np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(padded, window, axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows: no neighbours
        median = np.nanmedian(windows, axis=-1)
    close = np.abs(np.nan_to_num(rows - median, nan=np.inf)) <= max_jump_px
    supported = np.all(np.isfinite(windows), axis=0).mean(axis=-1) > 0.5
    return np.all(close & valid, axis=0) & supported


def find_line_rows(distortion_map: npt.NDArray[np.generic], count: int,
                   separation_px: int = 6, snr_min: float = 8.0,
                   max_jump_px: float = 2.0) -> LineRows:
    """The rows of ``count`` lines in each column of a (H, W) distortion map (DN)."""
    values = np.asarray(distortion_map, dtype=np.float64)
    if values.ndim != 2 or count < 1:
        raise CalibrationError(f"need a (H, W) distortion map and at least one line, got "
                               f"shape {values.shape} and count {count}")
    rows = _strongest_rows(values, count, separation_px)
    columns = np.broadcast_to(np.arange(values.shape[1]), rows.shape)
    strong = values[rows, columns] > snr_min * noise_sigma(values)
    refined = rows + _gaussian_offset(values, rows)
    order = np.argsort(refined, axis=0)
    refined = np.take_along_axis(refined, order, axis=0)
    valid = np.broadcast_to(np.all(strong, axis=0), rows.shape).copy()
    for _ in range(CONTINUITY_PASSES):  # the second pass drops islands left by the first
        valid &= _continuous(refined, valid, max_jump_px)[None, :]
    logger.debug("%d of %d columns show all %d lines", int(valid[0].sum()), values.shape[1],
                 count)
    return LineRows(np.where(valid, refined, 0.0), valid)
