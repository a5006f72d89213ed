"""Ground truth for one instant: depth map, true line rows and true sector distances.

The true row of line k in column c is where the light plane ``θ = α_k`` crosses the
column: θ (the projector-frame angle ``atan2(z, y + b)`` of the surface point each pixel
sees) is linearly interpolated between the two pixel centres on either side, on one
surface. Rows are observed (distorted) image rows, 0 = top row, as
:class:`atris_node.pipeline.peaks.LineSamples` reports them. When a column holds several crossings
of one line (occlusions) the nearest surface is kept. A crossing counts only when the
projector reaches the point (inside the fan, not shadowed).

The true point of a crossing is Eq. 1 at the undistorted sub-pixel position, so it is
the point the pipeline would triangulate from a perfect line row. Sector truth takes
those points on obstacles only (never the ground plane), in the vehicle frame, and keeps
the smallest horizontal range per sector of :class:`atris_node.pipeline.sectors.SectorLayout`.
On a ramp only points at least ``RAMP_MIN_HEIGHT_M`` above the ground count: a surface
rising gently out of the ground is ground below the sensor's stated floor (the pipeline's
default ``ground_clearance_m``). A shape whose top stays below that clearance (a 9 cm
kerb) is not an obstacle at all: the vehicle clears it. On the other shapes points count
from ``FLOOR_M`` above the ground up: a line meeting a kerb at its foot, 1 cm up, sees
ground, as any sensor would (the pipeline tells a surface from the ground from 3 cm up,
:mod:`atris_node.pipeline.tops`); the kerb is the truth where a line meets it higher.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.mounting import Mounting
from atris_node.pipeline.geometry import undistort_pixels
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim.layers import Surface, see
from atris_node.sim.optics import sheet_angles
from atris_node.sim.raycast import Ramp, Shape, occluded
from atris_node.sim.scene import Scene

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
#: ramp points lower than this above the ground (z = 0) are not sector truth, m
RAMP_MIN_HEIGHT_M = 0.1
#: a shape whose highest point is lower than this (m) is not an obstacle (the clearance)
CLEARANCE_M = RAMP_MIN_HEIGHT_M
#: points of other shapes lower than this above the ground (m) are not sector truth
FLOOR_M = 0.03


@dataclass(frozen=True)
class Truth:
    """What a perfect sensor would report for sub-frame ``sequence`` (time ``time_s``).

    Attributes:
        depth_m: (H, W) float64 camera-frame z of the surface each pixel sees, 0 = none.
        line_rows: (K, W) float64 sub-pixel observed row of line k in each column; 0 where
            ``line_visible`` is False.
        line_visible: (K, W) bool, True where line k reaches column c.
        line_points_m: (K, W, 3) float64 camera-frame points of the line samples (0 where
            not visible).
        line_obstacle: (K, W) bool, True where the sample lies on an obstacle (not ground).
        sector_distance_m: per sector, the smallest horizontal range (m) of an obstacle
            point hit by a line, None where there is none.
    """

    sequence: int
    time_s: float
    depth_m: FloatArray
    line_rows: FloatArray
    line_visible: BoolArray
    line_points_m: FloatArray
    line_obstacle: BoolArray
    sector_distance_m: tuple[float | None, ...]


@dataclass(frozen=True)
class _Crossings:
    rows: FloatArray  # (W,) observed sub-pixel row
    row_above: npt.NDArray[np.int64]  # (W,) integer row above the crossing
    found: BoolArray  # (W,)


def _crossings(theta: FloatArray, alpha: float, surface: Surface,
               depth: FloatArray) -> _Crossings:
    """Rows where ``theta`` crosses ``alpha`` in each column, nearest surface first."""
    s = theta - alpha
    a, b = s[:-1], s[1:]
    with np.errstate(invalid="ignore"):
        cross = (a * b <= 0.0) & (a != b) & (surface.shape[:-1] == surface.shape[1:])
    cross &= np.isfinite(a) & np.isfinite(b)
    frac = np.divide(a, a - b, out=np.zeros_like(a), where=cross)
    z = np.where(cross, depth[:-1] + frac * (depth[1:] - depth[:-1]), np.inf)
    best = np.argmin(z, axis=0)
    cols = np.arange(theta.shape[1])
    found = np.isfinite(z[best, cols])
    return _Crossings(best + frac[best, cols], best, found)


def _line_points(scene: Scene, k: int, rows: FloatArray, cols: FloatArray) -> tuple[
        FloatArray, BoolArray]:
    """Eq. 1 camera-frame points (n, 3) of line k at observed (row, col); valid mask."""
    camera, laser = scene.camera, scene.projector
    u, v = undistort_pixels(rows, cols, camera.model)
    denominator = camera.focal_px / np.tan(laser.alpha_rad[k]) - u
    ok = denominator > 1e-9
    scale = np.divide(laser.baseline_m, denominator, out=np.zeros_like(u), where=ok)
    return np.stack([v * scale, u * scale, camera.focal_px * scale], axis=-1), ok


def _reached(scene: Scene, mounting: Mounting, points_cam: FloatArray,
             time_s: float, rendered: tuple[FloatArray, ...] = ()) -> BoolArray:
    """True where the own projector reaches camera-frame points (in fan, not shadowed).

    ``rendered`` holds the ray-cast surface points (n, 3), vehicle frame, of the pixel rows
    each point's crossing lies between (none: the Eq. 1 test alone). An Eq. 1 point lies
    within ~1e-4 of r of its surface, which is cleared before the shadow test; where a sheet
    grazes a surface (a kerb's top edge, 4 deg incidence) that is not enough: the point lay
    1 mm under the top and its ray to the projector ran inside the kerb for 14 mm, so the
    truth had no obstacle where the stripe was rendered and read. A point whose Eq. 1 test
    fails is reached when either rendered point is lit as the renderer lights it
    (:func:`atris_node.sim.optics.sheet_irradiance`'s shadow test)."""
    world = mounting.camera_to_vehicle(points_cam)
    _, phi, r, dirs = sheet_angles(mounting, scene.projector, world)
    in_fan = np.abs(phi) <= scene.projector.fan_rad / 2.0
    if not world.size:
        return in_fan
    reached = in_fan & ~occluded(scene.shapes, world, -dirs, r, time_s, clearance_m=2e-3 * r)
    doubt = np.flatnonzero(in_fan & ~reached)
    for surface_points in rendered:
        if not doubt.size:
            break
        _, _, r_s, dirs_s = sheet_angles(mounting, scene.projector, surface_points[doubt])
        lit = ~occluded(scene.shapes, surface_points[doubt], -dirs_s, r_s, time_s)
        reached[doubt[lit]] = True
        doubt = doubt[~lit]
    return reached


def sector_distances(points_vehicle: FloatArray, layout: SectorLayout) -> tuple[
        float | None, ...]:
    """Smallest horizontal range per sector of (n, 3) vehicle-frame points, None if none."""
    index = layout.index_of(points_vehicle[:, 0], points_vehicle[:, 1])
    ranges = layout.horizontal_range(points_vehicle[:, 0], points_vehicle[:, 1])
    out: list[float | None] = []
    for sector in range(layout.count):
        mine = ranges[index == sector]
        out.append(float(mine.min()) if mine.size else None)
    return tuple(out)


def _top_m(shape: Shape, time_s: float) -> float:
    """The height (m) of the shape's highest point at ``time_s`` (inf when unbounded)."""
    bounds = shape.bounds(time_s)
    return float("inf") if bounds is None else float(bounds[1][2])


def compute_truth(scene: Scene, mounting: Mounting, dirs_cam: FloatArray,
                  dirs_world: FloatArray, *, sequence: int, time_s: float,
                  layout: SectorLayout) -> Truth:
    """Truth at ``time_s`` for rays (H, W, 3) of the camera at ``mounting``."""
    surface = see(scene.shapes, mounting.translation, dirs_world, time_s)
    depth = np.where(surface.hit, surface.t * dirs_cam[..., 2], 0.0)
    theta = np.where(surface.hit, sheet_angles(mounting, scene.projector, surface.points)[0],
                     np.nan)
    k_count, width = len(scene.projector.alpha_rad), scene.camera.width_px
    rows, visible = np.zeros((k_count, width)), np.zeros((k_count, width), bool)
    points, obstacle = np.zeros((k_count, width, 3)), np.zeros((k_count, width), bool)
    is_obstacle = np.array([s.obstacle and _top_m(s, time_s) >= CLEARANCE_M
                            for s in scene.shapes] + [False])
    floor = np.array([RAMP_MIN_HEIGHT_M if isinstance(s, Ramp) else FLOOR_M
                      for s in scene.shapes] + [0.0])
    floor_m = np.full((k_count, width), -np.inf)
    cols = np.arange(width)
    for k, alpha in enumerate(scene.projector.alpha_rad):
        c = _crossings(theta, alpha, surface, depth)
        pts, ok = _line_points(scene, k, c.rows[c.found], cols[c.found].astype(np.float64))
        above, found = c.row_above[c.found], cols[c.found]
        ok &= _reached(scene, mounting, pts, time_s, (surface.points[above, found],
                                                      surface.points[above + 1, found]))
        where = cols[c.found][ok]
        rows[k, where], visible[k, where], points[k, where] = c.rows[where], True, pts[ok]
        index = surface.shape[c.row_above[where], where]
        obstacle[k, where], floor_m[k, where] = is_obstacle[index], floor[index]
    counted = visible & obstacle
    hits = mounting.camera_to_vehicle(points[counted]).reshape(-1, 3)
    hits = hits[hits[:, 2] >= floor_m[counted]]
    return Truth(sequence, time_s, depth, rows, visible, points, visible & obstacle,
                 sector_distances(hits, layout))
