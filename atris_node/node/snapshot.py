"""Pictures of one moment of a unit: the plain sub-frame, the demodulated distortion map
(as the paper's figures 5-11 show them) and a top-down obstacle map.

All functions return 8-bit images (numpy arrays for ``cv2.imwrite``); nothing here runs
unless a snapshot is asked for.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from atris_node.pipeline.sectors import SectorLayout
from atris_node.types import DistortionMap, Measurement, SectorState, SubFrame

U8 = npt.NDArray[np.uint8]
#: pixels per metre of the top-down map, and its size in pixels
MAP_SCALE_PX_PER_M = 40.0
MAP_SIZE_PX = 480


def plain_image(sub: SubFrame) -> U8:
    """The raw sub-frame scaled from its bit depth to 8 bits."""
    shift = max(sub.bits - 8, 0)
    return (sub.pixels >> shift).astype(np.uint8) if shift else sub.pixels.astype(np.uint8)


def distortion_image(dmap: DistortionMap) -> U8:
    """Positive part of the distortion map, scaled so its 99.9th percentile is white."""
    positive = np.clip(dmap.values, 0, None).astype(np.float32)
    top = float(np.percentile(positive, 99.9)) if positive.size else 0.0
    scale = 255.0 / top if top > 0 else 0.0
    return np.clip(positive * scale, 0, 255).astype(np.uint8)


def _to_px(x_m: float, y_m: float) -> tuple[int, int]:
    """Vehicle (x forward, y left) to map pixels: vehicle at the bottom centre."""
    return (int(MAP_SIZE_PX / 2 - y_m * MAP_SCALE_PX_PER_M),
            int(MAP_SIZE_PX - 10 - x_m * MAP_SCALE_PX_PER_M))


def _draw_sector(image: U8, layout: SectorLayout, index: int, distance_m: float,
                 colour: tuple[int, int, int]) -> None:
    half = layout.width_rad / 2
    bearing = layout.bearing_of(index)
    arc = [_to_px(distance_m * math.cos(b), distance_m * math.sin(b))
           for b in np.linspace(bearing - half, bearing + half, 8)]
    cv2.polylines(image, [np.array([_to_px(0, 0), *arc, _to_px(0, 0)], np.int32)], True,
                  colour, 2)


def obstacle_map(measurement: Measurement | None, layout: SectorLayout,
                 points_vehicle_m: npt.NDArray[np.float64] | None, range_m: float) -> U8:
    """Top-down picture: points (grey), valid sectors (green), free (blue), invalid (red)."""
    image = np.zeros((MAP_SIZE_PX, MAP_SIZE_PX, 3), np.uint8)
    if points_vehicle_m is not None:
        for x, y in points_vehicle_m[:, :2]:
            cv2.circle(image, _to_px(float(x), float(y)), 1, (160, 160, 160), -1)
    for sector in measurement.sectors if measurement is not None else ():
        if sector.state is SectorState.VALID:
            _draw_sector(image, layout, sector.index, sector.distance_m, (0, 200, 0))
        elif sector.state is SectorState.NO_RETURN:
            _draw_sector(image, layout, sector.index, range_m, (200, 120, 0))
        else:
            _draw_sector(image, layout, sector.index, 0.5, (0, 0, 220))
    cv2.circle(image, _to_px(0, 0), 5, (255, 255, 255), -1)
    return image


def write_snapshot(directory: str | Path, stem: str, sub: SubFrame | None,
                   dmap: DistortionMap | None, top_down: U8 | None) -> list[Path]:
    """Write the pictures that exist as PNGs named ``stem_*.png``; returns their paths."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for suffix, image in (("plain", None if sub is None else plain_image(sub)),
                          ("demodulated", None if dmap is None else distortion_image(dmap)),
                          ("obstacles", top_down)):
        if image is not None:
            path = out / f"{stem}_{suffix}.png"
            cv2.imwrite(str(path), image)
            written.append(path)
    return written
