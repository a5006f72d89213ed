"""The visibility prior's hidden line by its plain definition, for the tests that hold the
compiled count (identity_kernels.unexplained) to what it means."""

from __future__ import annotations

from typing import Any

import numpy as np

from atris_node.pipeline.identity_kernels import HIDDEN_PX


def hidden_as_defined(prior: Any, rows: np.ndarray, z: list, place: np.ndarray, k: int
                      ) -> bool:
    """Line k is the one line missing between the nearest lines with a finite range above
    and below it in image order, the one below nearer, and its row at the range of the
    one above lies HIDDEN_PX or more below the row of the one below, and no line below
    that one is seen farther (the nearer surface hides it)."""
    f, b = prior.focal_px, prior.baseline_m
    finite = [j for j in range(rows.size) if np.isfinite(z[j])]
    above = [j for j in finite if place[j] < place[k]]
    below = [j for j in finite if place[j] > place[k]]
    if not above or not below:
        return False
    up = max(above, key=lambda j: place[j])
    low = min(below, key=lambda j: place[j])
    row = prior.cy_px + f * prior.cot_alpha[k] - f * b / z[up]
    farther_below = any(place[j] > place[low] and z[j] > z[low] for j in finite)
    return bool(place[low] - place[up] == 2 and z[low] < z[up] and row >= rows[low] + HIDDEN_PX
                and not farther_below)
