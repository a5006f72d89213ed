"""The lines' radiometric calibration from a white target at a known distance.

A flat target of albedo ρ facing the unit at ``distance_m`` is captured as one
distortion map of code length N. Each line sample's peak A (DN, the larger of the two map
pixels around its row), its range r from the projector and the incidence i of the sheet
on the target (the target faces the camera: cos i = z / r) give
``D = A · r² / (N/2 · ρ · cos i)``, the peak per on sub-frame of a white surface facing
the unit at 1 m (:attr:`atris_node.calibration.LaserCalibration.return_dn_m2`). A stripe
centred on a pixel row gives the full peak, one between two rows about 0.6 of it, so D is
the samples' 90th percentile; their spread is reported. The pipeline then reads a
sample too faint for the range its line gives as a wrong identity
(:mod:`atris_node.pipeline.radiometry`).

The same samples give the stripes' width (:attr:`atris_node.calibration.LaserCalibration
.stripe_sigma_px`): the σ of the parabola through the logarithms of each peak and its two
neighbours, ``(2 ln A - ln a - ln c)^-1/2`` px, their median. A flat target facing the
unit shows whole stripes; the pipeline reads a narrower one as cut by an edge.

Units: DN, metres, µs. Albedo: a matte white card or paper is 0.8-0.9; an unknown one
taken too high makes D too low and the check more lenient, never stricter.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from atris_node.calibration import Calibration
from atris_node.errors import CalibrationError
from atris_node.pipeline.geometry import Points, triangulate_pixels
from atris_node.pipeline.radiometry import sample_peaks, source_range_m
from calib.peaks import find_line_rows

#: samples a target needs
MIN_SAMPLES = 20
#: the quantile of the samples' D taken: a stripe centred on a row
PEAK_QUANTILE = 0.9


@dataclass(frozen=True)
class RadiometryReport:
    """``return_dn_m2`` (DN m² per on sub-frame, white, facing, at ``exposure_us``) from
    ``samples`` line samples on the target, with the 10th-90th percentile spread of the
    per-sample values relative to it."""

    return_dn_m2: float
    exposure_us: float
    samples: int
    spread: tuple[float, float]
    stripe_sigma_px: float = 0.0

    def as_dict(self) -> dict[str, object]:
        """The numbers, for ``--json``."""
        return {"return_dn_m2": self.return_dn_m2, "return_exposure_us": self.exposure_us,
                "samples": self.samples, "spread": list(self.spread),
                "stripe_sigma_px": self.stripe_sigma_px}


def measure_return(calibration: Calibration, values: npt.NDArray[np.generic],
                   code_length: int, distance_m: float, albedo: float,
                   exposure_us: float) -> RadiometryReport:
    """D from one map ``values`` (H, W) of a flat target of ``albedo`` facing the unit at
    ``distance_m`` (m), N = ``code_length``, taken at ``exposure_us`` (µs)."""
    _check_target(code_length, distance_m, albedo, exposure_us)
    camera, laser = calibration.camera, calibration.laser
    found = find_line_rows(values, len(laser.alpha_rad))
    line, column = np.nonzero(found.valid)
    rows = found.rows[line, column]
    points = triangulate_pixels(rows, column, line, camera, laser, z_max_m=10.0 * distance_m)
    ok = points.valid
    if int(ok.sum()) < MIN_SAMPLES:
        raise CalibrationError(f"lines not found on the target: {int(ok.sum())} samples "
                               f"give a range; at least {MIN_SAMPLES} are needed")
    kept = Points(points.xyz_m[ok], ok[ok], points.sigma_z_m[ok])
    r = source_range_m(kept, laser)
    cos_i = kept.xyz_m[:, 2] / r
    peaks = sample_peaks(np.asarray(values), rows[ok], column[ok].astype(np.float64))
    each = peaks * r**2 / (0.5 * code_length * albedo * cos_i)
    value = float(np.quantile(each, PEAK_QUANTILE))
    if not value > 0.0:
        raise CalibrationError("the target's line peaks are not positive: is the map "
                               "demodulated with the unit's own code?")
    low, high = np.quantile(each, [0.1, 0.9]) / value
    return RadiometryReport(value, exposure_us, int(ok.sum()), (float(low), float(high)),
                            stripe_width_px(np.asarray(values), rows[ok], column[ok]))


def stripe_width_px(values: npt.NDArray[np.generic], rows: npt.NDArray[np.floating],
                    columns: npt.NDArray[np.integer]) -> float:
    """Median σ (px) of the three-point Gaussian fit at each sample (sub-pixel ``rows``,
    integer ``columns``) of ``values`` (H, W): ``(2 ln A - ln a - ln c)^-1/2`` of the
    peak A and its two neighbours. Samples with a neighbour <= 0 or off the image have
    no width; none at all is an error (the target shows no stripe)."""
    centre = np.rint(rows).astype(np.int64)
    inside = (centre >= 1) & (centre < values.shape[0] - 1)
    centre, columns = centre[inside], np.asarray(columns, dtype=np.int64)[inside]
    a, b, c = (values[centre + d, columns].astype(np.float64) for d in (-1, 0, 1))
    ok = (a > 0) & (c > 0) & (b > a) & (b > c)
    if not ok.any():
        raise CalibrationError("no stripe on the target has a width: its peaks have no "
                               "positive neighbours (is the map demodulated?)")
    curvature = 2.0 * np.log(b[ok]) - np.log(a[ok]) - np.log(c[ok])
    return float(np.median(1.0 / np.sqrt(curvature)))


def with_return(calibration: Calibration, report: RadiometryReport) -> Calibration:
    """``calibration`` with the lines' radiometric calibration of ``report``."""
    return replace(calibration, laser=replace(
        calibration.laser, return_dn_m2=report.return_dn_m2,
        return_exposure_us=report.exposure_us, stripe_sigma_px=report.stripe_sigma_px))


def _check_target(code_length: int, distance_m: float, albedo: float,
                  exposure_us: float) -> None:
    if code_length < 2 or code_length % 2:
        raise CalibrationError(f"code length must be an even number >= 2, got {code_length}")
    if not (np.isfinite(distance_m) and distance_m > 0.0):
        raise CalibrationError(f"target distance must be > 0 m, got {distance_m}")
    if not (np.isfinite(albedo) and 0.0 < albedo <= 1.0):
        raise CalibrationError(f"target albedo must be in (0, 1], got {albedo}")
    if not (np.isfinite(exposure_us) and exposure_us > 0.0):
        raise CalibrationError(f"exposure must be > 0 us, got {exposure_us}")
