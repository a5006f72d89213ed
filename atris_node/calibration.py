"""Calibration values the pipeline needs: camera intrinsics and one light plane per line.

Units: pixels for the intrinsics, metres for the baseline, radians for the angles.
Loading and validating calibration files lives in ``calib/``; this module only holds the
values and checks that they can be used.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from atris_node.errors import CalibrationError


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera with optional OpenCV distortion (k1, k2, p1, p2[, k3...]).

    ``focal_px`` is f in pixels (square pixels assumed); ``cx_px``/``cy_px`` the principal
    point (column, row) in pixels; ``width_px``/``height_px`` the image size it belongs to.
    """

    width_px: int
    height_px: int
    focal_px: float
    cx_px: float
    cy_px: float
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise CalibrationError(
                f"image size must be positive, got {self.width_px}x{self.height_px}")
        if not (np.isfinite(self.focal_px) and self.focal_px > 0):
            raise CalibrationError(f"focal_px must be a positive number, got {self.focal_px}")
        if not all(np.isfinite(v) for v in (self.cx_px, self.cy_px, *self.distortion)):
            raise CalibrationError("principal point and distortion must be finite numbers")

    @property
    def matrix(self) -> np.ndarray:
        """3×3 camera matrix K, float64."""
        return np.array([[self.focal_px, 0.0, self.cx_px],
                         [0.0, self.focal_px, self.cy_px],
                         [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class LaserCalibration:
    """Baseline b (m, > 0) and the angle alpha_k (rad, in (0, π)) of each projected line.

    Lines are ordered by their singular row ``f·cot(alpha_k)``, top of the image first.

    ``return_dn_m2`` is the line's radiometric calibration: the peak a line leaves, in DN
    per sub-frame the laser is on, on a white Lambertian surface facing the unit 1 m
    away, times m² (a surface of albedo ρ at r metres, lit at incidence i, returns
    ``return_dn_m2 · ρ · cos i / r²`` DN per on sub-frame), at the exposure
    ``return_exposure_us`` (µs). 0 when not calibrated: the pipeline then cannot tell a
    return too faint for its range (:mod:`atris_node.pipeline.radiometry`).

    ``stripe_sigma_px`` is the stripes' width across the rows as the three-point Gaussian
    peak fit reads it (px, σ of ``ln`` of the peak and its two neighbours; optics and
    pixel together), on a flat target facing the unit. 0 when not measured: the pipeline
    then cannot tell a stripe cut by an edge (:mod:`atris_node.pipeline.peaks`).
    """

    baseline_m: float
    alpha_rad: tuple[float, ...]
    baseline_sigma_m: float = 0.0
    alpha_sigma_rad: tuple[float, ...] = field(default_factory=tuple)
    return_dn_m2: float = 0.0
    return_exposure_us: float = 0.0
    stripe_sigma_px: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.baseline_m) and self.baseline_m > 0):
            raise CalibrationError(f"baseline_m must be > 0, got {self.baseline_m}")
        if not self.alpha_rad:
            raise CalibrationError("at least one line angle alpha_rad is needed")
        if not all(np.isfinite(a) and 0.0 < a < np.pi for a in self.alpha_rad):
            raise CalibrationError(f"every alpha_rad must be in (0, π), got {self.alpha_rad}")
        if not (np.isfinite(self.return_dn_m2) and self.return_dn_m2 >= 0.0):
            raise CalibrationError(f"return_dn_m2 must be a number >= 0 (0: not calibrated), "
                                   f"got {self.return_dn_m2}")
        if self.return_dn_m2 > 0.0 and not (np.isfinite(self.return_exposure_us)
                                            and self.return_exposure_us > 0.0):
            raise CalibrationError("return_exposure_us must be > 0 when return_dn_m2 is "
                                   f"given, got {self.return_exposure_us}")
        if not (np.isfinite(self.stripe_sigma_px) and self.stripe_sigma_px >= 0.0):
            raise CalibrationError(f"stripe_sigma_px must be a number >= 0 (0: not "
                                   f"measured), got {self.stripe_sigma_px}")


@dataclass(frozen=True)
class Calibration:
    """Everything triangulation needs for one unit."""

    camera: CameraModel
    laser: LaserCalibration
