"""Compiled ray-shape hits (numba, ``nopython``): one pass over the rays per shape.

Each kernel is the :meth:`intersect` of one shape of :mod:`atris_node.sim.raycast` with
the same formulas in the same order, but it writes only where its hit is nearer than the
best one so far (``best_t``, ``best_normal``, ``best_shape``, updated in place), which is
what :func:`atris_node.sim.raycast.cast` keeps. The numpy methods made 20-60 passes and
temporaries per shape; here the whole frame's rays cost about as much as one of them.

Arguments: ``origins`` (1, 3) (one origin for all rays) or (n, 3), ``directions`` (n, 3),
float64, any layout; shape parameters as float64 vectors (3,) or scalars, already moved
to the time asked. Dot products are summed left to right; numpy's matrix products may use
fused multiply-adds, so a hit can differ from the numpy method's in the last bits (1e-16
relative), never more.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
#: hits closer than this along a ray are ignored (as raycast.EPSILON_M), m
EPSILON_M = 1e-6
_MAX = np.finfo(np.float64).max


@kernel()
def _valid(t: float) -> float:
    return t if t > EPSILON_M else np.inf


@kernel()
def _keep(i: int, t: float, nx: float, ny: float, nz: float, index: int, best_t: FloatArray,
          best_normal: FloatArray, best_shape: IntArray) -> None:
    if t < best_t[i]:
        best_t[i] = t
        best_normal[i, 0], best_normal[i, 1], best_normal[i, 2] = nx, ny, nz
        best_shape[i] = index


@kernel()
def _dot(a: FloatArray, i: int, b: FloatArray) -> float:
    return a[i, 0] * b[0] + a[i, 1] * b[1] + a[i, 2] * b[2]


@kernel()
def plane_hits(origins: FloatArray, directions: FloatArray, point: FloatArray,
               normal: FloatArray, index: int, best_t: FloatArray, best_normal: FloatArray,
               best_shape: IntArray) -> None:
    """Plane through ``point`` with unit ``normal``."""
    one = origins.shape[0] == 1
    for i in range(directions.shape[0]):
        k = 0 if one else i
        denom = _dot(directions, i, normal)
        rel = ((point[0] - origins[k, 0]) * normal[0] + (point[1] - origins[k, 1]) * normal[1]
               + (point[2] - origins[k, 2]) * normal[2])
        t = _valid(rel / denom) if abs(denom) > 1e-12 else np.inf
        s = -1.0 if denom > 0 else 1.0
        _keep(i, t, s * normal[0], s * normal[1], s * normal[2], index, best_t, best_normal,
              best_shape)


@kernel()
def sphere_hits(origins: FloatArray, directions: FloatArray, centre: FloatArray,
                radius: float, index: int, best_t: FloatArray, best_normal: FloatArray,
                best_shape: IntArray) -> None:
    """Sphere of ``radius`` around ``centre``."""
    one = origins.shape[0] == 1
    for i in range(directions.shape[0]):
        k = 0 if one else i
        ox, oy, oz = origins[k, 0] - centre[0], origins[k, 1] - centre[1], origins[k, 2] - centre[2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        half_b = ox * dx + oy * dy + oz * dz
        c = (ox * ox + oy * oy + oz * oz) - radius**2
        disc = half_b * half_b - c
        root = math.sqrt(max(disc, 0.0))
        near, far = -half_b - root, -half_b + root
        t = _valid(near if near > EPSILON_M else far) if disc >= 0.0 else np.inf
        if t < best_t[i]:
            _keep(i, t, (ox + dx * t) / radius, (oy + dy * t) / radius, (oz + dz * t) / radius,
                  index, best_t, best_normal, best_shape)


@kernel()
def _nan_to_num(x: float, nan: float) -> float:
    """numpy's ``nan_to_num(x, nan=nan)``: infinities become the largest finite floats."""
    if math.isnan(x):
        return nan
    if math.isinf(x):
        return _MAX if x > 0 else -_MAX
    return x


@kernel()
def box_hits(origins: FloatArray, directions: FloatArray, centre: FloatArray,
             half: FloatArray, rotation: FloatArray, index: int, best_t: FloatArray,
             best_normal: FloatArray, best_shape: IntArray) -> None:
    """Box of half sizes ``half`` around ``centre``, axes the columns of ``rotation``."""
    one = origins.shape[0] == 1
    o, d = np.empty(3), np.empty(3)
    t1, t2 = np.empty(3), np.empty(3)
    for i in range(directions.shape[0]):
        k = 0 if one else i
        for j in range(3):
            o[j] = ((origins[k, 0] - centre[0]) * rotation[0, j]
                    + (origins[k, 1] - centre[1]) * rotation[1, j]
                    + (origins[k, 2] - centre[2]) * rotation[2, j])
            d[j] = (directions[i, 0] * rotation[0, j] + directions[i, 1] * rotation[1, j]
                    + directions[i, 2] * rotation[2, j])
        for j in range(3):
            inv = 1.0 / d[j] if d[j] != 0.0 else math.copysign(np.inf, d[j])
            a, b = (-half[j] - o[j]) * inv, (half[j] - o[j]) * inv
            lo = np.nan if math.isnan(a) or math.isnan(b) else min(a, b)
            hi = np.nan if math.isnan(a) or math.isnan(b) else max(a, b)
            t1[j], t2[j] = _nan_to_num(lo, -np.inf), _nan_to_num(hi, np.inf)
        t_in, t_out = np.max(t1), np.min(t2)
        entering = t_in > EPSILON_M
        t = _valid(t_in if entering else t_out) if t_in <= t_out else np.inf
        if t < best_t[i]:
            axis = np.argmax(t1) if entering else np.argmin(t2)
            side = -np.sign(d[axis]) * (1.0 if entering else -1.0)
            _keep(i, t, side * rotation[0, axis], side * rotation[1, axis],
                  side * rotation[2, axis], index, best_t, best_normal, best_shape)


@kernel()
def _cylinder_side(ox: float, oy: float, oz: float, dx: float, dy: float, dz: float,
                   radius: float, height: float) -> float:
    a = dx**2 + dy**2
    half_b = ox * dx + oy * dy
    c = ox**2 + oy**2 - radius**2
    disc = half_b * half_b - a * c
    root = math.sqrt(max(disc, 0.0))
    near = (-half_b - root) / a if a != 0.0 else _divide_by_zero(-half_b - root)
    far = (-half_b + root) / a if a != 0.0 else _divide_by_zero(-half_b + root)
    t = near if near > EPSILON_M else far
    z = oz + dz * _nan_to_num(t, 0.0)
    if disc >= 0.0 and a > 1e-12 and 0.0 <= z <= height:
        return _valid(_nan_to_num(t, np.inf))
    return np.inf


@kernel()
def _divide_by_zero(x: float) -> float:
    """``x / 0.0`` as numpy gives it (inf with x's sign, nan for 0)."""
    return np.nan if x == 0.0 or math.isnan(x) else math.copysign(np.inf, x)


@kernel()
def _cylinder_cap(ox: float, oy: float, oz: float, dx: float, dy: float, dz: float,
                  radius: float, z_cap: float) -> float:
    t = (z_cap - oz) / dz if dz != 0.0 else _divide_by_zero(z_cap - oz)
    finite = math.isfinite(t)
    step = t if finite else 0.0
    x, y = ox + dx * step, oy + dy * step
    return _valid(t if finite else np.inf) if x * x + y * y <= radius**2 else np.inf


@kernel()
def cylinder_hits(origins: FloatArray, directions: FloatArray, base: FloatArray,
                  radius: float, height: float, index: int, best_t: FloatArray,
                  best_normal: FloatArray, best_shape: IntArray) -> None:
    """Upright cylinder standing on ``base`` (its lowest centre point)."""
    one = origins.shape[0] == 1
    for i in range(directions.shape[0]):
        k = 0 if one else i
        ox, oy, oz = origins[k, 0] - base[0], origins[k, 1] - base[1], origins[k, 2] - base[2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        side = _cylinder_side(ox, oy, oz, dx, dy, dz, radius, height)
        bottom = _cylinder_cap(ox, oy, oz, dx, dy, dz, radius, 0.0)
        top = _cylinder_cap(ox, oy, oz, dx, dy, dz, radius, height)
        t, which = side, 0
        if bottom < t:
            t, which = bottom, 1
        if top < t:
            t, which = top, 2
        if t < best_t[i]:
            if which == 0:
                _keep(i, t, (ox + dx * t) / radius, (oy + dy * t) / radius, 0.0, index,
                      best_t, best_normal, best_shape)
            else:
                _keep(i, t, 0.0, 0.0, -1.0 if which == 1 else 1.0, index, best_t,
                      best_normal, best_shape)


@kernel()
def ramp_hits(origins: FloatArray, directions: FloatArray, centre: FloatArray,
              axes: FloatArray, half_length: float, half_width: float, index: int,
              best_t: FloatArray, best_normal: FloatArray, best_shape: IntArray) -> None:
    """Rectangle around ``centre``; ``axes`` rows: up the slope, across, normal."""
    one = origins.shape[0] == 1
    up, across, n = axes[0], axes[1], axes[2]
    for i in range(directions.shape[0]):
        k = 0 if one else i
        denom = _dot(directions, i, n)
        rx, ry, rz = origins[k, 0] - centre[0], origins[k, 1] - centre[1], origins[k, 2] - centre[2]
        t = (-rx * n[0] + -ry * n[1] + -rz * n[2]) / denom if abs(denom) > 1e-12 else np.inf
        step = t if math.isfinite(t) else 0.0
        px, py, pz = rx + directions[i, 0] * step, ry + directions[i, 1] * step, rz + (
            directions[i, 2] * step)
        inside = (abs(px * up[0] + py * up[1] + pz * up[2]) <= half_length
                  and abs(px * across[0] + py * across[1] + pz * across[2]) <= half_width)
        t = _valid(t) if inside else np.inf
        s = -1.0 if denom > 0 else 1.0
        _keep(i, t, s * n[0], s * n[1], s * n[2], index, best_t, best_normal, best_shape)
