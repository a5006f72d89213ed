"""Compiled per-sector statistics of the obstacle points (numba, ``nopython``).

:func:`atris_node.pipeline.obstacles.sector_distances` needs, per sector, the sample count, a low
quantile of the obstacle points' ranges, their ``min_points``-th nearest and a median
SNR. As numpy steps (sorts grouped by sector, slices, a Python loop over the sectors) that
is ~0.3 ms per map; here one pass groups the values and a selection (not a sort) reads
each order statistic (~0.1 ms). The quantile and the median use numpy's own arithmetic,
so the results are the same to the bit (tests/test_obstacles.py).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel
from atris_node.pipeline.selection import kth, median, quantile

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@kernel()
def _group_order(sector: IntArray, keep: BoolArray, count: int
                 ) -> tuple[IntArray, IntArray]:
    """Indices of the ``keep`` samples grouped by ``sector`` (0..count-1, others left
    out), in the input order within a group: group s is ``order[start[s]:start[s + 1]]``."""
    start = np.zeros(count + 1, dtype=np.int64)
    for i in range(sector.size):
        if keep[i] and 0 <= sector[i] < count:
            start[sector[i] + 1] += 1
    start = np.cumsum(start)
    order = np.empty(start[-1], dtype=np.int64)
    fill = start[:-1].copy()
    for i in range(sector.size):
        s = sector[i]
        if keep[i] and 0 <= s < count:
            order[fill[s]] = i
            fill[s] += 1
    return order, start


@kernel()
def _snr_median_of_sector(sector: IntArray, snr: FloatArray, s: int) -> float:
    """Median SNR of every sample in sector ``s`` (it has at least one)."""
    return median(snr[sector == s])


@kernel("Tuple((int64[:], int64[:], float64[:], float64[:]))(int64[:], boolean[:], "
      "float64[:], float64[:], int64, int64, float64)")
def sector_statistics(sector: IntArray, obstacle: BoolArray, range_m: FloatArray,
                      snr: FloatArray, count: int, min_points: int, q: float
                      ) -> tuple[IntArray, IntArray, FloatArray, FloatArray]:
    """Per sector 0..count-1 (samples with another ``sector`` index are left out):

    - samples: every sample in it;
    - hits: its obstacle samples;
    - median SNR: of the hits, else of every sample, 0.0 when it has none;
    - distance, m: ``max(q-quantile of the hits' ranges, the min_points-th nearest)``
      when it has at least ``min_points`` hits, else 0.0.
    """
    order, start = _group_order(sector, obstacle, count)
    ranges, hit_snr = range_m[order], snr[order]
    samples = np.zeros(count, dtype=np.int64)
    for s in sector:
        if 0 <= s < count:
            samples[s] += 1
    hits = start[1:] - start[:-1]
    snr_median = np.zeros(count)
    distance = np.zeros(count)
    for s in range(count):
        if hits[s]:
            snr_median[s] = median(hit_snr[start[s]:start[s + 1]])
        elif samples[s]:  # rare: the sector's samples hit the ground or nothing
            snr_median[s] = _snr_median_of_sector(sector, snr, s)
        if hits[s] >= min_points:
            mine = ranges[start[s]:start[s + 1]]
            distance[s] = max(quantile(mine, q), kth(mine, min_points - 1))
    return samples, hits, snr_median, distance


def warm_up() -> None:
    """Call the kernel once on a tiny input, so that the first map does not pay numba's
    first-call argument typing."""
    sector_statistics(np.zeros(1, dtype=np.int64), np.ones(1, dtype=np.bool_), np.ones(1),
                      np.ones(1), 1, 1, 0.1)
