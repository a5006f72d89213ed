"""Sector verdicts that the data earn: the nearest credible obstacle, free only when seen.

A sector is one of three things (:class:`atris_node.types.SectorState`):

- VALID, at the *nearest credible* distance: walking its obstacle points from the nearest
  outwards, the first range r whose window ``[r, r + max(CLUSTER_REL·r, CLUSTER_ABS_M)]``
  holds at least ``min_points`` points from more than one line or from at least
  MIN_COLUMNS columns (independent evidence: one lone stripe segment can be a wrong
  identity, a lone noise peak never gets that far). The distance is the median of the
  first ``min_points`` points of that window, its σ the larger of their spread and their
  median triangulation σ. A thin pole or a sliver at a sector edge is reported by the
  sector its points fall in; nothing nearer is outvoted by a wall behind it.
- NO_RETURN (free up to z_max) only when it is earned: no obstacle point, no ambiguous,
  lone, dropped or saturated sample in its columns, no foreign light, and every line that
  meets the ground within z_max was seen in every one of its columns (on the ground,
  where the obstacle-free scene puts it). A line that would be missing where it is
  expected means something may stand there unseen (too dark, too thin, an ambiguous
  stripe): the sector is INVALID.
- INVALID otherwise, and always when the sector holds an ambiguous sample: a sample
  whose line could not be told may be the nearest obstacle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.pipeline.obstacles import SectorSettings
from atris_node.pipeline.sectors import SectorLayout
from atris_node.types import SectorDistance, SectorState

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

#: a credible cluster spans at most max(CLUSTER_REL·r, CLUSTER_ABS_M) in range
CLUSTER_REL = 0.03
CLUSTER_ABS_M = 0.05
#: the median SNR, in units of snr_min, at which the SNR no longer lowers the confidence
SNR_FULL = 1.5
#: columns a single line must cover to count as independent evidence
MIN_COLUMNS = 3


@dataclass(frozen=True)
class ObstaclePoints:
    """The valid samples of one map, (n,) each: horizontal ``range_m`` (vehicle frame),
    ``sector`` index (-1 outside the field of view), ``obstacle`` (above the ground
    clearance), ``line``, ``column`` (px), ``sigma_m`` (triangulation σ of the range),
    ``snr``."""

    range_m: FloatArray
    sector: IntArray
    obstacle: BoolArray
    line: IntArray
    column: IntArray
    sigma_m: FloatArray
    snr: FloatArray


@dataclass(frozen=True)
class ColumnEvidence:
    """What each image column (W,) holds besides its accepted samples: ``sector`` (W,)
    its sector (-1 outside), ``doubtful`` (W,) ambiguous, lone, dropped or saturated
    samples and foreign light (any count > 0 blocks NO_RETURN), ``ambiguous`` (W,) samples
    whose line could not be told (any makes the sector INVALID), and ``missing`` (W,)
    lines expected on the ground within z_max but not seen."""

    sector: IntArray
    doubtful: IntArray
    ambiguous: IntArray
    missing: IntArray

    def per_sector(self, counts: IntArray, sectors: int) -> IntArray:
        """(S,) sums of a (W,) per-column count over each sector's columns."""
        inside = self.sector >= 0
        return np.bincount(self.sector[inside], weights=counts[inside],
                           minlength=sectors).astype(np.int64)


def nearest_credible(points: ObstaclePoints, mine: BoolArray, min_points: int
                     ) -> tuple[float, float, int] | None:
    """(distance m, σ m, supporting points) of the nearest credible cluster among the
    obstacle points selected by ``mine`` (see the module docstring), None when none."""
    idx = np.flatnonzero(mine)
    if idx.size < min_points:
        return None
    idx = idx[np.argsort(points.range_m[idx], kind="stable")]
    r = points.range_m[idx]
    ends = np.searchsorted(r, r + np.maximum(CLUSTER_REL * r, CLUSTER_ABS_M), side="right")
    for i in np.flatnonzero(ends - np.arange(r.size) >= min_points):
        window = idx[i:ends[i]]
        if _independent(points, window):
            first = window[np.argsort(points.range_m[window], kind="stable")[:min_points]]
            distance = float(np.median(points.range_m[first]))
            sigma = max(float(np.std(points.range_m[first])),
                        float(np.median(points.sigma_m[first])))
            return distance, sigma, int(window.size)
    return None


def _independent(points: ObstaclePoints, window: IntArray) -> bool:
    """True when the points come from more than one line, or from MIN_COLUMNS columns."""
    return bool(np.unique(points.line[window]).size > 1
                or np.unique(points.column[window]).size >= MIN_COLUMNS)


def sector_verdicts(points: ObstaclePoints, evidence: ColumnEvidence, layout: SectorLayout,
                    settings: SectorSettings) -> tuple[SectorDistance, ...]:
    """One :class:`SectorDistance` per sector of ``layout`` (index 0 at the right edge)."""
    count = layout.count
    ambiguous = evidence.per_sector(evidence.ambiguous, count)
    doubtful = evidence.per_sector(evidence.doubtful + evidence.missing, count)
    return tuple(_verdict(s, points, layout, settings, ambiguous=int(ambiguous[s]),
                          doubtful=int(doubtful[s])) for s in range(count))


def _verdict(s: int, points: ObstaclePoints, layout: SectorLayout, settings: SectorSettings,
             *, ambiguous: int, doubtful: int) -> SectorDistance:
    bearing = layout.bearing_of(s)
    in_sector = points.sector == s
    samples = int(in_sector.sum())
    if ambiguous or samples < settings.min_points:
        return SectorDistance(s, bearing, SectorState.INVALID, point_count=samples)
    hits = in_sector & points.obstacle
    snr = float(np.median(points.snr[hits if hits.any() else in_sector]))
    if not hits.any():
        conf = _confidence(samples, snr, settings)
        free = doubtful == 0 and conf >= settings.min_confidence
        return SectorDistance(s, bearing, SectorState.NO_RETURN if free else
                              SectorState.INVALID, 0.0, conf, samples)
    found = nearest_credible(points, hits, settings.min_points)
    if found is None:
        return SectorDistance(s, bearing, SectorState.INVALID, point_count=int(hits.sum()))
    distance, sigma, support = found
    conf = _confidence(int(hits.sum()), snr, settings)
    if conf < settings.min_confidence:
        return SectorDistance(s, bearing, SectorState.INVALID, 0.0, conf, support)
    return SectorDistance(s, bearing, SectorState.VALID, distance, conf, support, sigma)


def _confidence(count: int, median_snr: float, settings: SectorSettings) -> float:
    """0..1: grows with the point count (full at 3·min_points) and the median SNR (full
    at SNR_FULL·snr_min: every sample already passed snr_min, and a median half as much
    again above it is not noise)."""
    by_count = min(1.0, count / (3.0 * settings.min_points))
    by_snr = min(1.0, median_snr / (SNR_FULL * settings.snr_min))
    return by_count * by_snr
