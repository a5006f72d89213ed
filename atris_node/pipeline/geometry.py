"""Triangulation of line samples (paper Eq. 1), error propagation and lens distortion.

Conventions are those of :mod:`atris_node.mounting`: ``u`` is the undistorted image row and
``v`` the column, both in pixels from the principal point; camera x right, y down, z
forward; the projector at (0, -b, 0); line k is the plane ``y = z·cot α_k - b``, so

    [x y z] = b / (f·cot α_k - u) · [v, u, f]                    (Eq. 1)

A denominator ``f·cot α_k - u <= 0`` (at or beyond the singular row) or a range beyond
``z_max`` is "no return": the point is flagged, never given an inf, NaN or negative range.

>>> import numpy as np
>>> from atris_node.calibration import CameraModel, LaserCalibration
>>> cam = CameraModel(640, 400, 400.0, 320.0, 200.0)
>>> laser = LaserCalibration(0.1, (np.pi / 2,))
>>> pts = triangulate(np.array([-20.0]), np.array([0.0]), np.array([0]), cam, laser,
...                   z_max_m=10.0)
>>> pts.xyz_m.round(3).tolist(), pts.valid.tolist()
([[0.0, -0.1, 2.0]], [True])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.errors import CalibrationError
from atris_node.jit import kernel

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
ScalarT = TypeVar("ScalarT", bound=np.generic)

#: smallest accepted Eq. 1 denominator f·cot α - u, pixels; below it the range is infinite
MIN_DENOMINATOR_PX = 1e-6
#: fixed-point iterations of the inverse distortion model (converges to < 1e-6 px for
#: the moderate distortion of machine-vision lenses)
UNDISTORT_ITERATIONS = 12


@dataclass(frozen=True)
class Points:
    """Triangulated line samples, all arrays of length n.

    Attributes:
        xyz_m: (n, 3) float64 camera-frame points, metres; rows where ``valid`` is False
            hold the point on the pixel ray at ``z = z_max`` (a direction, not a return).
        valid: (n,) bool, True where Eq. 1 gives a range in (0, z_max].
        sigma_z_m: (n,) float64 propagated range standard deviation, metres (0 where not
            valid).
    """

    xyz_m: FloatArray
    valid: BoolArray
    sigma_z_m: FloatArray


def _distortion_coefficients(camera: CameraModel) -> FloatArray:
    """(k1, k2, p1, p2, k3) as float64, zeros where the model gives fewer (OpenCV order)."""
    d = np.zeros(5)
    given = np.asarray(camera.distortion[:5], dtype=np.float64)
    d[: given.size] = given
    if any(abs(c) > 0 for c in camera.distortion[5:]):
        raise CalibrationError("only the k1, k2, p1, p2, k3 distortion model is supported, "
                               f"got {len(camera.distortion)} non-zero coefficients")
    return d


def _distort_normalised(x: FloatArray, y: FloatArray, d: FloatArray) -> tuple[FloatArray,
                                                                              FloatArray]:
    """Apply the OpenCV radial-tangential model to normalised coordinates (x, y)."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def distort_pixels(row: npt.ArrayLike, col: npt.ArrayLike,
                   camera: CameraModel) -> tuple[FloatArray, FloatArray]:
    """Ideal (undistorted) pixel positions -> observed pixel positions (row, col), float64."""
    f = camera.focal_px
    x = (np.asarray(col, np.float64) - camera.cx_px) / f
    y = (np.asarray(row, np.float64) - camera.cy_px) / f
    xd, yd = _distort_normalised(x, y, _distortion_coefficients(camera))
    return yd * f + camera.cy_px, xd * f + camera.cx_px


def undistort_pixels(row: npt.ArrayLike, col: npt.ArrayLike,
                     camera: CameraModel) -> tuple[FloatArray, FloatArray]:
    """Observed pixel (row, col) -> (u, v): undistorted pixels from the principal point.

    Vectorised fixed-point inverse of the OpenCV k1, k2, p1, p2, k3 model (what
    ``cv2.undistortPoints`` does), float64 in and out, any matching shapes.
    """
    f = camera.focal_px
    xd = (np.asarray(col, np.float64) - camera.cx_px) / f
    yd = (np.asarray(row, np.float64) - camera.cy_px) / f
    d = _distortion_coefficients(camera)
    if not d.any():
        return yd * f, xd * f
    x, y = xd.copy(), yd.copy()
    for _ in range(UNDISTORT_ITERATIONS):
        xe, ye = _distort_normalised(x, y, d)
        x, y = x - (xe - xd), y - (ye - yd)
    return y * f, x * f


def line_row_at_range(line: int, z_m: float, camera: CameraModel,
                      laser: LaserCalibration) -> float:
    """Undistorted row ``u = f·cot α_k - f·b/z`` of line k at range z (pixels from cy)."""
    f = camera.focal_px
    return float(f / np.tan(laser.alpha_rad[line]) - f * laser.baseline_m / z_m)


def singular_rows(camera: CameraModel, laser: LaserCalibration) -> FloatArray:
    """(K,) float64 singular rows ``u = f·cot α_k`` (pixels from cy, may be far off-image)."""
    return camera.focal_px / np.tan(np.asarray(laser.alpha_rad, dtype=np.float64))


def triangulate(u_px: npt.ArrayLike, v_px: npt.ArrayLike, line: npt.ArrayLike,
                camera: CameraModel, laser: LaserCalibration, *, z_max_m: float,
                sigma_u_px: npt.ArrayLike = 0.0) -> Points:
    """Eq. 1 for n samples: (n,) undistorted u, v (px from the principal point), line index.

    ``sigma_u_px`` (scalar or (n,)) gives ``sigma_z ≈ z²·σ_u / (f·b)``. Returns
    :class:`Points`; a denominator <= 0 or ``z > z_max_m`` is not valid. One compiled
    pass (:func:`_eq1`) over the samples flattened (any matching shapes; ``xyz_m`` is
    their shape plus (3,)).
    """
    return _triangulated(u_px, v_px, line, camera, laser, z_max_m, sigma_u_px, _UNDISTORTED)


def triangulate_pixels(row_px: npt.ArrayLike, col_px: npt.ArrayLike, line: npt.ArrayLike,
                       camera: CameraModel, laser: LaserCalibration, *, z_max_m: float,
                       sigma_u_px: npt.ArrayLike = 0.0) -> Points:
    """:func:`triangulate` of observed (distorted) pixel rows and columns, undistorted
    first (:func:`undistort_pixels`); for a camera without distortion the two in one
    compiled pass (the same numbers)."""
    if any(camera.distortion):
        u, v = undistort_pixels(row_px, col_px, camera)
        return triangulate(u, v, line, camera, laser, z_max_m=z_max_m, sigma_u_px=sigma_u_px)
    return _triangulated(row_px, col_px, line, camera, laser, z_max_m, sigma_u_px,
                         np.array([camera.cy_px, camera.cx_px], dtype=np.float64))


#: :func:`_eq1`'s ``centre`` for rows and columns already undistorted (u, v)
_UNDISTORTED = np.zeros(0)


def _triangulated(u_px: npt.ArrayLike, v_px: npt.ArrayLike, line: npt.ArrayLike,
                  camera: CameraModel, laser: LaserCalibration, z_max_m: float,
                  sigma_u_px: npt.ArrayLike, centre: FloatArray) -> Points:
    """:func:`triangulate` (``centre`` empty) or :func:`triangulate_pixels` without
    distortion (``centre`` (cy, cx) px)."""
    u, v = np.asarray(u_px, dtype=np.float64), np.asarray(v_px, dtype=np.float64)
    k, sigma = np.asarray(line, dtype=np.int64), np.asarray(sigma_u_px, dtype=np.float64)
    if not (u.shape == v.shape == k.shape and sigma.shape in ((), u.shape)):
        u, v, k, sigma = np.broadcast_arrays(u, v, k, sigma)
    shape = u.shape
    xyz, valid, sigma_z = _eq1(np.ascontiguousarray(u).reshape(-1),
                               np.ascontiguousarray(v).reshape(-1),
                               np.ascontiguousarray(k).reshape(-1), sigma.reshape(-1),
                               singular_rows(camera, laser), float(camera.focal_px),
                               float(laser.baseline_m), float(z_max_m), centre)
    return Points(xyz_m=xyz.reshape(*shape, 3), valid=valid.reshape(shape),
                  sigma_z_m=sigma_z.reshape(shape))


@kernel("Tuple((float64[:, ::1], boolean[::1], float64[::1]))(float64[::1], float64[::1], "
        "int64[::1], float64[:], float64[::1], float64, float64, float64, float64[::1])")
def _eq1(u: FloatArray, v: FloatArray, line: IntArray, sigma_u: FloatArray,
         singular: FloatArray, f: float, b: float, z_max_m: float, centre: FloatArray
         ) -> tuple[FloatArray, BoolArray, FloatArray]:
    """(n, 3) points m, (n,) valid and (n,) σ_z m of Eq. 1 at (n,) u, v px, line (a
    negative one counted from the last, as numpy indexes; beyond the lines: IndexError)
    and σ_u px ((n,), or (1,) for every sample; any strides), with the (K,) ``singular``
    rows px: as the array steps, ``scale = b / (f·cot α - u)`` where that denominator
    exceeds MIN_DENOMINATOR_PX and ``scale·f <= z_max``, else ``z_max / f``;
    ``[v, u, f]·scale``; ``σ_z = z·z·σ_u / (f·b)`` where valid, else 0. With ``centre``
    (cy, cx) px, ``u`` and ``v`` are observed rows and columns of a camera without
    distortion, undistorted first as :func:`undistort_pixels` does (``(row - cy) / f ·
    f``); empty: they are undistorted already."""
    n = u.size
    xyz = np.empty((n, 3))
    valid = np.empty(n, dtype=np.bool_)
    sigma_z = np.empty(n)
    lines = singular.size
    fb = f * b
    far = z_max_m / f
    pixels = centre.size == 2
    for i in range(n):
        k = line[i] + lines if line[i] < 0 else line[i]
        if k < 0 or k >= lines:
            raise IndexError("a line beyond the calibrated lines")
        ui = (u[i] - centre[0]) / f * f if pixels else u[i]
        vi = (v[i] - centre[1]) / f * f if pixels else v[i]
        denominator = singular[k] - ui
        ok = denominator > MIN_DENOMINATOR_PX
        scale = b / denominator if ok else 0.0
        good = ok and scale * f <= z_max_m
        if not good:
            scale = far
        xyz[i, 0] = vi * scale
        xyz[i, 1] = ui * scale
        z = f * scale
        xyz[i, 2] = z
        valid[i] = good
        sigma = sigma_u[0] if sigma_u.size == 1 else sigma_u[i]
        sigma_z[i] = z * z * sigma / fb if good else 0.0
    return xyz, valid, sigma_z


def rows_where(array: npt.NDArray[ScalarT], mask: BoolArray) -> npt.NDArray[ScalarT]:
    """``array[mask]`` for an (n, ...) ``array`` and an (n,) bool ``mask``: the rows where
    it is True, in order (a copy). By the rows' indices (``take``): numpy's boolean
    indexing of an (n, 3) array costs ten times as much (33 against 3.5 µs at 2900
    rows)."""
    return array.take(np.flatnonzero(mask), axis=0)


def range_sigma(z_m: npt.ArrayLike, sigma_u_px: float, focal_px: float,
                baseline_m: float) -> FloatArray:
    """Propagated range standard deviation ``z²·σ_u / (f·b)``, metres (float64)."""
    z = np.asarray(z_m, dtype=np.float64)
    return z * z * sigma_u_px / (focal_px * baseline_m)
