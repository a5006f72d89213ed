"""Frames and the camera's mounting pose on the vehicle.

Camera frame (the paper's Eq. 1): x to the right (image column v grows), y down (image
row u grows), z forward along the optical axis; metres. ``u`` and ``v`` are measured in
pixels from the principal point. The projector sits at (0, -b, 0): a baseline b > 0 puts
it above the camera. Projected line k is the plane ``y = z * cot(alpha_k) - b``; its image
row tends to ``u = f * cot(alpha_k)`` (the singular row) as the range goes to infinity.

Vehicle frame (ISO 8855): x forward, y left, z up; metres, origin on the ground below
the reference point. Bearing is ``atan2(y, x)``: 0 straight ahead, positive to the left.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError

#: camera axes expressed in the vehicle frame for a camera looking straight ahead:
#: camera x (right) = -vehicle y, camera y (down) = -vehicle z, camera z (fwd) = vehicle x.
_CAMERA_TO_VEHICLE_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _rotation_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> npt.NDArray[np.float64]:
    """Rotation about vehicle x (roll), y (pitch, positive nose down), z (yaw)."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


@dataclass(frozen=True)
class Mounting:
    """Pose of the camera on the vehicle: position in metres, angles in radians.

    ``pitch_rad`` > 0 tilts the camera down towards the ground.
    """

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.5
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        values = (self.x_m, self.y_m, self.z_m, self.roll_rad, self.pitch_rad, self.yaw_rad)
        if not all(np.isfinite(v) for v in values):
            raise ConfigError(f"mounting pose must be finite numbers, got {values}")
        if abs(self.pitch_rad) >= np.pi / 2:
            raise ConfigError(f"mounting pitch_rad must be within ±pi/2, got {self.pitch_rad}")

    @cached_property
    def rotation(self) -> npt.NDArray[np.float64]:
        """3×3 matrix taking camera-frame vectors to vehicle-frame vectors (read-only,
        computed once: every map's points go through it)."""
        rotation = _rotation_rpy(self.roll_rad, self.pitch_rad, self.yaw_rad) @ (
            _CAMERA_TO_VEHICLE_LEVEL)
        rotation.flags.writeable = False
        return rotation

    @cached_property
    def translation(self) -> npt.NDArray[np.float64]:
        """Camera centre in the vehicle frame, metres, shape (3,) (read-only)."""
        translation = np.array([self.x_m, self.y_m, self.z_m])
        translation.flags.writeable = False
        return translation

    def camera_to_vehicle(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Map (..., 3) camera-frame points (m) to the vehicle frame (m).

        >>> Mounting(z_m=1.0).camera_to_vehicle([0.0, 0.0, 2.0]).tolist()
        [2.0, 0.0, 1.0]
        """
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {p.shape}")
        return p @ self.rotation.T + self.translation

    def vehicle_to_camera(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Map (..., 3) vehicle-frame points (m) to the camera frame (m)."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {p.shape}")
        return (p - self.translation) @ self.rotation
