"""Returns too faint for their range: the brightness of a stripe checks its identity.

A surface of albedo ρ lit at incidence i from r metres returns ``D · ρ · cos i / r²`` DN
per sub-frame the laser is on (Lambertian; D the line's radiometric calibration,
:attr:`atris_node.calibration.LaserCalibration.return_dn_m2`, scaled to the exposure), and
a map sums N/2 such sub-frames. So the peak A (DN) of a sample at range r stands for an
*apparent reflectance* ``ρ cos i = A · r² / (N/2 · D)``. A shifted line identity reads a
far surface's stripe at a near range, where the same peak stands for a surface
(r_far / r_near)² times darker: a dark wall at 7.6 m (ρ 0.12) whose upper stripes were
taken three lines low read 0.31 m, an apparent reflectance of 0.0012, which no surface
there has (edge_on_glossy_plate_dark_wall). Whatever stands at a range returns at least
MIN_REFLECTANCE (black velvet, ρ ≈ 0.02, lit at 84°): a sample under it is not at the
range its identity gives. It is dropped and kept as a doubt at that range, with every
other sample of its column (:func:`whole_columns`): its line is wrong, the column's comb
with it, and which line is right is not known (a sector cannot be VALID farther than the
doubts, nor free).

Measured on the shipped and stress scenes (seed 1, two maps each, 168,876 valid
samples): the correctly identified samples stand for 0.0068 at their 0.1 % quantile and
none under 0.0028 (a turned dark wall at 7.6 m lit at a grazing angle), while 75 of the
4,166 misidentified ones stand under 0.002 (0.0004-0.0012 for the near phantoms of
edge_on_glossy_plate_dark_wall and retro_pole_stray_stripe). Brightness tells only large
range ratios: a wall at 1.6 m read at 1.0 m is 2.6 times darker, well within the spread
of albedos, and passes.

Left out: saturated samples (their peak is clipped; a clipped peak is bright), a map
without a calibrated D (``return_dn_m2`` 0: nothing to compare with), and
``min_reflectance`` 0. The peak is the larger of the two map pixels around the
sub-pixel row (a stripe centred between two rows spreads over both), over the local
background the peaks were found against: light the code does not cancel leaves a
pedestal of either sign (flicker_100hz's second map lies 590 DN below 0), which would
otherwise lend a faint return a near surface's brightness or take a bright one's away.
Vignetting and haze, which the model leaves out, only make returns fainter: a sample
near the edge of the image or in fog may be dropped that should not be (INVALID, not
wrong).

Units: DN for map values, m for ranges, µs for exposures; float64 throughout; no inf or
NaN leaves (a point at the projector, r = 0, cannot occur: a valid point lies beyond
z_min > 0).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node.calibration import LaserCalibration
from atris_node.pipeline import radiometry_kernels
from atris_node.pipeline.geometry import Points
from atris_node.pipeline.noise import NoiseMap
from atris_node.pipeline.peaks import LineSamples

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: ρ cos i: the faintest surface taken at face value (albedo 0.02 lit at 84°)
MIN_REFLECTANCE = 0.002
#: ρ cos i: the faintest surface taken for a sample whose line continuity chose over
#: farther rivals the physics could not rule out (``Identity.tied``: its nearest
#: hypothesis): about the 0.1 % quantile of the correctly identified samples (0.0068)
TIED_REFLECTANCE = 0.007


def calibrated(laser: LaserCalibration) -> bool:
    """True when the lines have a radiometric calibration to compare peaks with."""
    return laser.return_dn_m2 > 0.0


def sample_peaks(values: npt.NDArray[Any], row_px: FloatArray, col_px: FloatArray,
                 local: NoiseMap | None = None) -> FloatArray:
    """(n,) float64 peak DN of each sample at (``row_px``, ``col_px``) (n,): the larger of
    the map pixels on the rows around its sub-pixel row, in its column (clipped to the
    image), over the ``local`` background there (None: over 0)."""
    height, width = values.shape
    row = np.clip(np.floor(row_px).astype(np.int64), 0, height - 1)
    col = np.clip(np.rint(col_px).astype(np.int64), 0, width - 1)
    below = np.minimum(row + 1, height - 1)
    peak = np.maximum(values[row, col], values[below, col]).astype(np.float64)
    return peak if local is None else peak - local.background_at(row_px, col_px)


def source_range_m(points: Points, laser: LaserCalibration) -> FloatArray:
    """(n,) distance (m) from the projector, at (0, -b, 0) in the camera frame (Eq. 1's
    sheets ``y = z·cot α − b``), to each point."""
    xyz = points.xyz_m.reshape(-1, 3)
    return np.sqrt(xyz[:, 0] ** 2 + (xyz[:, 1] + laser.baseline_m) ** 2 + xyz[:, 2] ** 2)


def _per_map_dn_m2(code_length: int, laser: LaserCalibration, exposure_us: float | None
                   ) -> float:
    """N/2 · D at ``exposure_us`` (None: the calibration's own): what a map of
    ``code_length`` sub-frames holds, in DN·m², of a white surface facing the unit."""
    exposure = laser.return_exposure_us if exposure_us is None else exposure_us
    return 0.5 * code_length * laser.return_dn_m2 * exposure / laser.return_exposure_us


def apparent_reflectance(peak_dn: FloatArray, range_m: FloatArray, code_length: int,
                         laser: LaserCalibration, exposure_us: float | None) -> FloatArray:
    """(n,) ρ cos i that a peak of ``peak_dn`` (DN, summed over a map of ``code_length``
    sub-frames) stands for at ``range_m`` (m, > 0), with the calibration scaled to
    ``exposure_us`` (None: the calibration's own). A negative peak gives 0."""
    return np.maximum(peak_dn, 0.0) * range_m**2 / _per_map_dn_m2(code_length, laser,
                                                                   exposure_us)


def too_faint(values: npt.NDArray[Any], samples: LineSamples, points: Points,
              code_length: int, laser: LaserCalibration, exposure_us: float | None,
              min_reflectance: float = MIN_REFLECTANCE,
              stricter: tuple[float, BoolArray] | None = None,
              local: NoiseMap | None = None) -> BoolArray:
    """(n,) True for the valid, unsaturated samples whose peak (:func:`sample_peaks`)
    stands for an apparent reflectance (:func:`apparent_reflectance` at
    :func:`source_range_m`) under ``min_reflectance`` at the range their line gives, or,
    for the samples ``stricter`` = (reflectance, which (n,)) names, under the larger of
    the two; all False when the check is left out (no calibration, both floors 0, no
    sample). The peak is over the ``local`` background the peaks were found against
    (None: over 0). One compiled pass (:func:`radiometry_kernels.too_faint`); the numpy
    functions above are its reference and the calibration's."""
    out = np.zeros(len(samples), dtype=np.bool_)
    floor = np.full(len(samples), max(float(min_reflectance), 0.0))
    if stricter is not None:
        floor[stricter[1]] = np.maximum(floor[stricter[1]], float(stricter[0]))
    test = points.valid & ~samples.saturated & (floor > 0.0)
    if not calibrated(laser) or not test.any():
        return out
    row = np.ascontiguousarray(samples.row_px, dtype=np.float64)
    col = np.ascontiguousarray(samples.col_px, dtype=np.float64)
    background = np.zeros(row.size) if local is None else local.background_at(row, col)
    radiometry_kernels.too_faint(
        values, row, col, background, np.ascontiguousarray(test),
        np.ascontiguousarray(points.xyz_m.reshape(-1, 3), dtype=np.float64),
        float(laser.baseline_m), _per_map_dn_m2(code_length, laser, exposure_us), floor, out)
    return out


def whole_columns(col_px: FloatArray, faint: BoolArray) -> BoolArray:
    """(n,) True for every sample in a column (``col_px`` (n,)) that holds a ``faint``
    one. A column's lines are identified together (one comb per column): a stripe too
    faint for its line's range shows the comb taken lines off, and its neighbours in the
    column are off with it, however bright they look at their ranges (the dark wall's
    stripe read at 0.31 m came with another read at 0.94 m, bright enough there). ``faint``
    itself when none is."""
    if not faint.any():
        return faint
    cols = col_px.astype(np.int64)
    return np.isin(cols, cols[faint])
