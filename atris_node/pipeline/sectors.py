"""Angular sectors in the vehicle frame: one definition for the pipeline and the simulator.

Sectors split the horizontal field of view ``[-fov/2, +fov/2]`` around the vehicle's x
axis (bearing 0 = straight ahead, positive to the left) into ``count`` equal slices,
index 0 at the right edge. The distance of a point is its horizontal range
``hypot(x, y)`` in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError
from atris_node.pipeline import verdicts_kernels


@dataclass(frozen=True)
class SectorLayout:
    """``count`` sectors over a horizontal field of view of ``fov_rad`` (0 < fov ≤ 2π)."""

    count: int = 8
    fov_rad: float = np.deg2rad(70.0)

    def __post_init__(self) -> None:
        if not 1 <= self.count <= 64:
            raise ConfigError(f"sector count must be 1..64, got {self.count}")
        if not 0.0 < self.fov_rad <= 2.0 * np.pi:
            raise ConfigError(f"sector fov_rad must be in (0, 2π], got {self.fov_rad}")

    @property
    def width_rad(self) -> float:
        """Angular width of one sector, radians."""
        return self.fov_rad / self.count

    def bearing_of(self, index: int) -> float:
        """Centre bearing of sector ``index``, radians."""
        return -self.fov_rad / 2.0 + (index + 0.5) * self.width_rad

    def index_of(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Sector index of vehicle-frame points; -1 outside the field of view: the floor of
        (bearing + fov/2) / width (one compiled pass after the bearings for (n,) points,
        :func:`atris_node.pipeline.verdicts_kernels.sector_index`)."""
        bearing = np.arctan2(np.asarray(y_m, dtype=np.float64), np.asarray(x_m, np.float64))
        if bearing.ndim == 1:
            return verdicts_kernels.sector_index(bearing, self.fov_rad / 2.0, self.width_rad,
                                                 self.count)
        idx = np.floor((bearing + self.fov_rad / 2.0) / self.width_rad).astype(np.int64)
        return np.where((idx >= 0) & (idx < self.count), idx, -1)

    @staticmethod
    def horizontal_range(x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Horizontal range ``hypot(x, y)`` in metres."""
        return np.hypot(np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64))
