"""From vehicle-frame points to obstacle distances: ground, sectors, nearest, closing speed.

Points are (n, 3) float64 in the vehicle frame (ISO 8855: x forward, y left, z up,
metres). A point is an *obstacle* when it is a valid return and higher than the ground
clearance above the ground plane. Per sector (see :mod:`atris_node.pipeline.sectors`):

- VALID: at least ``min_points`` obstacle points and enough confidence; the distance is
  a low quantile of their horizontal ranges, and never nearer than the ``min_points``-th
  nearest point (a distance always has ``min_points`` points behind it);
- NO_RETURN: at least ``min_points`` samples (ground hits or rays with no return within
  range) and no obstacle point at all: free up to the range limit;
- INVALID: everything else (too few samples, too few obstacle points to trust, or low
  confidence). An INVALID sector never carries a distance.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError
from atris_node.pipeline import obstacles_kernels
from atris_node.pipeline.sectors import SectorLayout
from atris_node.types import SectorDistance, SectorState

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: a fitted ground plane may tilt at most this much from the vehicle's z axis, radians
MAX_GROUND_TILT_RAD = np.deg2rad(15.0)
#: points considered for a ground fit lie within this height of the current plane, m
GROUND_SEARCH_M = 0.3


@dataclass(frozen=True)
class GroundPlane:
    """Plane ``n·p + offset_m = 0`` with unit normal ``n`` pointing up (vehicle frame)."""

    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    offset_m: float = 0.0

    def height(self, points: FloatArray) -> FloatArray:
        """(n,) signed height (m) of (n, 3) vehicle-frame points above the plane."""
        return np.asarray(points @ np.asarray(self.normal) + self.offset_m, dtype=np.float64)


def estimate_ground(points: FloatArray, previous: GroundPlane, threshold_m: float = 0.03,
                    min_inliers: int = 50) -> GroundPlane | None:
    """Ground plane fitted by open3d ``segment_plane`` (RANSAC) to the points within
    ``GROUND_SEARCH_M`` of ``previous``; None when no near-level plane of at least
    ``min_inliers`` points is found. ``points`` is (n, 3) float64, vehicle frame, m."""
    near = points[np.abs(previous.height(points)) < GROUND_SEARCH_M]
    if near.shape[0] < min_inliers:
        return None
    import open3d as o3d

    o3d.utility.random.seed(1)  # reproducible RANSAC
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(near))
    model, inliers = cloud.segment_plane(threshold_m, 3, 100)
    a, b, c, d = (float(x) for x in model)
    sign = 1.0 if c >= 0 else -1.0
    norm = sign * float(np.sqrt(a * a + b * b + c * c))
    if len(inliers) < min_inliers or np.arccos(min(abs(c) / abs(norm), 1.0)) > (
            MAX_GROUND_TILT_RAD):
        return None
    return GroundPlane((a / norm, b / norm, c / norm), d / norm)


@dataclass(frozen=True)
class SectorSettings:
    """How sector distances are made: counts, quantile (0..1), confidence (0..1)."""

    min_points: int = 5
    quantile: float = 0.1
    min_confidence: float = 0.2
    snr_min: float = 6.0

    def __post_init__(self) -> None:
        if self.min_points < 1:
            raise ConfigError(f"min_points must be >= 1, got {self.min_points}")
        if not 0.0 <= self.quantile <= 0.5:
            raise ConfigError(f"quantile must be in [0, 0.5], got {self.quantile}")
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ConfigError(f"min_confidence must be in [0, 1], got {self.min_confidence}")


@dataclass(frozen=True)
class SectorInput:
    """Per-sample arrays (n,) for :func:`sector_distances`.

    ``points`` (n, 3) vehicle frame (for a no-return sample: a point on its ray, used
    for the bearing only); ``obstacle`` True for valid returns above the ground clearance;
    ``snr`` the line-peak SNR of each sample.
    """

    points: FloatArray
    obstacle: BoolArray
    snr: FloatArray
    _placed: dict[SectorLayout, tuple[npt.NDArray[np.int64], FloatArray]] = field(
        default_factory=dict, init=False, repr=False, compare=False)

    def placed(self, layout: SectorLayout) -> tuple[npt.NDArray[np.int64], FloatArray]:
        """(n,) sector index (-1 outside the field of view) and horizontal range (m) of
        every sample, computed once per layout (the sectors and the nearest obstacle
        both need them)."""
        if layout not in self._placed:
            x, y = self.points[:, 0], self.points[:, 1]
            self._placed[layout] = (layout.index_of(x, y), layout.horizontal_range(x, y))
        return self._placed[layout]


def _confidence(count: int, median_snr: float, settings: SectorSettings) -> float:
    """0..1: grows with the point count (full at 3·min_points) and the median SNR (full
    at 2·snr_min)."""
    if count == 0:
        return 0.0
    by_count = min(1.0, count / (3.0 * settings.min_points))
    by_snr = min(1.0, median_snr / (2.0 * settings.snr_min))
    return by_count * by_snr


def _sector(index: int, layout: SectorLayout, settings: SectorSettings, *, samples: int,
            hits: int, median_snr: float, distance_m: float) -> SectorDistance:
    """One sector from the counts of its samples and obstacle points, the median SNR (of
    the obstacle points, else of every sample) and its distance (see
    :func:`atris_node.pipeline.obstacles_kernels.sector_statistics`)."""
    bearing = layout.bearing_of(index)
    if samples < settings.min_points:
        return SectorDistance(index, bearing, SectorState.INVALID, point_count=samples)
    if hits == 0:
        conf = _confidence(samples, median_snr, settings)
        state = SectorState.NO_RETURN if conf >= settings.min_confidence else (
            SectorState.INVALID)
        return SectorDistance(index, bearing, state, 0.0, conf, samples)
    conf = _confidence(hits, median_snr, settings)
    if hits < settings.min_points or conf < settings.min_confidence:
        return SectorDistance(index, bearing, SectorState.INVALID, 0.0, conf, hits)
    return SectorDistance(index, bearing, SectorState.VALID, distance_m, conf, hits)


def sector_distances(data: SectorInput, layout: SectorLayout,
                     settings: SectorSettings) -> tuple[SectorDistance, ...]:
    """One :class:`SectorDistance` per sector of ``layout``, index 0 at the right edge.
    The samples are grouped by sector in one compiled pass and each order statistic is
    read by selection (:func:`atris_node.pipeline.obstacles_kernels.sector_statistics`)."""
    idx, rng = data.placed(layout)
    samples, hits, median, distance = obstacles_kernels.sector_statistics(
        np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(data.obstacle,
                                                                        dtype=np.bool_),
        np.ascontiguousarray(rng, dtype=np.float64),
        np.ascontiguousarray(data.snr, dtype=np.float64), layout.count, settings.min_points,
        float(settings.quantile))
    return tuple(_sector(s, layout, settings, samples=int(samples[s]), hits=int(hits[s]),
                         median_snr=float(median[s]), distance_m=float(distance[s]))
                 for s in range(layout.count))


def nearest_obstacle(sectors: tuple[SectorDistance, ...], data: SectorInput,
                     layout: SectorLayout) -> SectorDistance | None:
    """The VALID sector with the smallest distance, its bearing taken from the obstacle
    points at or nearer than that distance (radians, 0 ahead, positive left)."""
    valid = [s for s in sectors if s.state is SectorState.VALID]
    if not valid:
        return None
    best = min(valid, key=lambda s: s.distance_m)
    idx, rng = data.placed(layout)
    near = data.obstacle & (idx == best.index) & (rng <= best.distance_m + 1e-9)
    if near.any():
        p = data.points[near]
        bearing = float(np.arctan2(p[:, 1], p[:, 0]).mean())
        return SectorDistance(best.index, bearing, best.state, best.distance_m,
                              best.confidence, best.point_count)
    return best


class ClosingTracker:
    """Closing speed (m/s, > 0 approaching) and time to collision (s) of the nearest
    obstacle, from a least-squares slope over the last few frames.

    The history restarts when the nearest obstacle disappears, jumps by more than
    ``max_jump_m`` (a different object) or is older than ``window_s``.
    """

    def __init__(self, window_s: float = 1.0, max_frames: int = 6,
                 max_jump_m: float = 0.75, min_closing_mps: float = 0.05) -> None:
        self.window_s = window_s
        self.max_jump_m = max_jump_m
        self.min_closing_mps = min_closing_mps
        self._history: deque[tuple[float, float]] = deque(maxlen=max_frames)

    def update(self, distance_m: float | None, time_s: float) -> tuple[float | None,
                                                                       float | None]:
        """Add one frame; returns (closing speed m/s or None, time to collision s or None)."""
        if distance_m is None:
            self._history.clear()
            return None, None
        if self._history and abs(distance_m - self._history[-1][1]) > self.max_jump_m:
            self._history.clear()
        self._history.append((time_s, distance_m))
        while self._history and time_s - self._history[0][0] > self.window_s:
            self._history.popleft()
        return self._estimate(distance_m)

    def _estimate(self, distance_m: float) -> tuple[float | None, float | None]:
        if len(self._history) < 3:
            return None, None
        t, d = np.array(self._history).T
        if np.ptp(t) <= 0:
            return None, None
        dt = t - t.mean()  # least-squares slope in closed form (np.polyfit: 10x the time)
        closing = -float(dt @ (d - d.mean()) / (dt @ dt))
        ttc = distance_m / closing if closing > self.min_closing_mps else None
        return closing, ttc
