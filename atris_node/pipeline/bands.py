"""Row bands: the rows of the distortion map where each projected line can appear.

A projected line k can only be imaged between its rows at ``z_min`` and ``z_max``
(``u = f·cot α_k - f·b/z``, see :mod:`atris_node.pipeline.geometry`), widened by the lens
distortion and a margin: its *band*. Rows outside every band are never read
(:func:`read_rows`); the peaks of :mod:`atris_node.pipeline.peaks` are looked for inside them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.pipeline import peaks_kernels
from atris_node.pipeline.geometry import distort_pixels, line_row_at_range

IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Band:
    """Rows ``[row_lo, row_hi)`` of the observed image where line ``line`` can appear."""

    line: int
    row_lo: int
    row_hi: int

    @property
    def empty(self) -> bool:
        """True when the band lies entirely outside the image."""
        return self.row_hi <= self.row_lo


def _band(line: int, u_px: tuple[float, float], camera: CameraModel,
          margin_px: float) -> Band:
    """Observed rows of the undistorted row interval ``u_px`` (px from cy) of one line,
    through the distortion at 17 columns; empty when the interval misses the image by
    more than half its height (lines of α near 0 or π)."""
    h, cy = camera.height_px, camera.cy_px
    lo_u, hi_u = min(u_px) + cy, max(u_px) + cy
    if hi_u < -h / 2 or lo_u > 1.5 * h:
        return Band(line, 0, 0)
    cols = np.linspace(0.0, camera.width_px - 1.0, 17)
    rows = np.concatenate([distort_pixels(np.full_like(cols, r), cols, camera)[0]
                           for r in np.clip([lo_u, hi_u], -h / 2, 1.5 * h)])
    lo = max(int(np.floor(rows.min() - margin_px)), 0)
    hi = min(int(np.ceil(rows.max() + margin_px)) + 1, h)
    return Band(line, lo, max(hi, lo))


def line_bands(camera: CameraModel, laser: LaserCalibration, z_min_m: float,
               z_max_m: float, margin_px: float) -> tuple[Band, ...]:
    """Observed row band of every line for ranges ``[z_min_m, z_max_m]``.

    The band edges are the rows ``u = f·cot α_k - f·b/z`` at z_min and z_max, pushed
    through the lens distortion, widened by ``margin_px`` and clipped to the image.
    """
    return tuple(_band(k, (line_row_at_range(k, z_min_m, camera, laser),
                           line_row_at_range(k, z_max_m, camera, laser)), camera, margin_px)
                 for k in range(len(laser.alpha_rad)))


def read_rows(bands: tuple[Band, ...], pad: int, height: int) -> list[tuple[int, int]]:
    """Merged row intervals ``[lo, hi)`` covering every band plus ``pad`` rows each side."""
    spans = sorted((max(b.row_lo - pad, 0), min(b.row_hi + pad, height))
                   for b in bands if not b.empty)
    merged: list[tuple[int, int]] = []
    for lo, hi in spans:
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged


def in_image_order(bands: tuple[Band, ...]) -> tuple[IntArray, IntArray, IntArray]:
    """(K,) ``row_lo``, ``row_hi`` and line of the bands, top of the image first."""
    ordered = sorted(bands, key=lambda b: b.row_lo + b.row_hi)
    return (np.array([b.row_lo for b in ordered], dtype=np.int64),
            np.array([b.row_hi for b in ordered], dtype=np.int64),
            np.array([b.line for b in ordered], dtype=np.int64))



def image_positions(order: IntArray) -> IntArray:
    """(K,) each line's position from the top of the image (0 = top), from the (K,) lines
    in image ``order`` (the third array of :func:`in_image_order`)."""
    position = np.empty(order.size, dtype=np.int64)
    position[order] = np.arange(order.size)
    return position

def count_in_bands(peaks: IntArray, bands: tuple[Band, ...]) -> IntArray:
    """(W,) entries of (M, W) ``peaks`` (rows, -1 = none) inside at least one band, looked
    up in a table of the rows some band covers (its last entry, for -1 and for rows
    below every band, False); counted in one compiled pass
    (:func:`atris_node.pipeline.peaks_kernels.covered_per_column`)."""
    top = max((b.row_hi for b in bands), default=0)
    covered = np.zeros(top + 1, dtype=np.bool_)
    for b in bands:
        covered[b.row_lo:max(b.row_hi, b.row_lo)] = True
    return peaks_kernels.covered_per_column(np.ascontiguousarray(peaks, dtype=np.int64),
                                            covered)
