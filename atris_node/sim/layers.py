"""Per-pixel surfaces and electron rates of each light source, on a grid of camera rays.

The simulator computes these once for the static scene (whole image) and, per sub-frame,
for the patch of image a moving shape covers. Rates are float32 electrons per second:
the sub-frame's electrons are a weighted sum of them (see :mod:`atris_node.sim.render`).
Laser light of interferers is assumed to pass the camera's narrow-band filter (same
wavelength band as the own projector).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.mounting import Mounting
from atris_node.sim import optics
from atris_node.sim.raycast import Shape, cast
from atris_node.sim.scene import CameraSpec, LinePattern, Scene

FloatArray = npt.NDArray[np.float64]
Float32Array = npt.NDArray[np.float32]


@dataclass(frozen=True)
class Surface:
    """What each ray of an (h, w) grid sees: ray parameter ``t`` (m, inf = nothing),
    world ``points`` and ``normals`` (h, w, 3), ``shape`` index (h, w) (-1 = nothing),
    ``albedo`` (h, w) (the diffuse part) and the ``hit`` mask; ``finish`` holds per-pixel
    (h, w) arrays for :func:`atris_node.sim.optics.finish_factor`, None when every shape
    seen is plain Lambertian."""

    t: FloatArray
    points: FloatArray
    normals: FloatArray
    shape: npt.NDArray[np.int64]
    albedo: FloatArray
    hit: npt.NDArray[np.bool_]
    finish: dict[str, FloatArray] | None = None


def _finish(shapes: Sequence[Shape], index: npt.NDArray[np.int64]) -> dict[str, FloatArray] | None:
    """Per-pixel finish arrays of the shapes ``index`` points at (-1 = none)."""
    if not any(s.finished for s in shapes):
        return None

    def per_pixel(values: list[float]) -> FloatArray:
        return np.array([*values, 0.0])[index]
    return {"retro_gain": per_pixel([s.retro_gain for s in shapes]),
            "retro_lobe_rad": per_pixel([s.retro_lobe_rad for s in shapes]) + 1e-9,
            "mirror": per_pixel([s.albedo * s.specular for s in shapes]),
            "gloss_rad": per_pixel([s.gloss_rad for s in shapes]) + 1e-9}


def see(shapes: Sequence[Shape], origin: FloatArray, dirs: FloatArray,
        time_s: float = 0.0) -> Surface:
    """Cast the (h, w, 3) unit rays ``dirs`` from ``origin`` (3,) into ``shapes``."""
    h, w = dirs.shape[:2]
    hits = cast(shapes, origin, dirs.reshape(-1, 3), time_s)
    hit = hits.shape >= 0
    t = np.where(hit, hits.t, 0.0)
    points = origin + dirs.reshape(-1, 3) * t[:, None]
    albedo = np.array([s.albedo * (1.0 - s.specular) for s in shapes] + [0.0])[hits.shape]
    index = hits.shape.reshape(h, w)
    return Surface(hits.t.reshape(h, w), points.reshape(h, w, 3),
                   hits.normal.reshape(h, w, 3), index, albedo.reshape(h, w), hit.reshape(h, w),
                   _finish(shapes, index))


def ambient_rates(scene: Scene, surface: Surface, shapes: Sequence[Shape],
                  time_s: float = 0.0) -> tuple[Float32Array, Float32Array]:
    """(steady, lamp) electron rates (h, w) e⁻/s: sun and sky (plus the sky seen directly
    where no surface is hit), and the lamp that may flicker."""
    camera, ambient = scene.camera, scene.ambient
    ff = scene.projector.filter_factor
    k = optics.electrons_per_radiance(camera, optics.AMBIENT_WAVELENGTH_NM)
    normals = surface.normals.reshape(-1, 3)
    sky, lamp = optics.diffuse_irradiance(ambient, normals, ff)
    steady = sky
    if ambient.sun is not None and ambient.sun.lux > 0:
        steady = steady + optics.sun_irradiance(ambient.sun, shapes,
                                                surface.points.reshape(-1, 3), normals, ff,
                                                time_s)
    albedo = surface.albedo.reshape(-1)
    steady_e = albedo * steady * k / math.pi
    hit = surface.hit.reshape(-1)
    steady_e[~hit] = optics.lux_to_w_m2(ambient.sky_lux, ff) / math.pi * k
    lamp_e = np.where(hit, albedo * lamp * k / math.pi, 0.0)
    shape = surface.hit.shape
    return steady_e.reshape(shape).astype(np.float32), lamp_e.reshape(shape).astype(np.float32)


def sheet_rates(camera: CameraSpec, pose: Mounting, pattern: LinePattern, surface: Surface,
                shapes: Sequence[Shape], *, time_s: float = 0.0,
                eye_m: FloatArray | None = None) -> Float32Array:
    """Electron rate (h, w) e⁻/s of a line pattern at full power, shadows included.

    ``eye_m`` (3,) is the viewing camera's centre (vehicle frame, m; default: ``pose``'s,
    the own projector's camera); it matters only for retro-reflective or glossy finishes.
    """
    irr = optics.sheet_irradiance(pose, pattern, shapes, points=surface.points,
                                  normals=surface.normals, hit=surface.hit,
                                  psf_sigma_px=camera.psf_sigma_px, time_s=time_s)
    k = optics.electrons_per_radiance(camera, pattern.wavelength_nm)
    if surface.finish is None:
        return (surface.albedo * irr * (k / math.pi)).astype(np.float32)
    eye = pose.translation if eye_m is None else np.asarray(eye_m)
    to_eye = eye - surface.points
    to_eye /= np.maximum(np.linalg.norm(to_eye, axis=-1, keepdims=True), 1e-12)
    from_source = optics.sheet_angles(pose, pattern, surface.points)[3]
    extra = optics.finish_factor(surface.finish, surface.normals, from_source, to_eye)
    return (irr * k * (surface.albedo / math.pi + extra)).astype(np.float32)


def camera_rays(camera: CameraSpec, mounting: Mounting) -> tuple[FloatArray, FloatArray]:
    """Unit rays through every observed pixel centre: camera frame and vehicle frame,
    both (H, W, 3) float64. Lens distortion is undone per pixel."""
    from atris_node.pipeline.geometry import undistort_pixels

    rows, cols = np.mgrid[0:camera.height_px, 0:camera.width_px].astype(np.float64)
    u, v = undistort_pixels(rows, cols, camera.model)
    dirs = np.stack([v / camera.focal_px, u / camera.focal_px, np.ones_like(u)], axis=-1)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    return dirs, dirs @ mounting.rotation.T
