"""Synthetic distortion maps with exact ground truth for the line / geometry / sector tests.

Not a simulator: stripes are drawn straight into a demodulated map (pixel-integrated
Gaussian profiles plus Gaussian noise) at rows computed analytically from Eq. 1, for a
scene made of the ground plane and upright boxes in the vehicle frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from atris_node.calibration import Calibration, CameraModel, LaserCalibration
from atris_node.mounting import Mounting
from atris_node.pipeline.geometry import distort_pixels
from atris_node.pipeline.sectors import SectorLayout
from atris_node.types import DistortionMap

FloatArray = npt.NDArray[np.float64]


def stripe_map(height: int, rows: FloatArray, amplitude: FloatArray, sigma_px: float, *,
               noise_dn: float, rng: np.random.Generator, supersample: int = 8) -> FloatArray:
    """(height, W) float map: a pixel-integrated Gaussian stripe of σ ``sigma_px`` centred
    at ``rows[k, c]`` (NaN = no stripe) with peak ``amplitude[k, c]`` DN, plus noise."""
    image = rng.normal(0.0, noise_dn, (height, rows.shape[1])) if noise_dn > 0 else (
        np.zeros((height, rows.shape[1])))
    sub = (np.arange(supersample) + 0.5) / supersample - 0.5
    grid = np.arange(height)[:, None] + sub[None, :]
    for k in range(rows.shape[0]):
        cols = np.flatnonzero(np.isfinite(rows[k]))
        d = (grid[:, :, None] - rows[k, cols][None, None, :]) / sigma_px
        image[:, cols] += amplitude[k, cols] * np.exp(-0.5 * d * d).mean(axis=1)
    return image


def as_map(image: FloatArray, saturated: npt.NDArray[np.bool_] | None = None,
           time_s: float = 1.0, sequence: int = 16) -> DistortionMap:
    """Wrap a float map as an int32 :class:`DistortionMap` of N = 16."""
    values = np.round(image).astype(np.int32)
    sat = np.zeros(values.shape, bool) if saturated is None else saturated
    return DistortionMap(values, sat, 16, sequence - 15, sequence, time_s - 0.03, time_s)


def oak_calibration(alpha_deg: tuple[float, ...] = (80.0,), baseline_m: float = 0.075,
                    width: int = 640, height: int = 400,
                    distortion: tuple[float, ...] = ()) -> Calibration:
    """An OAK-like camera (f = 763 px at 1280 wide) with the given line angles."""
    f = 763.0 * width / 1280.0
    camera = CameraModel(width, height, f, width / 2 - 0.5, height / 2 - 0.5, distortion)
    return Calibration(camera, LaserCalibration(baseline_m, tuple(np.deg2rad(alpha_deg))))


@dataclass(frozen=True)
class Box:
    """An upright box face towards the camera: plane x = distance_m (vehicle frame)
    for ``y_min_m <= y <= y_max_m`` and ``0 <= z <= height_m``."""

    distance_m: float
    y_min_m: float
    y_max_m: float
    height_m: float = 2.0


@dataclass(frozen=True)
class Scene:
    """Ground plane z = 0 (optional) and boxes, seen by one calibrated, mounted unit."""

    calibration: Calibration
    mounting: Mounting
    boxes: tuple[Box, ...] = ()
    ground: bool = True
    z_far_m: float = 60.0
    amplitude_dn: float = 2000.0
    sigma_px: float = 1.2
    noise_dn: float = 10.0
    extra: dict[str, float] = field(default_factory=dict)


def _ray_parameters(scene: Scene, line: int) -> tuple[FloatArray, FloatArray]:
    """Camera points on light plane k in column c: P(z) = z·a_c + c0; returns (a (W,3), c0)."""
    cam = scene.calibration.camera
    v = (np.arange(cam.width_px) - cam.cx_px) / cam.focal_px
    cot = 1.0 / np.tan(scene.calibration.laser.alpha_rad[line])
    a = np.stack([v, np.full_like(v, cot), np.ones_like(v)], axis=1)
    return a, np.array([0.0, -scene.calibration.laser.baseline_m, 0.0])


def _hits(scene: Scene, line: int) -> tuple[FloatArray, FloatArray]:
    """(W,) camera range z of the first surface along light plane k per column (inf none),
    and (W, 3) vehicle-frame hit points."""
    a, c0 = _ray_parameters(scene, line)
    rot, t = scene.mounting.rotation, scene.mounting.translation
    av, cv = a @ rot.T, rot @ c0 + t
    best = np.full(a.shape[0], np.inf)
    if scene.ground:
        with np.errstate(divide="ignore", invalid="ignore"):
            zg = -cv[2] / av[:, 2]
        best = np.where((zg > 0.05) & np.isfinite(zg), zg, best)
    for box in scene.boxes:
        with np.errstate(divide="ignore", invalid="ignore"):
            zb = (box.distance_m - cv[0]) / av[:, 0]
        p = zb[:, None] * av + cv
        ok = (zb > 0.05) & (p[:, 1] >= box.y_min_m) & (p[:, 1] <= box.y_max_m)
        ok &= (p[:, 2] >= 0.0) & (p[:, 2] <= box.height_m) & (zb < best)
        best = np.where(ok, zb, best)
    best = np.where(best <= scene.z_far_m, best, np.inf)
    return best, np.where(np.isfinite(best)[:, None], best[:, None] * av + cv, 0.0)


@dataclass(frozen=True)
class Truth:
    """Exact line rows (K, W) (observed pixels, NaN = no stripe), camera range (K, W)
    (inf = none) and the vehicle-frame hit points (K, W, 3)."""

    line_rows: FloatArray
    range_m: FloatArray
    points_vehicle: FloatArray

    def sector_distance(self, layout: SectorLayout, clearance_m: float,
                        z_max_m: float) -> list[float | None]:
        """Smallest horizontal range of obstacle hits per sector (None = none)."""
        p = self.points_vehicle.reshape(-1, 3)
        keep = np.isfinite(self.range_m.ravel()) & (self.range_m.ravel() <= z_max_m)
        keep &= p[:, 2] > clearance_m
        idx = layout.index_of(p[keep, 0], p[keep, 1])
        rng = layout.horizontal_range(p[keep, 0], p[keep, 1])
        return [float(rng[idx == s].min()) if (idx == s).any() else None
                for s in range(layout.count)]


def truth(scene: Scene) -> Truth:
    """Exact stripes of ``scene`` (distorted rows, ranges, hit points)."""
    cam, laser = scene.calibration.camera, scene.calibration.laser
    rows, ranges, points = [], [], []
    for k in range(len(laser.alpha_rad)):
        z, p = _hits(scene, k)
        with np.errstate(divide="ignore"):
            u = cam.focal_px / np.tan(laser.alpha_rad[k]) - cam.focal_px * laser.baseline_m / z
        r, _ = distort_pixels(u + cam.cy_px, np.arange(cam.width_px, dtype=float), cam)
        visible = np.isfinite(z) & (r >= 0) & (r <= cam.height_px - 1)
        rows.append(np.where(visible, r, np.nan))
        ranges.append(np.where(visible, z, np.inf))
        points.append(p)
    return Truth(np.array(rows), np.array(ranges), np.array(points))


def render(scene: Scene, rng: np.random.Generator) -> tuple[DistortionMap, Truth]:
    """A noisy distortion map of ``scene`` and its exact truth."""
    t = truth(scene)
    amplitude = np.full(t.line_rows.shape, scene.amplitude_dn)
    image = stripe_map(scene.calibration.camera.height_px, t.line_rows, amplitude,
                       scene.sigma_px, noise_dn=scene.noise_dn, rng=rng)
    return as_map(image), t
