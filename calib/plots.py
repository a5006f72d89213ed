"""Residual plots (PNG, matplotlib's Agg canvas, no pyplot state) for each calibration run."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from calib.intrinsics import IntrinsicsResult
from calib.laser import LaserFit
from calib.verify import VerifyReport

logger = logging.getLogger(__name__)


def _save(figure: Figure, path: str | Path) -> Path:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(figure)
    figure.tight_layout()
    figure.savefig(out, dpi=100)
    logger.info("residual plot written to %s", out)
    return out


def plot_intrinsics(result: IntrinsicsResult, path: str | Path) -> Path:
    """Bar chart of the RMS reprojection error (px) of each board view."""
    figure = Figure(figsize=(8, 4))
    axes = figure.add_subplot()
    axes.bar(range(len(result.view_rms_px)), result.view_rms_px, color="tab:blue")
    axes.axhline(result.rms_px, color="tab:red", label=f"overall {result.rms_px:.3f} px")
    axes.set_xticks(range(len(result.view_names)), result.view_names, rotation=60, fontsize=7)
    axes.set_ylabel("RMS reprojection error (px)")
    axes.set_title(f"intrinsics: f = {result.camera.focal_px:.2f} px")
    axes.legend()
    return _save(figure, path)


def plot_laser(fit: LaserFit, path: str | Path) -> Path:
    """Row residual (px) against range per line, outliers grey, and their histogram."""
    figure = Figure(figsize=(10, 4))
    left, right = figure.add_subplot(1, 2, 1), figure.add_subplot(1, 2, 2)
    z_m = 1.0 / fit.samples.inv_z
    left.scatter(z_m[~fit.inlier], fit.residual_px[~fit.inlier], s=2, c="0.7",
                 label="outliers")
    for k in range(len(fit.laser.alpha_rad)):
        keep = fit.inlier & (fit.samples.line == k)
        left.scatter(z_m[keep], fit.residual_px[keep], s=2,
                     label=f"line {k}: {np.degrees(fit.laser.alpha_rad[k]):.3f}°")
    span = max(5.0 * fit.residual_rms_px, 0.05)
    left.set_ylim(-span, span)
    left.set(xlabel="range z (m)", ylabel="row residual (px)",
             title=f"b = {fit.laser.baseline_m * 1000:.3f} mm")
    left.legend(fontsize=7, markerscale=4)
    right.hist(fit.residual_px[fit.inlier], bins=60, color="tab:blue")
    right.set(xlabel="row residual (px)", ylabel="samples",
              title=f"RMS {fit.residual_rms_px:.3f} px, {fit.residual_rms_mm:.2f} mm")
    return _save(figure, path)


def plot_verify(report: VerifyReport, path: str | Path) -> Path:
    """Range error (mm) per column and line, with the ±3σ_z band expected."""
    figure = Figure(figsize=(8, 4))
    axes = figure.add_subplot()
    for k in np.unique(report.line):
        here = report.line == k
        axes.scatter(report.columns[here], report.error_m[here] * 1000, s=2, label=f"line {k}")
    band = 3000 * report.expected_sigma_z_m
    axes.axhspan(-band, band, color="tab:green", alpha=0.15, label="±3 σ_z expected")
    axes.set(xlabel="image column (px)", ylabel="range error (mm)",
             title=f"target at {report.distance_m:.3f} m: bias {report.bias_m * 1000:.2f} mm,"
                   f" RMS {report.rms_error_m * 1000:.2f} mm")
    axes.legend(fontsize=7, markerscale=4)
    return _save(figure, path)
