"""Compiled source-frame angles of surface points (numba, ``nopython``): one pass.

The kernel of :func:`atris_node.sim.optics.sheet_angles`, with the same formulas in the
same order (the numpy form made a dozen passes and temporaries over the points). Matrix
products are summed left to right and ``atan2``/``hypot`` come from the C library, so a
value can differ from numpy's in the last bits (1e-16 relative), never more.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel

FloatArray = npt.NDArray[np.float64]


@kernel()
def source_angles(points: FloatArray, translation: FloatArray, rotation: FloatArray,
                  baseline_m: float, theta: FloatArray, phi: FloatArray, r: FloatArray,
                  dirs: FloatArray) -> None:
    """Fill θ, φ, r (n,) and unit world directions (n, 3) of world ``points`` (n, 3) seen
    from a source ``baseline_m`` below the camera at ``translation`` (3,) whose axes are
    the columns of ``rotation`` (3, 3)."""
    d = np.empty(3)
    for i in range(points.shape[0]):
        q0 = points[i, 0] - translation[0]
        q1 = points[i, 1] - translation[1]
        q2 = points[i, 2] - translation[2]
        for j in range(3):
            d[j] = q0 * rotation[0, j] + q1 * rotation[1, j] + q2 * rotation[2, j]
        d[1] = d[1] - -baseline_m
        dist = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        r[i] = dist
        theta[i] = math.atan2(d[2], d[1])
        phi[i] = math.atan2(d[0], math.hypot(d[1], d[2]))
        scale = max(dist, 1e-12)
        e0, e1, e2 = d[0] / scale, d[1] / scale, d[2] / scale
        for j in range(3):
            dirs[i, j] = e0 * rotation[j, 0] + e1 * rotation[j, 1] + e2 * rotation[j, 2]
