"""Check a calibration on a flat target at a known distance.

The target's line samples are triangulated with paper Eq. 1 (:func:`atris_node.pipeline.geometry.
triangulate`) and their ranges compared with the known one. The expected spread of one
sample is ``σ_z ≈ z²·σ_u / (f·b)``; the check passes when the bias and the RMS error are
both within ``factor·σ_z`` (default 3). σ_u is given (default 0.1 px, the sub-pixel line
centre accuracy of DESIGN §3) and the σ_u seen in the capture is reported beside it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.calibration import Calibration
from atris_node.errors import CalibrationError
from atris_node.pipeline.geometry import range_sigma, triangulate, undistort_pixels
from calib.peaks import LineRows

logger = logging.getLogger(__name__)

DEFAULT_SIGMA_U_PX = 0.1
PASS_FACTOR = 3.0
MIN_SAMPLES = 20


@dataclass(frozen=True)
class VerifyReport:
    """Range errors on a target at ``distance_m``; metres unless the name says otherwise.

    ``columns`` (n,) and ``error_m`` (n,) are the per-sample data (for the plot);
    ``line`` (n,) the line index of each sample.
    """

    distance_m: float
    samples: int
    bias_m: float
    rms_error_m: float
    sigma_u_px: float
    measured_sigma_u_px: float
    expected_sigma_z_m: float
    passed: bool
    columns: npt.NDArray[np.float64]
    error_m: npt.NDArray[np.float64]
    line: npt.NDArray[np.int64]

    def as_dict(self) -> dict[str, float | int | bool]:
        """The summary numbers (no arrays), for ``--json``."""
        return {"distance_m": self.distance_m, "samples": self.samples,
                "bias_m": self.bias_m, "rms_error_m": self.rms_error_m,
                "sigma_u_px": self.sigma_u_px, "measured_sigma_u_px": self.measured_sigma_u_px,
                "expected_sigma_z_m": self.expected_sigma_z_m, "passed": self.passed}


def _spread_of_u(u_px: npt.NDArray[np.float64], v_px: npt.NDArray[np.float64],
                 line: npt.NDArray[np.int64]) -> float:
    """Robust σ of u about a straight line in v, per line (a flat target may be tilted)."""
    residuals = []
    for k in np.unique(line):
        here = line == k
        if here.sum() < 3:
            continue
        trend = np.polyfit(v_px[here], u_px[here], 1)
        residuals.append(u_px[here] - np.polyval(trend, v_px[here]))
    if not residuals:
        return 0.0
    spread = np.concatenate(residuals)
    return float(1.4826 * np.median(np.abs(spread - np.median(spread))))


def verify_flat_target(calibration: Calibration, line_rows: LineRows, distance_m: float,
                       sigma_u_px: float = DEFAULT_SIGMA_U_PX) -> VerifyReport:
    """Compare the Eq. 1 ranges of ``line_rows`` with the known ``distance_m`` (m)."""
    camera, laser = calibration.camera, calibration.laser
    if line_rows.line_count != len(laser.alpha_rad):
        raise CalibrationError(f"the capture shows {line_rows.line_count} lines but the "
                               f"calibration has {len(laser.alpha_rad)}")
    line, column = np.nonzero(line_rows.valid)
    if len(line) < MIN_SAMPLES:
        raise CalibrationError(f"lines not found on the target: {len(line)} samples; "
                               f"at least {MIN_SAMPLES} are needed")
    u_px, v_px = undistort_pixels(line_rows.rows[line, column], column, camera)
    points = triangulate(u_px, v_px, line, camera, laser, z_max_m=10.0 * distance_m)
    if int(points.valid.sum()) < MIN_SAMPLES:
        raise CalibrationError(f"only {int(points.valid.sum())} samples give a range (Eq. 1) "
                               "on the target; check the calibration and the capture")
    error = points.xyz_m[points.valid, 2] - distance_m
    expected = float(range_sigma(distance_m, sigma_u_px, camera.focal_px, laser.baseline_m))
    bias, rms = float(np.mean(error)), float(np.sqrt(np.mean(error**2)))
    passed = abs(bias) <= PASS_FACTOR * expected and rms <= PASS_FACTOR * expected
    logger.info("verify at %.3f m: bias %.4f m, RMS %.4f m, expected sigma_z %.4f m",
                distance_m, bias, rms, expected)
    return VerifyReport(distance_m, len(error), bias, rms, sigma_u_px,
                        _spread_of_u(u_px, v_px, line), expected, passed,
                        column[points.valid].astype(np.float64), error,
                        line[points.valid].astype(np.int64))
