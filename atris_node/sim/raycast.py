"""Scene geometry and vectorised ray casting, in the vehicle frame (x fwd, y left, z up, m).

Every shape answers :meth:`Shape.intersect` for n rays at once: ``origins`` (3,) or (n, 3)
and unit ``directions`` (n, 3), float64, at time ``time_s`` (a shape with a velocity v and
an acceleration a has moved by ``v·t + a·t²/2``). It returns the ray parameter ``t`` (n,) in metres
(``inf`` for a miss, only hits with ``t > EPSILON_M`` count) and the outward unit normals
(n, 3). :func:`cast` takes the nearest hit over several shapes; it runs each shape's
compiled kernel (:mod:`atris_node.sim.raycast_kernels`, the same formulas in one pass,
through :meth:`Shape.nearest`), and :func:`cast_reference` the numpy methods.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.sim import raycast_kernels as kernels

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
#: hits closer than this along a ray are ignored (self-intersection of shadow rays), m
EPSILON_M = 1e-6
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Shape:
    """Common surface data: ``albedo`` 0..1, ``velocity_mps`` and ``acceleration_mps2``
    (3,) each, a name, and the finish (:mod:`atris_node.sim.optics`, "Finishes"):
    ``retro_gain`` (peak retro-reflected radiance relative to a white Lambertian surface,
    0 = none) within a Gaussian lobe of σ ``retro_lobe_rad`` about the source direction,
    and ``specular`` (0..1, the part of ``albedo`` reflected into a mirror lobe of σ
    ``gloss_rad`` instead of diffusely).

    ``obstacle`` is False only for the ground plane, which sector truth leaves out.
    """

    albedo: float
    velocity_mps: Vec3 = (0.0, 0.0, 0.0)
    name: str = ""
    obstacle: bool = True
    acceleration_mps2: Vec3 = (0.0, 0.0, 0.0)
    retro_gain: float = 0.0
    retro_lobe_rad: float = 0.0175
    specular: float = 0.0
    gloss_rad: float = 0.035

    @property
    def moving(self) -> bool:
        """True when the shape has a non-zero velocity or acceleration."""
        return any(v != 0.0 for v in (*self.velocity_mps, *self.acceleration_mps2))

    @property
    def finished(self) -> bool:
        """True when the surface is not purely Lambertian (retro-reflective or glossy)."""
        return self.retro_gain > 0.0 or self.specular > 0.0

    def offset(self, time_s: float) -> FloatArray:
        """Displacement (3,) of the shape at ``time_s``: ``v·t + a·t²/2``, metres."""
        return (np.asarray(self.velocity_mps) * time_s
                + 0.5 * np.asarray(self.acceleration_mps2) * time_s * time_s)

    def bounding_sphere(self, time_s: float) -> tuple[FloatArray, float]:
        """Centre (3,) and radius (m) of a sphere holding the shape; radius inf if unbounded."""
        raise NotImplementedError

    def bounds(self, time_s: float) -> tuple[FloatArray, FloatArray] | None:
        """Axis-aligned box (lo, hi), each (3,), holding the shape; None if unbounded."""
        centre, radius = self.bounding_sphere(time_s)
        if not np.isfinite(radius):
            return None
        return centre - radius, centre + radius

    def intersect(self, origins: FloatArray, directions: FloatArray,
                  time_s: float = 0.0) -> tuple[FloatArray, FloatArray]:
        """Ray parameter (n,) (inf on a miss) and unit normals (n, 3)."""
        raise NotImplementedError

    def nearest(self, origins: FloatArray, directions: FloatArray, time_s: float,
                index: int, best: Hits) -> None:
        """Write this shape's hits into ``best`` where they are nearer, as shape ``index``.

        ``origins`` (1, 3) or (n, 3), ``directions`` (n, 3). Shapes with a compiled
        kernel override this; the default uses :meth:`intersect`.
        """
        t, normal = self.intersect(origins[0] if origins.shape[0] == 1 else origins,
                                   directions, time_s)
        closer = t < best.t
        best.t[closer] = t[closer]
        best.normal[closer] = normal[closer]
        best.shape[closer] = index


def _valid(t: FloatArray) -> FloatArray:
    return np.where(t > EPSILON_M, t, np.inf)


@dataclass(frozen=True)
class Plane(Shape):
    """Infinite plane through ``point_m`` with normal ``normal`` (need not be unit)."""

    point_m: Vec3 = (0.0, 0.0, 0.0)
    normal: Vec3 = (0.0, 0.0, 1.0)

    def bounding_sphere(self, time_s: float) -> tuple[FloatArray, float]:
        return np.asarray(self.point_m) + self.offset(time_s), float("inf")

    def intersect(self, origins: FloatArray, directions: FloatArray,
                  time_s: float = 0.0) -> tuple[FloatArray, FloatArray]:
        n = np.asarray(self.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        p = np.asarray(self.point_m) + self.offset(time_s)
        denom = directions @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((p - origins) @ n) / denom
        t = _valid(np.where(np.abs(denom) > 1e-12, t, np.inf))
        normals = np.where((denom > 0)[:, None], -n, n)
        return t, normals

    def nearest(self, origins: FloatArray, directions: FloatArray, time_s: float,
                index: int, best: Hits) -> None:
        n = np.asarray(self.normal, dtype=np.float64)
        kernels.plane_hits(origins, directions, np.asarray(self.point_m) + self.offset(time_s),
                           n / np.linalg.norm(n), index, best.t, best.normal, best.shape)


@dataclass(frozen=True)
class Sphere(Shape):
    """Sphere of ``radius_m`` around ``center_m``."""

    center_m: Vec3 = (0.0, 0.0, 0.0)
    radius_m: float = 1.0

    def bounding_sphere(self, time_s: float) -> tuple[FloatArray, float]:
        return np.asarray(self.center_m) + self.offset(time_s), self.radius_m

    def intersect(self, origins: FloatArray, directions: FloatArray,
                  time_s: float = 0.0) -> tuple[FloatArray, FloatArray]:
        oc = origins - (np.asarray(self.center_m) + self.offset(time_s))
        oc = np.broadcast_to(oc, directions.shape)
        half_b = np.einsum("ij,ij->i", oc, directions)
        c = np.einsum("ij,ij->i", oc, oc) - self.radius_m**2
        disc = half_b * half_b - c
        root = np.sqrt(np.maximum(disc, 0.0))
        near, far = -half_b - root, -half_b + root
        t = np.where(near > EPSILON_M, near, far)
        t = np.where(disc >= 0.0, _valid(t), np.inf)
        hit = oc + directions * np.where(np.isfinite(t), t, 0.0)[:, None]
        return t, hit / self.radius_m

    def nearest(self, origins: FloatArray, directions: FloatArray, time_s: float,
                index: int, best: Hits) -> None:
        centre = np.asarray(self.center_m) + self.offset(time_s)
        kernels.sphere_hits(origins, directions, centre, float(self.radius_m), index,
                            best.t, best.normal, best.shape)


@dataclass(frozen=True)
class Box(Shape):
    """Box of ``size_m`` (dx, dy, dz) around ``center_m``, turned by ``yaw_rad`` about z."""

    center_m: Vec3 = (0.0, 0.0, 0.0)
    size_m: Vec3 = (1.0, 1.0, 1.0)
    yaw_rad: float = 0.0

    def bounding_sphere(self, time_s: float) -> tuple[FloatArray, float]:
        centre = np.asarray(self.center_m) + self.offset(time_s)
        return centre, 0.5 * float(np.linalg.norm(self.size_m))

    def bounds(self, time_s: float) -> tuple[FloatArray, FloatArray] | None:
        centre = np.asarray(self.center_m) + self.offset(time_s)
        half = np.abs(self._rotation()) @ (0.5 * np.asarray(self.size_m))
        return centre - half, centre + half

    def _rotation(self) -> FloatArray:
        c, s = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def intersect(self, origins: FloatArray, directions: FloatArray,
                  time_s: float = 0.0) -> tuple[FloatArray, FloatArray]:
        rot = self._rotation()
        o = (origins - (np.asarray(self.center_m) + self.offset(time_s))) @ rot
        o = np.broadcast_to(o, directions.shape)
        d = directions @ rot
        half = 0.5 * np.asarray(self.size_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1, t2 = (-half - o) * inv, (half - o) * inv
        t1, t2 = np.nan_to_num(np.minimum(t1, t2), nan=-np.inf), np.nan_to_num(
            np.maximum(t1, t2), nan=np.inf)
        t_in, t_out = t1.max(axis=1), t2.min(axis=1)
        t = np.where(t_in > EPSILON_M, t_in, t_out)
        t = np.where(t_in <= t_out, _valid(t), np.inf)
        axis = np.where(t_in > EPSILON_M, t1.argmax(axis=1), t2.argmin(axis=1))
        local = np.zeros_like(d)
        rows = np.arange(d.shape[0])
        local[rows, axis] = -np.sign(d[rows, axis])
        local[rows, axis] *= np.where(t_in > EPSILON_M, 1.0, -1.0)
        return t, local @ rot.T

    def nearest(self, origins: FloatArray, directions: FloatArray, time_s: float,
                index: int, best: Hits) -> None:
        centre = np.asarray(self.center_m, dtype=np.float64) + self.offset(time_s)
        kernels.box_hits(origins, directions, centre, 0.5 * np.asarray(self.size_m),
                         self._rotation(), index, best.t, best.normal, best.shape)


@dataclass(frozen=True)
class Cylinder(Shape):
    """Upright cylinder: base centre ``center_m`` (its lowest point), radius, height."""

    center_m: Vec3 = (0.0, 0.0, 0.0)
    radius_m: float = 0.3
    height_m: float = 1.7

    def bounding_sphere(self, time_s: float) -> tuple[FloatArray, float]:
        centre = np.asarray(self.center_m) + self.offset(time_s)
        centre[2] += 0.5 * self.height_m
        return centre, float(np.hypot(self.radius_m, 0.5 * self.height_m))

    def bounds(self, time_s: float) -> tuple[FloatArray, FloatArray] | None:
        base = np.asarray(self.center_m) + self.offset(time_s)
        r = self.radius_m
        return base - np.array([r, r, 0.0]), base + np.array([r, r, self.height_m])

    def _side(self, o: FloatArray, d: FloatArray) -> FloatArray:
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        half_b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]
        c = o[:, 0] ** 2 + o[:, 1] ** 2 - self.radius_m**2
        disc = half_b * half_b - a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            near, far = (-half_b - root) / a, (-half_b + root) / a
        t = np.where(near > EPSILON_M, near, far)
        z = o[:, 2] + d[:, 2] * np.nan_to_num(t)
        ok = (disc >= 0.0) & (a > 1e-12) & (z >= 0.0) & (z <= self.height_m)
        return np.where(ok, _valid(np.nan_to_num(t, nan=np.inf)), np.inf)

    def _cap(self, o: FloatArray, d: FloatArray, z_cap: float) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (z_cap - o[:, 2]) / d[:, 2]
        t = np.nan_to_num(t, nan=np.inf, posinf=np.inf, neginf=np.inf)
        x, y = o[:, 0] + d[:, 0] * np.where(np.isfinite(t), t, 0.0), o[:, 1] + d[:, 1] * (
            np.where(np.isfinite(t), t, 0.0))
        return np.where(x * x + y * y <= self.radius_m**2, _valid(t), np.inf)

    def intersect(self, origins: FloatArray, directions: FloatArray,
                  time_s: float = 0.0) -> tuple[FloatArray, FloatArray]:
        o = np.broadcast_to(origins - (np.asarray(self.center_m) + self.offset(time_s)),
                            directions.shape)
        hits = np.stack([self._side(o, directions), self._cap(o, directions, 0.0),
                         self._cap(o, directions, self.height_m)])
        which = hits.argmin(axis=0)
        t = hits.min(axis=0)
        p = o + directions * np.where(np.isfinite(t), t, 0.0)[:, None]
        side = np.stack([p[:, 0], p[:, 1], np.zeros_like(t)], axis=1) / self.radius_m
        caps = np.zeros_like(p)
        caps[:, 2] = np.where(which == 1, -1.0, 1.0)
        return t, np.where((which == 0)[:, None], side, caps)

    def nearest(self, origins: FloatArray, directions: FloatArray, time_s: float,
                index: int, best: Hits) -> None:
        base = np.asarray(self.center_m, dtype=np.float64) + self.offset(time_s)
        kernels.cylinder_hits(origins, directions, base, float(self.radius_m),
                              float(self.height_m), index, best.t, best.normal, best.shape)


@dataclass(frozen=True)
class Ramp(Shape):
    """A finite tilted rectangle (a ramp's running surface, seen from both sides): its low
    edge centred on ``start_m``, climbing ``length_m`` along its surface at ``slope_rad``
    above the horizontal towards the heading ``yaw_rad`` (about z, 0 = vehicle +x), and
    ``width_m`` across."""

    start_m: Vec3 = (0.0, 0.0, 0.0)
    length_m: float = 1.0
    width_m: float = 1.0
    slope_rad: float = 0.1
    yaw_rad: float = 0.0

    def axes(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Unit vectors (3,) up the slope, across it, and normal to it (upwards)."""
        cs, ss = np.cos(self.slope_rad), np.sin(self.slope_rad)
        cy, sy = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        up = np.array([cs * cy, cs * sy, ss])
        across = np.array([-sy, cy, 0.0])
        return up, across, np.cross(up, across)

    def centre(self, time_s: float) -> FloatArray:
        """Centre (3,) of the rectangle at ``time_s``, m."""
        return np.asarray(self.start_m) + 0.5 * self.length_m * self.axes()[0] + self.offset(
            time_s)

    def bounding_sphere(self, time_s: float) -> tuple[FloatArray, float]:
        return self.centre(time_s), 0.5 * float(np.hypot(self.length_m, self.width_m))

    def bounds(self, time_s: float) -> tuple[FloatArray, FloatArray] | None:
        up, across, _ = self.axes()
        half = 0.5 * (np.abs(up) * self.length_m + np.abs(across) * self.width_m)
        centre = self.centre(time_s)
        return centre - half, centre + half

    def intersect(self, origins: FloatArray, directions: FloatArray,
                  time_s: float = 0.0) -> tuple[FloatArray, FloatArray]:
        up, across, n = self.axes()
        centre = self.centre(time_s)
        denom = directions @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((centre - origins) @ n) / denom
        t = np.where(np.abs(denom) > 1e-12, t, np.inf)
        rel = np.broadcast_to(origins - centre, directions.shape) + directions * np.where(
            np.isfinite(t), t, 0.0)[:, None]
        inside = (np.abs(rel @ up) <= 0.5 * self.length_m) & (
            np.abs(rel @ across) <= 0.5 * self.width_m)
        t = np.where(inside, _valid(t), np.inf)
        return t, np.where((denom > 0)[:, None], -n, n)

    def nearest(self, origins: FloatArray, directions: FloatArray, time_s: float,
                index: int, best: Hits) -> None:
        kernels.ramp_hits(origins, directions, self.centre(time_s), np.stack(self.axes()),
                          0.5 * self.length_m, 0.5 * self.width_m, index, best.t,
                          best.normal, best.shape)


@dataclass(frozen=True)
class Hits:
    """Nearest hits of n rays: ``t`` (n,) (inf = miss), ``normal`` (n, 3), ``shape`` (n,)
    index into the shape list (-1 = miss)."""

    t: FloatArray
    normal: FloatArray
    shape: IntArray


def cast(shapes: Sequence[Shape], origins: FloatArray, directions: FloatArray,
         time_s: float = 0.0, index_offset: int = 0) -> Hits:
    """Nearest hit of every ray over ``shapes``; shape indices start at ``index_offset``."""
    n = directions.shape[0]
    best = Hits(np.full(n, np.inf), np.zeros((n, 3)), np.full(n, -1, dtype=np.int64))
    rays = np.asarray(directions, dtype=np.float64)
    starts = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    for i, shape in enumerate(shapes):
        shape.nearest(starts, rays, time_s, i + index_offset, best)
    return best


def cast_reference(shapes: Sequence[Shape], origins: FloatArray, directions: FloatArray,
                   time_s: float = 0.0, index_offset: int = 0) -> Hits:
    """:func:`cast` with the shapes' numpy :meth:`Shape.intersect` (the tests' reference)."""
    n = directions.shape[0]
    best = Hits(np.full(n, np.inf), np.zeros((n, 3)), np.full(n, -1, dtype=np.int64))
    for i, shape in enumerate(shapes):
        t, normal = shape.intersect(origins, directions, time_s)
        closer = t < best.t
        best.t[closer] = t[closer]
        best.normal[closer] = normal[closer]
        best.shape[closer] = i + index_offset
    return best


def occluded(shapes: Sequence[Shape], points: FloatArray, towards: FloatArray,
             distance_m: FloatArray | float, time_s: float = 0.0,
             clearance_m: FloatArray | float = 1e-4) -> npt.NDArray[np.bool_]:
    """True where the segment from ``points`` (n, 3) along unit ``towards`` (n, 3) or (3,)
    hits a shape before ``distance_m`` (shadow rays; use inf for a light at infinity).

    The segment starts ``clearance_m`` (scalar or (n,)) away from the point, so a point
    computed slightly inside its own surface does not shadow itself.
    """
    dirs = np.broadcast_to(towards, points.shape)
    clearance = np.asarray(clearance_m, dtype=np.float64)
    start = points + dirs * (clearance[..., None] if clearance.ndim else clearance)
    hits = cast(shapes, start, np.ascontiguousarray(dirs), time_s)
    return hits.t < np.asarray(distance_m) - 2.0 * clearance
