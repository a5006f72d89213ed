"""A calibration error handed to the pipeline: the ``[miscalibration]`` table of a scene.

The renderer always uses the scene's true projector, camera and mounting; the pipeline of
the simulated unit gets them off by the stated amounts (:meth:`Miscalibration.calibration`,
:meth:`Miscalibration.mounting`), applied in one place, ``Simulator`` (its
``calibration()`` and ``mounting``), so ``atris sim``, the benches and the node's simulated
camera all measure with the same wrong values. The unit cannot know its calibration is off.

Keys (all optional, defaults leave the calibration true): ``baseline_scale`` (b' = b · scale
+ offset), ``baseline_offset_m``, ``alpha_offset_deg`` (one number for every line, or one
per line in the order of ``projector.alpha_deg``), ``focal_offset_px``, ``cx_offset_px``,
``cy_offset_px``, ``mounting_z_offset_m``, ``mounting_pitch_offset_deg``,
``mounting_roll_offset_deg``, ``mounting_yaw_offset_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from atris_node.calibration import Calibration, CameraModel
from atris_node.mounting import Mounting
from atris_node.sim import schema as s

F = s.Field
#: largest α offset accepted, degrees (beyond it lines would swap their order)
ALPHA_OFFSET_MAX_DEG = 1.0
_KEYS = {
    "baseline_scale": F(float, 1.0, s.within(0.5, 2.0)),
    "baseline_offset_m": F(float, 0.0, s.within(-0.1, 0.1)),
    "alpha_offset_deg": F("floats", (0.0,), s.within(-ALPHA_OFFSET_MAX_DEG,
                                                     ALPHA_OFFSET_MAX_DEG)),
    "focal_offset_px": F(float, 0.0, s.within(-100.0, 100.0)),
    "cx_offset_px": F(float, 0.0, s.within(-100.0, 100.0)),
    "cy_offset_px": F(float, 0.0, s.within(-100.0, 100.0)),
    "mounting_z_offset_m": F(float, 0.0, s.within(-1.0, 1.0)),
    "mounting_pitch_offset_deg": F(float, 0.0, s.within(-10.0, 10.0)),
    "mounting_roll_offset_deg": F(float, 0.0, s.within(-10.0, 10.0)),
    "mounting_yaw_offset_deg": F(float, 0.0, s.within(-10.0, 10.0)),
}


@dataclass(frozen=True)
class Miscalibration:
    """Offsets of the pipeline's calibration from the truth. ``alpha_offset_rad`` holds one
    offset per line in calibration order (top of the image first), or nothing for none;
    the others are scalars (dimensionless scale, m, px, rad)."""

    baseline_scale: float = 1.0
    baseline_offset_m: float = 0.0
    alpha_offset_rad: tuple[float, ...] = ()
    focal_offset_px: float = 0.0
    cx_offset_px: float = 0.0
    cy_offset_px: float = 0.0
    mounting_z_offset_m: float = 0.0
    mounting_pitch_offset_rad: float = 0.0
    mounting_roll_offset_rad: float = 0.0
    mounting_yaw_offset_rad: float = 0.0

    def calibration(self, truth: Calibration) -> Calibration:
        """The calibration the pipeline gets for the true ``truth``."""
        cam, laser = truth.camera, truth.laser
        camera = CameraModel(cam.width_px, cam.height_px, cam.focal_px + self.focal_offset_px,
                             cam.cx_px + self.cx_offset_px, cam.cy_px + self.cy_offset_px,
                             cam.distortion)
        offsets = self.alpha_offset_rad or (0.0,) * len(laser.alpha_rad)
        alpha = tuple(a + d for a, d in zip(laser.alpha_rad, offsets, strict=True))
        baseline = laser.baseline_m * self.baseline_scale + self.baseline_offset_m
        return Calibration(camera, replace(laser, baseline_m=baseline, alpha_rad=alpha))

    def mounting(self, truth: Mounting) -> Mounting:
        """The mounting pose the pipeline gets for the true pose ``truth``."""
        return replace(truth, z_m=truth.z_m + self.mounting_z_offset_m,
                       pitch_rad=truth.pitch_rad + self.mounting_pitch_offset_rad,
                       roll_rad=truth.roll_rad + self.mounting_roll_offset_rad,
                       yaw_rad=truth.yaw_rad + self.mounting_yaw_offset_rad)


def parse_miscalibration(table: Any, alpha_deg: tuple[float, ...],
                         order: list[int], baseline_m: float) -> Miscalibration:
    """Validate a ``[miscalibration]`` table for a projector with file-order angles
    ``alpha_deg`` renumbered by ``order`` (calibration index -> file index); raises
    ConfigError naming the key."""
    if isinstance(table, dict) and isinstance(table.get("alpha_offset_deg"), int | float):
        table = {**table, "alpha_offset_deg": [table["alpha_offset_deg"]]}
    v = s.read_table(table, "miscalibration", _KEYS)
    offsets = v.pop("alpha_offset_deg")
    if len(offsets) not in (1, len(alpha_deg)):
        raise s.fail("miscalibration.alpha_offset_deg", "must be one number or one per "
                     f"line of projector.alpha_deg ({len(alpha_deg)})", list(offsets))
    per_line = offsets * len(alpha_deg) if len(offsets) == 1 else offsets
    _check_order([alpha_deg[i] + per_line[i] for i in order])
    if baseline_m * v["baseline_scale"] + v["baseline_offset_m"] <= 0:
        raise s.fail("miscalibration.baseline_offset_m", "must leave the baseline > 0",
                     v["baseline_offset_m"])
    alpha = tuple(math.radians(per_line[i]) for i in order)
    return Miscalibration(
        alpha_offset_rad=alpha if any(alpha) else (),
        **{k.replace("_deg", "_rad"): math.radians(x) if k.endswith("_deg") else x
           for k, x in v.items()})


def _check_order(alpha_deg: list[float]) -> None:
    """The erred angles must stay in (0.1, 179.9) degrees and keep the lines' order."""
    cot = [1.0 / math.tan(math.radians(a)) for a in alpha_deg]
    if not all(0.1 < a < 179.9 for a in alpha_deg) or cot != sorted(cot):
        raise s.fail("miscalibration.alpha_offset_deg", "must keep every angle in "
                     "(0.1, 179.9) deg and the lines in their order", alpha_deg)
