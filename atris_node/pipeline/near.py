"""Stripes nearer than the operating range: the rows above every band.

Line k's stripe from a surface at camera z lies on row ``u = f·cot α_k - f·b/z``
(:mod:`atris_node.pipeline.geometry`), which rises in the image as z falls. Nearer than
z_min every line leaves its band on the image's top side: its stripe lands in the band of
a line above it, where it is read as that line farther away (a dark sphere whose near side
is 0.15 m from the unit, met 0.24-0.27 m away by both sheets: the lower sheet's saturated
stripe read 0.48 m in four sectors), or, for the topmost line, above every band, where no
band is read. Nothing within or beyond the operating range puts a stripe above the
topmost band (that would take a negative range), so a stripe there is the sign of a
surface nearer than z_min, and the lines below it may be read off by one or more.

The *near guard* reads those rows, ``[0, topmost band's first row - read padding)``, with
their own noise statistics, and keeps the maxima that are a stripe of own light: one that
continues into its neighbouring columns (:func:`atris_node.pipeline.rivals.stripe_peaks`),
whose time course can be own light (:func:`atris_node.pipeline.temporal.not_own_light`),
that stands above both sides of its column (no step's edge,
:func:`atris_node.pipeline.peaks.one_sided`), and that is bright enough for the range the
topmost line gives it (an apparent reflectance of at least ``min_reflectance``,
:mod:`atris_node.pipeline.radiometry`, from the map's value, clipped or not: a sky that
saturates leaves residues there that are no light of the unit's). Kept only in runs of
NEAR_RUN columns or more (a surface that near spans many columns; the residue of a lamp
a few). The chain keeps them as
doubts at the topmost line's range (:class:`atris_node.pipeline.peaks.Extraction`
``doubts``) and as doubtful peaks in their columns: a sector they look into is neither
VALID nor free.

Left out where the topmost band reaches the image's top (no row above it to read, the
guard is empty: :func:`guard_span` is None).

Units: rows and columns in pixels of the map, DN for values, m for ranges.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.pipeline import radiometry
from atris_node.pipeline.bands import Band
from atris_node.pipeline.geometry import triangulate_pixels
from atris_node.pipeline.noise import NoiseMap, noise_map
from atris_node.pipeline.peaks import (
    ExtractorSettings,
    one_sided,
    read_padding,
    saturation_mask,
    strong_maxima,
    true_runs,
)
from atris_node.pipeline.rivals import set_aside, stripe_peaks
from atris_node.pipeline.temporal import not_own_light
from atris_node.types import WindowFrames

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

#: columns a run of near stripes must span (a surface within 0.3 m of a camera of 340 px
#: focal length spans 11 columns per centimetre of its width)
NEAR_RUN = 10
#: maxima looked at per column of the guard (a line and the one below it)
NEAR_PEAKS = 2
#: fewest guard rows worth reading (one noise tile's statistics need some)
GUARD_MIN_ROWS = 4

_NONE = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))


def topmost(bands: tuple[Band, ...]) -> Band | None:
    """The band nearest the image's top (smallest first row), None when every band is
    empty."""
    shown = [b for b in bands if not b.empty]
    return min(shown, key=lambda b: b.row_lo) if shown else None


def guard_span(bands: tuple[Band, ...], settings: ExtractorSettings) -> tuple[int, int] | None:
    """Rows ``[0, hi)`` above every band and its read padding: where only a surface
    nearer than z_min puts a stripe; None when fewer than GUARD_MIN_ROWS."""
    top = topmost(bands)
    if top is None:
        return None
    hi = top.row_lo - read_padding(settings)
    return (0, hi) if hi >= GUARD_MIN_ROWS else None


def near_stripes(values: npt.NDArray[Any], saturated: BoolArray, bands: tuple[Band, ...],
                 settings: ExtractorSettings, camera: CameraModel, laser: LaserCalibration,
                 *, code_length: int, exposure_us: float | None, min_reflectance: float,
                 window: WindowFrames | None = None) -> tuple[IntArray, IntArray]:
    """(rows, columns) (n,) int64 of the own-light stripes in the near guard (module
    docstring) that run over NEAR_RUN columns or more; empty when the guard is.
    ``values`` (H, W) the map (DN), ``saturated`` its (H, W) mask, ``window`` its raw
    sub-frames (None: the time course is not looked at); ``min_reflectance`` 0 or an
    uncalibrated ``laser``: brightness is not looked at."""
    span = guard_span(bands, settings)
    top = topmost(bands)
    if span is None or top is None:
        return _NONE
    local = noise_map(values, [span])
    peaks = strong_maxima(values, [span], local, settings.snr_min,
                          settings.min_separation_px, NEAR_PEAKS)
    # a maximum on the guard's last rows may be the flank of a stripe inside the band
    peaks = np.where(peaks >= span[1] - settings.min_separation_px, -1, peaks)
    peaks, _ = stripe_peaks(peaks)
    peaks, _ = set_aside(peaks, not_own_light(peaks, window, local))
    peaks, _ = set_aside(peaks, one_sided(values, saturation_mask(saturated), peaks, local,
                                          settings))
    slot, col = np.nonzero(peaks >= 0)
    row = peaks[slot, col]
    bright = _bright_enough(values, local, row, col, top.line, camera, laser,
                            code_length, exposure_us, min_reflectance)
    row, col = row[bright], col[bright]
    keep = _in_long_runs(col, values.shape[1], NEAR_RUN)
    return row[keep].astype(np.int64), col[keep].astype(np.int64)


def _bright_enough(values: npt.NDArray[Any], local: NoiseMap, row: IntArray,
                   col: IntArray, line: int, camera: CameraModel, laser: LaserCalibration,
                   code_length: int, exposure_us: float | None,
                   min_reflectance: float) -> BoolArray:
    """(n,) True for the peaks at (``row``, ``col``) that, as ``line`` (the topmost: the
    farthest range any line gives a row above its band), stand for an apparent
    reflectance of ``min_reflectance`` or more (the peak over its ``local`` background; a
    saturated peak by its clipped value: a lower bound); all True when brightness is not
    looked at, False where the line gives no range."""
    points = triangulate_pixels(row.astype(np.float64), col.astype(np.float64),
                                np.full(row.size, line, dtype=np.int64), camera, laser,
                                z_max_m=np.inf)
    if min_reflectance <= 0.0 or not radiometry.calibrated(laser) or not row.size:
        return np.asarray(points.valid, dtype=np.bool_)
    peak = radiometry.sample_peaks(values, row.astype(np.float64), col.astype(np.float64),
                                   local)
    reflectance = radiometry.apparent_reflectance(
        peak, radiometry.source_range_m(points, laser), code_length, laser, exposure_us)
    return np.asarray(points.valid & (reflectance >= min_reflectance), dtype=np.bool_)


def _in_long_runs(col: IntArray, width: int, run: int) -> BoolArray:
    """(n,) True for the entries of ``col`` whose column lies in a run of ``run`` or more
    adjacent columns that all hold an entry."""
    held = np.zeros(width, dtype=np.bool_)
    held[col] = True
    long = np.zeros(width, dtype=np.bool_)
    for start, stop in true_runs(held):
        if stop - start >= run:
            long[start:stop] = True
    return long[col]
