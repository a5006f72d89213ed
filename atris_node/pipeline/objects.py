"""Optional outputs, computed only when enabled: object clusters and point-cloud export.

Both use open3d, imported lazily (a node that does not ask for them never loads it).
DBSCAN on a few thousand line points costs milliseconds to tens of milliseconds, so the
pipeline runs it only when ``objects`` is enabled in its configuration.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

CLOUD_SUFFIXES = (".ply", ".pcd")


@dataclass(frozen=True)
class ObjectBox:
    """One cluster of obstacle points, vehicle frame: axis-aligned box (m), nearest
    horizontal range (m) and the bearing of the box centre (rad, positive left)."""

    centre_m: tuple[float, float, float]
    size_m: tuple[float, float, float]
    point_count: int
    distance_m: float
    bearing_rad: float


def _box(points: FloatArray) -> ObjectBox:
    """The axis-aligned box of (n, 3) points."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2.0
    return ObjectBox(
        centre_m=(float(centre[0]), float(centre[1]), float(centre[2])),
        size_m=(float(hi[0] - lo[0]), float(hi[1] - lo[1]), float(hi[2] - lo[2])),
        point_count=int(points.shape[0]),
        distance_m=float(np.hypot(points[:, 0], points[:, 1]).min()),
        bearing_rad=float(np.arctan2(centre[1], centre[0])))


def cluster_objects(points: FloatArray, eps_m: float = 0.3,
                    min_points: int = 10) -> tuple[ObjectBox, ...]:
    """Objects from (n, 3) float64 vehicle-frame obstacle points by open3d DBSCAN
    (neighbourhood ``eps_m`` metres, ``min_points`` per core point), nearest first."""
    if points.shape[0] < min_points:
        return ()
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    labels = np.asarray(cloud.cluster_dbscan(eps_m, min_points, print_progress=False))
    boxes = [_box(points[labels == k]) for k in range(int(labels.max(initial=-1)) + 1)]
    return tuple(sorted(boxes, key=lambda b: b.distance_m))


def export_cloud(points: FloatArray, path: Path) -> Path:
    """Write (n, 3) float64 points to ``path`` (.ply or .pcd, chosen by suffix) via open3d."""
    if path.suffix.lower() not in CLOUD_SUFFIXES:
        raise ConfigError(f"point cloud file {path} must end in one of {CLOUD_SUFFIXES}")
    import open3d as o3d

    path.parent.mkdir(parents=True, exist_ok=True)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if not o3d.io.write_point_cloud(path, cloud):
        raise ConfigError(f"open3d could not write the point cloud to {path}")
    logger.debug("wrote %d points to %s", points.shape[0], path)
    return path
