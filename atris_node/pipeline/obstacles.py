"""From vehicle-frame points to what the sectors need: ground, nearest obstacle, closing.

Points are (n, 3) float64 in the vehicle frame (ISO 8855: x forward, y left, z up,
metres). A point is an *obstacle* when it is a valid return and higher than the ground
clearance above the ground plane. The sector verdicts themselves (VALID at the nearest
credible distance, NO_RETURN only when earned, INVALID otherwise) are made by
:mod:`atris_node.pipeline.verdicts` from a :class:`SectorInput` and the columns'
evidence (:mod:`atris_node.pipeline.evidence`).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError
from atris_node.pipeline.geometry import rows_where
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
    near = rows_where(points, np.abs(previous.height(points)) < GROUND_SEARCH_M)
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
    """How sector verdicts are made (atris_node.pipeline.verdicts): the points a distance
    needs, the confidence (0..1) it needs, the peak SNR threshold, the largest
    standard error a VALID distance d may have: max(``max_sigma_rel``·d, ``max_sigma_m``),
    and the near end of the operating range ``z_min_m`` (camera z, m; 0: none)."""

    min_points: int = 5
    min_confidence: float = 0.2
    snr_min: float = 6.0
    max_sigma_rel: float = 0.015
    max_sigma_m: float = 0.025
    z_min_m: float = 0.0

    def sigma_limit_m(self, distance_m: float) -> float:
        """The largest standard error (m) of a VALID distance ``distance_m``."""
        return max(self.max_sigma_rel * distance_m, self.max_sigma_m)

    def __post_init__(self) -> None:
        if self.min_points < 1:
            raise ConfigError(f"min_points must be >= 1, got {self.min_points}")
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ConfigError(f"min_confidence must be in [0, 1], got {self.min_confidence}")
        if not (self.max_sigma_rel > 0.0 and self.max_sigma_m > 0.0):
            raise ConfigError(f"max_sigma_rel and max_sigma_m must be > 0, got "
                              f"{self.max_sigma_rel} and {self.max_sigma_m}")


@dataclass(frozen=True)
class SectorInput:
    """Per-sample arrays (n,) for the sector verdicts and :func:`nearest_obstacle`.

    ``points`` (n, 3) vehicle frame (for a no-return sample: a point on its ray, used
    for the bearing only); ``obstacle`` True for valid returns above the ground clearance;
    ``snr`` the line-peak SNR of each sample; ``height_m`` their height (m) above the
    ground plane the sector stage judges with, when already computed (None: computed
    from ``points`` where needed).
    """

    points: FloatArray
    obstacle: BoolArray
    snr: FloatArray
    height_m: FloatArray | None = None
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
        p = rows_where(data.points, near)
        bearing = float(np.arctan2(p[:, 1], p[:, 0]).mean())
        return SectorDistance(best.index, bearing, best.state, best.distance_m,
                              best.confidence, best.point_count)
    return best


class ClosingTracker:
    """Closing speed (m/s, > 0 approaching) and time to collision (s) of the nearest
    obstacle, from a least-squares fit over the last few frames: a line, or a parabola
    once four frames show a closing acceleration (ACCELERATION_SIGMAS from zero; the time
    to collision then solves the motion with it).

    A map integrates its window, so its distance belongs to the window's middle time;
    the time to collision is counted from the newest sub-frame (``now_s``): the distance
    at the middle, less what the obstacle closed since, over the closing speed. A value
    the fit does not support is None: the closing speed when its standard error (from
    the fit's residuals and the distances' σ, at least MIN_SIGMA_M, the larger: three
    points can lie on a line by chance) exceeds max(MAX_REL_SE · |closing|,
    MAX_ABS_SE_MPS); the time to collision unless the obstacle closes faster than
    ``min_closing_mps`` with a standard error within TTC_REL_SE of it (a time to
    collision half the true one needs the closing speed twice the true one: an error of
    at least 4 standard errors then).

    The history restarts when the nearest obstacle disappears, jumps by more than
    ``max_jump_m`` (a different object) or is older than ``window_s``, and when a map is
    not newer than the last (a clock that stepped back, a map given twice).
    """

    #: largest standard error of a published closing speed, relative and absolute (m/s)
    MAX_REL_SE = 0.25
    MAX_ABS_SE_MPS = 0.1
    #: largest standard error of the closing speed behind a published time to collision
    TTC_REL_SE = 0.125
    #: the least distance σ assumed per frame, m
    MIN_SIGMA_M = 0.02

    def __init__(self, window_s: float = 1.0, max_frames: int = 6,
                 max_jump_m: float = 0.75, min_closing_mps: float = 0.05) -> None:
        self.window_s = window_s
        self.max_jump_m = max_jump_m
        self.min_closing_mps = min_closing_mps
        self._history: deque[tuple[float, float, float]] = deque(maxlen=max_frames)

    def update(self, distance_m: float | None, time_s: float, now_s: float | None = None,
               sigma_m: float = 0.0) -> tuple[float | None, float | None]:
        """Add one frame: the distance (m, σ ``sigma_m``) at ``time_s`` (s, the window's
        middle), the newest sub-frame at ``now_s`` (default ``time_s``). Returns (closing
        speed m/s or None, time to collision s or None)."""
        if distance_m is None:
            self._history.clear()
            return None, None
        if self._history and (abs(distance_m - self._history[-1][1]) > self.max_jump_m
                              or time_s <= self._history[-1][0]):
            self._history.clear()  # another object, or a map not newer than the last
        self._history.append((time_s, distance_m, max(sigma_m, self.MIN_SIGMA_M)))
        while self._history and time_s - self._history[0][0] > self.window_s:
            self._history.popleft()
        return self._estimate(distance_m, time_s, time_s if now_s is None else now_s)

    def _estimate(self, distance_m: float, time_s: float, now_s: float
                  ) -> tuple[float | None, float | None]:
        if len(self._history) < 3:
            return None, None
        t, d, sigma = np.array(self._history).T
        if np.ptp(t) <= 0:
            return None, None
        accelerating = _accelerating(t - now_s, d, sigma) if len(t) >= 4 else None
        if accelerating is None:
            closing, se = _closing_line(t, d, sigma)
            d_now, accel = distance_m - closing * max(now_s - time_s, 0.0), 0.0
        else:
            d_now, closing, accel, se = accelerating
        if se > max(self.MAX_REL_SE * abs(closing), self.MAX_ABS_SE_MPS):
            return None, None
        if closing <= self.min_closing_mps or se > self.TTC_REL_SE * closing:
            return closing, None
        return closing, _time_to_reach(max(d_now, 0.0), closing, accel)


#: a closing acceleration is used once it stands this many standard errors from zero
ACCELERATION_SIGMAS = 5.0


def _closing_line(t: FloatArray, d: FloatArray, sigma: FloatArray) -> tuple[float, float]:
    """Closing speed (m/s, minus the least-squares slope of ``d`` over ``t``) and its
    standard error (from the residuals and from ``sigma``, the larger)."""
    dt = t - t.mean()  # closed form (np.polyfit: 10x the time)
    spread = float(dt @ dt)
    closing = -float(dt @ (d - d.mean()) / spread)
    residual = d - d.mean() + closing * dt
    se = max(math.sqrt(float(residual @ residual) / max(len(t) - 2, 1) / spread),
             float(np.sqrt((sigma * sigma) @ (dt * dt))) / spread)
    return closing, se


def _accelerating(x: FloatArray, d: FloatArray, sigma: FloatArray
                  ) -> tuple[float, float, float, float] | None:
    """(distance now m, closing speed now m/s, closing acceleration m/s², closing speed's
    standard error) of a parabola ``d = p0 + p1 x + p2 x²`` fitted over ``x`` (s before
    now, <= 0), when its curvature stands ACCELERATION_SIGMAS standard errors from zero
    (error from the residuals and from ``sigma``, the larger); None otherwise (a
    constant closing speed explains the track)."""
    if np.unique(x).size < 3:
        return None  # a parabola needs three times (repeated ones pin down a line at most)
    design = np.stack([np.ones_like(x), x, x * x], axis=1)
    p, *_ = np.linalg.lstsq(design, d, rcond=None)
    residual = d - design @ p
    variance = max(float(residual @ residual) / max(len(x) - 3, 1),
                   float(np.mean(sigma * sigma)))
    normal = design.T @ design
    if abs(float(np.linalg.det(normal))) < 1e-18:
        return None
    cov = variance * np.linalg.inv(normal)
    if not (cov[1, 1] > 0.0 and cov[2, 2] > 0.0 and np.isfinite(cov).all()):
        return None  # rounding in a near-singular inverse: the times do not pin it down
    se_curve, se_slope = math.sqrt(float(cov[2, 2])), math.sqrt(float(cov[1, 1]))
    if abs(float(p[2])) <= ACCELERATION_SIGMAS * se_curve:
        return None
    return float(p[0]), -float(p[1]), -2.0 * float(p[2]), se_slope


def _time_to_reach(distance_m: float, closing_mps: float, accel_mps2: float) -> float | None:
    """Seconds until ``distance_m`` closes at ``closing_mps`` speeding up at
    ``accel_mps2`` (the first positive root of d - v τ - a τ²/2 = 0); None when it stops
    closing first."""
    if abs(accel_mps2) < 1e-9:
        return distance_m / closing_mps
    disc = closing_mps * closing_mps + 2.0 * accel_mps2 * distance_m
    if disc < 0.0:
        return None  # decelerating: it stops before it arrives
    roots = [(-closing_mps + sign * math.sqrt(disc)) / accel_mps2 for sign in (1.0, -1.0)]
    ahead = [r for r in roots if r >= 0.0]
    return min(ahead) if ahead else None
