"""Synthetic board views with a known camera, for tests and ``atris calib simulate``.

A view is the board texture warped through ``H = K [r1 r2 t] A⁻¹`` (A maps board metres
to texture pixels), then blurred and given Gaussian noise. Laser lines on the board are
drawn from the geometry: the intersection of each light plane ``y = z·cot α_k − b``
(camera frame, see :mod:`atris_node.mounting`) with the board plane, as a Gaussian
stripe across the board. The camera's lens distortion (OpenCV k1, k2, p1, p2, k3) is
applied to both: views by remapping every pixel through the inverse distortion, line
rows by distorting a dense set of ideal samples.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.pipeline.geometry import distort_pixels, undistort_pixels
from calib.board import BoardSpec, texture

PX_PER_SQUARE = 120
MARGIN_SQUARES = 1
#: views are rendered at this many times the resolution and averaged down (anti-aliasing)
SUPERSAMPLE = 3


@dataclass(frozen=True)
class BoardPose:
    """Board-to-camera pose: rotation vector (3,) and translation (3,) in metres."""

    rvec: npt.NDArray[np.float64]
    tvec: npt.NDArray[np.float64]

    @property
    def rotation(self) -> npt.NDArray[np.float64]:
        """3×3 rotation matrix, board frame to camera frame."""
        return np.asarray(cv2.Rodrigues(self.rvec)[0], dtype=np.float64)

    def plane(self) -> tuple[npt.NDArray[np.float64], float]:
        """Board plane in the camera frame as (unit normal n (3,), d): n·X = d."""
        normal = self.rotation[:, 2]
        return normal, float(normal @ self.tvec)


def _corners_in_view(spec: BoardSpec, camera: CameraModel, pose: BoardPose,
                     margin_px: float) -> bool:
    w, h = spec.size_m
    corners = np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]], dtype=np.float64)
    distortion = np.asarray(camera.distortion) if any(camera.distortion) else None
    points, _ = cv2.projectPoints(corners, pose.rvec, pose.tvec, camera.matrix, distortion)
    uv = points.reshape(-1, 2)
    return bool(np.all(uv >= margin_px) and np.all(uv[:, 0] <= camera.width_px - margin_px)
                and np.all(uv[:, 1] <= camera.height_px - margin_px))


def _random_pose(spec: BoardSpec, rng: np.random.Generator, distance_m: float,
                 tilt_deg: float, centre_y_m: float) -> BoardPose:
    tilt = np.radians(rng.uniform(-tilt_deg, tilt_deg, size=2))
    roll = np.radians(rng.uniform(-15.0, 15.0))
    tilted = cv2.Rodrigues(np.array([tilt[0], tilt[1], 0.0]))[0]
    rolled = cv2.Rodrigues(np.array([0.0, 0.0, roll]))[0]
    rvec = np.asarray(cv2.Rodrigues(tilted @ rolled)[0], dtype=np.float64).ravel()
    rotation = np.asarray(cv2.Rodrigues(rvec)[0], dtype=np.float64)
    centre = np.array([spec.size_m[0] / 2, spec.size_m[1] / 2, 0.0])
    target = np.array([rng.uniform(-0.1, 0.1) * distance_m,
                       centre_y_m + rng.uniform(-0.08, 0.08) * distance_m, distance_m])
    return BoardPose(rvec, target - rotation @ centre)


def random_poses(spec: BoardSpec, camera: CameraModel, count: int, rng: np.random.Generator,
                 *, distance_m: tuple[float, float] = (0.6, 1.3), tilt_deg: float = 30.0,
                 aim_y: tuple[float, float] = (0.0, 0.0)) -> list[BoardPose]:
    """``count`` board poses fully in view (20 px margin), distances spread over the range.

    The board centre is aimed at camera ``y = aim_y[0]·z + aim_y[1]`` (m), plus jitter.
    """
    poses: list[BoardPose] = []
    for distance in np.linspace(*distance_m, count):
        for _ in range(200):
            centre_y = aim_y[0] * float(distance) + aim_y[1]
            pose = _random_pose(spec, rng, float(distance), tilt_deg, centre_y)
            if _corners_in_view(spec, camera, pose, 20.0):
                poses.append(pose)
                break
    return poses


def _texture_to_image(spec: BoardSpec, camera: CameraModel, pose: BoardPose,
                      supersample: int = 1) -> npt.NDArray[np.float64]:
    scale = PX_PER_SQUARE / spec.square_m
    offset = MARGIN_SQUARES * PX_PER_SQUARE - 0.5  # pixel centres sit at integers
    metres_to_texture = np.array([[scale, 0.0, offset], [0.0, scale, offset], [0, 0, 1.0]])
    rotation = pose.rotation
    fine = np.array([[supersample, 0.0, (supersample - 1) / 2],
                     [0.0, supersample, (supersample - 1) / 2], [0.0, 0.0, 1.0]])
    board_to_image = fine @ camera.matrix @ np.column_stack([rotation[:, 0], rotation[:, 1],
                                                             pose.tvec])
    return board_to_image @ np.linalg.inv(metres_to_texture)


@functools.lru_cache(maxsize=1)
def _ideal_fine_grid(camera: CameraModel, supersample: int
                     ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """For each pixel of the observed (distorted) fine grid, its ideal fine position
    (column, row) under the camera's lens distortion; each (H·s, W·s) float64."""
    s, half = supersample, (supersample - 1) / 2
    rows, cols = np.mgrid[0:camera.height_px * s, 0:camera.width_px * s].astype(np.float64)
    u_px, v_px = undistort_pixels((rows - half) / s, (cols - half) / s, camera)
    return (v_px + camera.cx_px) * s + half, (u_px + camera.cy_px) * s + half


def _warp(board: npt.NDArray[np.float32], homography: npt.NDArray[np.float64],
          camera: CameraModel) -> npt.NDArray[np.float32]:
    """The board texture seen through ``homography`` (texture to ideal fine pixels) and,
    when the camera has any, its lens distortion: (H·s, W·s) float32."""
    size = (camera.width_px * SUPERSAMPLE, camera.height_px * SUPERSAMPLE)
    if not any(camera.distortion):
        return np.asarray(cv2.warpPerspective(board, homography, size, flags=cv2.INTER_LINEAR,
                                              borderValue=110.0), dtype=np.float32)
    ideal_x, ideal_y = _ideal_fine_grid(camera, SUPERSAMPLE)
    inverse = np.linalg.inv(homography)
    w = inverse[2, 0] * ideal_x + inverse[2, 1] * ideal_y + inverse[2, 2]
    map_x = ((inverse[0, 0] * ideal_x + inverse[0, 1] * ideal_y + inverse[0, 2]) / w)
    map_y = ((inverse[1, 0] * ideal_x + inverse[1, 1] * ideal_y + inverse[1, 2]) / w)
    return np.asarray(cv2.remap(board, map_x.astype(np.float32), map_y.astype(np.float32),
                                cv2.INTER_LINEAR, borderValue=110.0), dtype=np.float32)


def render_board_view(spec: BoardSpec, camera: CameraModel, pose: BoardPose,
                      rng: np.random.Generator, *, noise_dn: float = 2.0,
                      blur_px: float = 0.7) -> npt.NDArray[np.uint8]:
    """(height_px, width_px) uint8 camera image of the board on a grey background, with
    the camera's lens distortion."""
    board = texture(spec, PX_PER_SQUARE, MARGIN_SQUARES * PX_PER_SQUARE).astype(np.float32)
    board = np.asarray(cv2.GaussianBlur(board * 0.8 + 20.0, (0, 0), 1.0))  # print: not 0, 255
    fine = _warp(board, _texture_to_image(spec, camera, pose, SUPERSAMPLE), camera)
    view = cv2.resize(fine, (camera.width_px, camera.height_px), interpolation=cv2.INTER_AREA)
    view = cv2.GaussianBlur(view, (0, 0), blur_px) if blur_px > 0 else view
    view = view + rng.normal(0.0, noise_dn, view.shape)
    return np.clip(np.rint(view), 0, 255).astype(np.uint8)


def _ideal_rows(camera: CameraModel, laser: LaserCalibration, pose: BoardPose,
                columns: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(K, n) ideal (undistorted) rows of each light plane on the board plane at the
    ideal ``columns`` (absolute pixels)."""
    normal, d = pose.plane()
    ray_x = (columns - camera.cx_px) / camera.focal_px
    rows = np.empty((len(laser.alpha_rad), len(columns)))
    for k, alpha in enumerate(laser.alpha_rad):
        # a point of plane k on the ray (x', y', 1)·z: y' = cot α − b/z, and n·X = d
        # gives z (n_x x' + n_y cot α + n_z) − n_y b = d
        z = (d + normal[1] * laser.baseline_m) / (
            normal[0] * ray_x + normal[1] / np.tan(alpha) + normal[2])
        rows[k] = camera.cy_px + camera.focal_px * (1.0 / np.tan(alpha) - laser.baseline_m / z)
    return rows


def laser_rows_on_board(spec: BoardSpec, camera: CameraModel, laser: LaserCalibration,
                        pose: BoardPose) -> npt.NDArray[np.float64]:
    """True line rows on the board: (K, width_px) float64 observed image rows (absolute
    pixels, lens distortion applied) of each light plane where it hits the board, -1.0
    for columns off the board."""
    if not any(camera.distortion):
        columns = np.arange(camera.width_px, dtype=np.float64)
        return _mask_off_board(spec, camera, pose, _ideal_rows(camera, laser, pose, columns),
                               columns)
    columns = np.linspace(-0.2 * camera.width_px, 1.2 * camera.width_px, 6 * camera.width_px)
    ideal = _ideal_rows(camera, laser, pose, columns)
    on_board = _mask_off_board(spec, camera, pose, ideal, columns) >= 0
    observed_rows, observed_cols = distort_pixels(ideal, np.broadcast_to(columns, ideal.shape),
                                                  camera)
    targets = np.arange(camera.width_px, dtype=np.float64)
    out = np.full((len(ideal), camera.width_px), -1.0)
    for k in range(len(ideal)):
        row = np.interp(targets, observed_cols[k], observed_rows[k])
        hit = np.interp(targets, observed_cols[k], on_board[k].astype(np.float64)) > 0.999
        out[k] = np.where(hit & (row >= 0) & (row <= camera.height_px - 1), row, -1.0)
    return out


def _mask_off_board(spec: BoardSpec, camera: CameraModel, pose: BoardPose,
                    rows: npt.NDArray[np.float64],
                    columns: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``rows`` (K, n) at ideal ``columns`` (n,), -1.0 where off the board or the image."""
    inverse = np.linalg.inv(_texture_to_image(spec, camera, pose))
    grid = np.broadcast_to(columns, rows.shape)
    pixels = np.stack([grid, rows, np.ones_like(rows)], axis=-1) @ inverse.T
    tex = pixels[..., :2] / pixels[..., 2:3]
    margin = MARGIN_SQUARES * PX_PER_SQUARE - 0.5
    limit = np.array([spec.squares_x, spec.squares_y]) * PX_PER_SQUARE
    on_board = np.all((tex >= margin) & (tex <= margin + limit), axis=-1)
    on_board &= (rows >= 0) & (rows <= camera.height_px - 1)
    return np.where(on_board, rows, -1.0)


def render_line_map(rows: npt.NDArray[np.float64], height_px: int, rng: np.random.Generator,
                    *, peak_dn: float = 400.0, sigma_px: float = 1.2,
                    noise_dn: float = 6.0) -> npt.NDArray[np.int32]:
    """A distortion map with Gaussian stripes at ``rows`` (K, W) (-1 = absent):
    (height_px, W) int32, peak ``peak_dn`` plus Gaussian noise."""
    grid = np.arange(height_px, dtype=np.float64)[:, None]
    image = np.zeros((height_px, rows.shape[1]))
    for line in rows:
        stripe = peak_dn * np.exp(-0.5 * ((grid - line[None, :]) / sigma_px) ** 2)
        image += np.where(line[None, :] >= 0, stripe, 0.0)
    image += rng.normal(0.0, noise_dn, image.shape)
    return np.rint(image).astype(np.int32)
