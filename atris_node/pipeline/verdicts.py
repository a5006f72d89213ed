"""Sector verdicts that the data earn: the nearest credible obstacle, free only when seen.

A sector is one of three things (:class:`atris_node.types.SectorState`):

- VALID, at the *nearest credible* distance: walking its obstacle points from the nearest
  outwards, the first range r whose window ``[r, r + max(CLUSTER_REL·r, CLUSTER_ABS_M,
  SPREAD_SIGMAS·σ)]`` holds at least ``min_points`` points from more than one line, or
  from one line over SLIVER_COLUMNS·min_points columns (independent evidence: a short run
  of one line is what a wrong identity looks like). When the window is no wider than its
  triangulation noise, it opened on a noisy surface's near tail: the surface is the
  points within SURFACE_SIGMAS·σ of a centre moved from the window's median to the
  median of the points near it (verdicts_kernels). The distance is
  the front of a straight fit of range against column over all lines of the surface:
  its mean when the slope is within SLOPE_SIGMAS of zero, else the fit at its nearest
  column, the surface's points followed along the slope (a range window cuts a slanted
  surface short); one line's front instead where it lies significantly nearer (the
  lower lines on a ramp). Its σ is the standard error of that estimate, with one
  sample's triangulation σ as the least scatter (smoothing along the lines correlates
  neighbours). A distance whose σ exceeds max(``max_sigma_rel``·d, ``max_sigma_m``)
  (half the accuracy it is held to) is not pinned down by its points: INVALID. A
  minimum or a low quantile of noisy points would be biased near by about a σ, a mean
  over a slanted surface far: neither is used.
  A distance is not published either where a nearer surface may go on unseen: strong
  lines stop over ``min_points`` or more columns of the sector between their points on
  both sides, one side nearer than the distance, with nothing seen in those columns
  nearer or beyond (:func:`unseen_columns`; a black panel lit only in the next sector).
  Nor where bright lines stop together over a few columns in the middle of the surface
  they are seen on (:func:`shadowed_columns`; a plate seen edge-on before a wall), nor
  where a line the surface should show below its lowest seen lines (it meets the surface
  above the ground clearance) has no peak over a run of its columns while the surface's
  other lines are found solidly (:func:`missing_on_surface`; a dark platform before a
  wall, lower than the lines that pass over it). A line that meets the ground before
  the surface, or the surface within a row and a half of its ground row, is not looked
  for there: nothing says a grazed floor, or a platform's grazed top, returns it.
  A thin pole at a sector edge is reported by the sector its points fall in; nothing
  nearer is outvoted by a wall behind it. When ``min_points`` or more obstacle points lie
  nearer than the credible cluster without being credible themselves (a sliver, a short
  run of a doubtful identity), the sector is INVALID: they may be the nearest obstacle.
  A low surface whose top no line saw (:mod:`atris_node.pipeline.tops`: a kerb the
  lines only graze below the clearance) more than max(TOP_REL·d, TOP_ABS_M) nearer than
  d may rise above the clearance there: INVALID; so does one within a row and a half of
  its ground row (it may be a surface's foot as well) more than its phantom tolerance
  nearer (:func:`atris_node.pipeline.tops.foot_reach_m`).
- NO_RETURN (free up to z_max) only when it is earned: no obstacle point, no ambiguous,
  lone, dropped or saturated sample and no low surface with an unseen top in its
  columns, no foreign light, and every line that meets the ground within z_max was seen
  in every one of its columns (on the ground, where the obstacle-free scene puts it),
  with at least one line that does not (where every sheet meets the ground nearer than
  z_max, nothing beyond the farthest ground hit is looked at: such columns are counted
  doubtful, :class:`atris_node.pipeline.evidence.SectorJudge`);
  a line that meets nothing within z_max shows that nothing stands in its way only where
  a return would have stood out of the noise: its band (the rows of the whole operating
  range) no noisier than CLEAN_NOISE times the map's typical tile noise, and holding
  no pixel blinded in every sub-frame (evidence.CLEAN_NOISE, ``ColumnEvidence.noisy``).
  A line that would be missing where it is expected means something may stand there
  unseen (too dark, too thin, an ambiguous stripe): the sector is INVALID.
- INVALID otherwise, and whenever a peak whose line could not be told may stand as near
  as the distance found: its nearest hypothesis, triangulated, is not farther than
  d + max(DOUBT_REL·d, DOUBT_ABS_M). It may be the nearest obstacle, and the cluster
  found may be the same kind of guess (a comb taken one line off next to columns where
  the two identities tie). Ambiguity farther away leaves the distance standing.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from atris_node.pipeline import verdicts_kernels
from atris_node.pipeline.identity import VisibilityPrior
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
#: the distance is this quantile of the ranges in the credible window (the window spans a
#: slanted surface's depth as well as its noise: its near part is the obstacle's front)
WINDOW_QUANTILE = 0.25
#: an ambiguous peak whose nearest hypothesis lies within max(DOUBT_REL·d, DOUBT_ABS_M)
#: beyond the distance d found (or nearer) makes the sector INVALID
DOUBT_REL = 0.10
DOUBT_ABS_M = 0.20
#: a low surface whose top no line saw (:mod:`atris_node.pipeline.tops`) at a range more
#: than max(TOP_REL·d, TOP_ABS_M) nearer than the distance d found makes the sector
#: INVALID: it may rise above the clearance there (nearer than that, d is accurate for it)
TOP_REL = 0.03
TOP_ABS_M = 0.05
#: a cluster window is at least this many triangulation σ of its first point wide
SPREAD_SIGMAS = 2.0
#: a cluster from one line must cover SLIVER_COLUMNS·min_points columns
SLIVER_COLUMNS = 3
#: a line whose obstacle points in a sector have a median SNR of at least GAP_SNR·snr_min
#: would be seen on a surface 40 % as bright: where it stops, something darker stands (at
#: 3.0 a black crate's edge, all lines stopping over 14 columns beside it, was not counted
#: with the lines at 2.7-3.0·snr_min on a person beside it, and the person read for it)
GAP_SNR = 2.5
#: a hole in a line is at least this many columns wide (single dropouts are noise)
GAP_RUN = 3
#: strong lines that stop in the same columns between points on the reported surface:
#: something stands in all their rays there (:func:`shadowed_columns`)
SHADOW_LINES = 2
#: such a line is seen on GAP_RUN of the 2·GAP_RUN columns each side of its hole with an
#: SNR of at least SHADOW_SNR·snr_min: a surface a tenth as bright would still show
SHADOW_SNR = 10.0
#: a surface seen by lines of SNR SURFACE_SNR·snr_min would show another line on it
#: (:func:`missing_on_surface`); such a line is looked for only where it would meet the
#: surface SURFACE_ROWS_PX or more rows above the row where it meets the ground
#: clearance (nearer, its sample would be ground, tops.GROUND_ROW_PX)
SURFACE_SNR = 2.0
SURFACE_ROWS_PX = 1.5
#: SURFACE_SEEN_ROWS_PX for a line seen on the surface in other columns (it reaches it)
SURFACE_SEEN_ROWS_PX = 0.5
#: it must be missing over SURFACE_RUN·min_points columns (longer than the gaps that
#: noise and the lone-sample rule leave in a weak line), on a surface whose lines are
#: found in SURFACE_SOLID of their columns
SURFACE_RUN = 2
SURFACE_SOLID = 0.8
#: a line the ground returns in a map (on its ground rows in LOST_RETURNED of the quiet
#: columns where it meets the ground within the range, at a median SNR of LOST_SNR·snr_min;
#: evidence.SectorJudge) that shows in at most LOST_SEEN of the LOST_RUN·min_points or
#: more quiet columns of a sector where it would meet the ground nearer than the distance
#: found is stopped there by something that returns no light (:func:`lost_before`)
LOST_RETURNED = 0.2
LOST_SNR = 1.5
LOST_SEEN = 0.05
LOST_RUN = 2
#: a line the ground returns at HOLE_SNR·snr_min or more on both sides of a run of at
#: least LOST_RUN·min_points quiet columns (within GAP_RUN of its ends), and that shows at
#: no row in that run where it would meet the ground clearance nearer than the distance,
#: is stopped there by something that returns no light (:func:`hole_before`)
HOLE_SNR = 3.0
#: a line fades into a run (:func:`_abrupt`) only with this many of its points beside it:
#: two weak ones are as likely a partial return at a dark object's edge
FADE_POINTS = 3
#: a line of any SNR seen in STEADY_SEEN of the STEADY_FLANK·min_points columns beside a
#: run where it has no peak, on the side where it shows the surface found, drops out
#: there by noise about as often: a run of min_points or more such columns is no
#: dropout (:func:`dim_hole`)
STEADY_SEEN = 0.9
STEADY_FLANK = 2
#: columns across a sector boundary within which a neighbour's obstacle points vouch for a
#: sector's few nearer points (one object straddling the boundary)
STRADDLE_COLUMNS = 8
#: the constants as the kernel takes them
_PARAMS = np.array([CLUSTER_REL, CLUSTER_ABS_M, SPREAD_SIGMAS, SLIVER_COLUMNS,
                    WINDOW_QUANTILE])
#: no band too noisy, as the kernels take it
_NOWHERE = np.zeros((0, 0), dtype=np.bool_)


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
    #: (n,) camera-frame depth z (m); None: not known, no test of the lines below a surface
    depth_m: FloatArray | None = None
    #: (n,) below the clearance and off its sheet's ground row: a low surface's point, not
    #: the ground's (a hole's flank opposite an obstacle point, :class:`LineHoles`); None:
    #: not known, none is
    low: BoolArray | None = None

    @property
    def size(self) -> int:
        """The number of points n."""
        return int(self.range_m.size)

    def take(self, index: IntArray | slice) -> ObstaclePoints:
        """The points at ``index`` (an index array or a slice), in that order."""
        return ObstaclePoints(
            self.range_m[index], self.sector[index], self.obstacle[index], self.line[index],
            self.column[index], self.sigma_m[index], self.snr[index],
            None if self.depth_m is None else self.depth_m[index],
            None if self.low is None else self.low[index])


@dataclass(frozen=True)
class SectorPoints:
    """The points of one sector: ``grouped`` holds the map's points sorted by sector
    (:func:`by_sector`), this sector's are its ``start`` .. ``stop`` (exclusive), its
    obstacle points first, up to ``split``."""

    grouped: ObstaclePoints
    start: int
    split: int
    stop: int

    @property
    def size(self) -> int:
        """How many points the sector holds."""
        return self.stop - self.start

    @cached_property
    def inside(self) -> ObstaclePoints:
        """All points of the sector: its obstacle points first, then the others, each in
        the map's order."""
        return self.grouped.take(slice(self.start, self.stop))

    @cached_property
    def hits(self) -> ObstaclePoints:
        """The sector's obstacle points, in the map's order."""
        return self.grouped.take(slice(self.start, self.split))


def by_sector(points: ObstaclePoints, count: int) -> list[SectorPoints]:
    """The :class:`SectorPoints` of sectors 0 .. ``count`` - 1: one stable sort of the
    map's points by sector (obstacle points first within it); each sector's points are
    taken out of it when first asked for (the sort counts the keys, one compiled pass:
    :func:`atris_node.pipeline.verdicts_kernels.grouped`)."""
    key = 2 * points.sector + (~points.obstacle).astype(np.int64)
    order, below = verdicts_kernels.grouped(key, 2 * count)
    grouped = points.take(order)
    bounds = below.tolist()
    return [SectorPoints(grouped, bounds[2 * s], bounds[2 * s + 1], bounds[2 * s + 2])
            for s in range(count)]


@dataclass(frozen=True)
class ColumnEvidence:
    """What each image column (W,) holds besides its accepted samples: ``sector`` (W,)
    its sector (-1 outside), ``doubtful`` (W,) lone, dropped or saturated samples and
    foreign light, ``ambiguous`` (W,) peaks whose line could not be told, and ``missing``
    (W,) lines expected on the ground within z_max but not seen. Any of them in a sector
    blocks NO_RETURN, and so does a line not seen where its band is ``noisy`` (it may be
    lost in the noise, not free); an ambiguous peak blocks VALID too where its nearest
    hypothesis may stand as near as the distance (``doubt_m`` of :func:`sector_verdicts`)."""

    sector: IntArray
    doubtful: IntArray
    ambiguous: IntArray
    missing: IntArray
    #: (K, W) line k has a peak (any range) in column c; None: not known, no hole test
    seen: BoolArray | None = None
    #: (K, W) line k's band in column c is too noisy to show the line (evidence.CLEAN_NOISE)
    noisy: BoolArray | None = None
    #: (K, W) line k meets the ground within the operating range in column c
    expected: BoolArray | None = None
    #: where each line would show on a surface (:func:`missing_on_surface`); None: unknown
    prior: VisibilityPrior | None = None
    #: (K, W) horizontal range (m) at which line k meets the ground clearance in column c
    #: where the line is expected there, its band quiet, and the ground returns it in this
    #: map (LOST_RETURNED, LOST_SNR); inf elsewhere; None: not known (:func:`lost_before`)
    returned_m: FloatArray | None = None
    #: (K, W) the highest SNR of line k's samples on its ground rows in column c (0:
    #: none); None where ``returned_m`` is (:func:`hole_before`)
    ground_snr: FloatArray | None = None
    #: (K, W) line k's sample in column c was a dim of a bright line, dropped
    #: (:mod:`atris_node.pipeline.dimming`); None: none
    dimmed: BoolArray | None = None

    @property
    def unclean(self) -> IntArray:
        """(W,) lines not seen, not expected on the ground (``missing`` counts those),
        whose band is too noisy to show that nothing stands in their way."""
        if self.noisy is None or self.seen is None or self.expected is None:
            return np.zeros(self.sector.size, dtype=np.int64)
        return lines_per_column(self.noisy & ~self.seen & ~self.expected)

    def sector_counts(self, sectors: int) -> tuple[IntArray, IntArray]:
        """(S,) ``per_sector`` of ``ambiguous`` and of ``doubtful`` + ``missing`` +
        ``unclean``, int64, in one compiled pass
        (:func:`atris_node.pipeline.verdicts_kernels.sector_counts`)."""
        masks = ((_NOWHERE,) * 3 if self.noisy is None or self.seen is None
                 or self.expected is None else (self.seen, self.noisy, self.expected))
        seen, noisy, expected = (np.ascontiguousarray(m, dtype=np.bool_) for m in masks)
        sector, ambiguous, doubtful, missing = (
            np.ascontiguousarray(a, dtype=np.int64)
            for a in (self.sector, self.ambiguous, self.doubtful, self.missing))
        return verdicts_kernels.sector_counts(sector, ambiguous, doubtful, missing, seen,
                                              noisy, expected, sectors)

    def per_sector(self, counts: IntArray, sectors: int) -> IntArray:
        """(S,) sums of a (W,) per-column count over each sector's columns."""
        inside = self.sector >= 0
        return np.bincount(self.sector[inside], weights=counts[inside],
                           minlength=sectors).astype(np.int64)


def lines_per_column(mask: BoolArray) -> IntArray:
    """(W,) int64 how many rows of a (K, W) bool ``mask`` are True in each column, as
    ``mask.sum(axis=0)``: added as bytes while K fits one (several times faster)."""
    if mask.shape[0] > np.iinfo(np.uint8).max:
        return mask.sum(axis=0).astype(np.int64)
    return np.add.reduce(mask.view(np.uint8), axis=0, dtype=np.uint8).astype(np.int64)


@dataclass(frozen=True)
class Credible:
    """The nearest credible cluster of a sector: ``distance_m`` (its front, see the module
    docstring), ``sigma_m`` (standard error of it, m), ``support`` (its points) and
    ``nearer`` (obstacle points nearer than it that are not credible themselves)."""

    distance_m: float
    sigma_m: float
    support: int
    nearer: int


def nearest_credible(points: ObstaclePoints, mine: BoolArray, min_points: int
                     ) -> Credible | None:
    """The nearest credible cluster among the obstacle points selected by ``mine`` (see the
    module docstring), None when there is none.

    The window and the front are those of the module docstring; the front is never
    nearer than the window's first point. The sort by range and the loop are compiled
    (:func:`atris_node.pipeline.verdicts_kernels.credible_of`)."""
    idx = np.flatnonzero(mine)
    if idx.size < min_points:
        return None
    return _credible(points.take(idx), int(points.column.max()) + 1, min_points)


def _credible(hits: ObstaclePoints, width: int, min_points: int) -> Credible | None:
    """:func:`nearest_credible` of all of ``hits`` (their columns below ``width``)."""
    if hits.size < min_points:
        return None
    distance, sigma, support, nearer = verdicts_kernels.credible_of(
        np.asarray(hits.range_m, dtype=np.float64), np.asarray(hits.sigma_m, dtype=np.float64),
        np.asarray(hits.line, dtype=np.int64), np.asarray(hits.column, dtype=np.int64),
        min_points, width, _PARAMS)
    if support < 0:
        return None
    return Credible(float(distance), float(sigma), int(support), int(nearer))


def sector_verdicts(points: ObstaclePoints, evidence: ColumnEvidence, layout: SectorLayout,
                    settings: SectorSettings, doubt_m: FloatArray | None = None,
                    reach_m: FloatArray | None = None, columns: SectorColumns | None = None
                    ) -> tuple[SectorDistance, ...]:
    """One :class:`SectorDistance` per sector of ``layout`` (index 0 at the right edge).
    ``doubt_m`` (S,) is the nearest range (m) an ambiguous peak may stand for in each
    sector (inf: none; None: every ambiguous peak may stand for anything); ``reach_m``
    (S,) the farthest distance (m) that the low surfaces whose top no line saw let stand
    (:func:`top_reach_m`, :func:`atris_node.pipeline.tops.foot_reach_m`; inf or None:
    none; the samples are in ``evidence.doubtful`` too); ``columns`` the
    :class:`SectorColumns` of ``evidence.sector`` (None: made here)."""
    count = layout.count
    ambiguous, doubtful = evidence.sector_counts(count)
    if doubt_m is None:
        doubt_m = np.where(ambiguous > 0, 0.0, np.inf)
    if reach_m is None:
        reach_m = np.full(count, np.inf)
    view = MapView.of(points, evidence, count, settings, columns)
    return tuple(_verdict(s, view, layout, settings, ambiguous=int(ambiguous[s]),
                          doubtful=int(doubtful[s]), doubt_m=float(doubt_m[s]),
                          reach_m=float(reach_m[s]), doubt_all=doubt_m)
                 for s in range(count))


def top_reach_m(range_m: FloatArray) -> FloatArray:
    """(n,) the farthest distance (m) a low surface at ``range_m`` whose top is unknown
    lets stand: a distance d stands while the surface lies within max(TOP_REL·d,
    TOP_ABS_M) of it, d <= max(r / (1 - TOP_REL), r + TOP_ABS_M)."""
    return np.asarray(np.maximum(range_m / (1.0 - TOP_REL), range_m + TOP_ABS_M),
                      dtype=np.float64)


@dataclass(frozen=True)
class LineHoles:
    """The runs of at least GAP_RUN columns in which a line has no peak at all, with its
    obstacle points on both sides (or, where its band is too noisy to show it, any of
    its samples), of one map: ``line``, ``start``, ``stop`` (columns,
    stop exclusive), ``nearer_m`` and ``farther_m`` (the flanks' ranges, inf where not
    flanked), ``noisy`` (the line's band is too noisy to show it in most of the run) and
    ``bright`` (the line has an obstacle point of SNR ``bright_snr`` or more in each of
    the GAP_RUN columns before the run and from its stop on: bright flanks; or a dim of
    a bright line in the run, :mod:`atris_node.pipeline.dimming`, whose flanks a moving
    occluder dims too) per run, (n,) each."""

    line: IntArray
    start: IntArray
    stop: IntArray
    nearer_m: FloatArray
    farther_m: FloatArray
    noisy: BoolArray
    bright: BoolArray

    @classmethod
    def of(cls, points: ObstaclePoints, seen: BoolArray, noisy: BoolArray | None = None,
           bright_snr: float = np.inf, dimmed: BoolArray | None = None) -> LineHoles:
        """The holes of every line of ``seen`` (K, W) (``noisy`` (K, W): where its band
        is too noisy to show it; None: nowhere), bright at ``bright_snr`` or where they
        hold a ``dimmed`` (K, W) sample (None: none); one compiled pass
        (:func:`atris_node.pipeline.verdicts_kernels.line_holes`). A flank is the
        line's last obstacle point in the column, or opposite one its last ``low`` point
        (a low surface's, below the clearance, not the ground's: a moving sphere's stripe
        ended 10 columns before a car's foot 3 cm up, which took the line on; without
        that flank there was no hole, and the car was read for the sphere)."""
        return cls(*verdicts_kernels.line_holes(
            seen, _NOWHERE if noisy is None else noisy,
            _NOWHERE if dimmed is None else dimmed,
            np.asarray(points.line, dtype=np.int64), np.asarray(points.column, dtype=np.int64),
            np.asarray(points.range_m, dtype=np.float64), points.obstacle,
            np.zeros(points.size, dtype=np.bool_) if points.low is None else points.low,
            np.asarray(points.snr, dtype=np.float64), float(bright_snr), GAP_RUN))


@dataclass(frozen=True)
class SectorColumns:
    """The image columns of each of ``count`` sectors: ``mask`` (S, W) True where column
    c looks into sector s, read-only; ``spans`` per sector its (first, last) column, None
    where it has none. They depend on the calibration and mounting only."""

    mask: BoolArray
    spans: list[tuple[int, int] | None]

    @classmethod
    def of(cls, sector: IntArray, count: int) -> SectorColumns:
        """The columns of sectors 0 .. ``count`` - 1 under the per-column ``sector`` (W,)
        (-1 outside)."""
        mask = sector[None, :] == np.arange(count)[:, None]
        mask.flags.writeable = False
        spans: list[tuple[int, int] | None] = []
        for row in mask:
            where = np.flatnonzero(row)
            spans.append((int(where[0]), int(where[-1])) if where.size else None)
        return cls(mask, spans)


@dataclass(frozen=True)
class MapView:
    """What the verdicts of one map share: the ``points`` and ``evidence``, the points of
    each sector (``sectors``), each sector's columns (``columns`` (S, W) mask and
    ``spans``, (first, last) column or None), the line holes (None without
    ``evidence.seen``; bright at SHADOW_SNR·snr_min), ``width`` (a bound on the
    points' columns) and ``found`` (S, 4): each sector's nearest credible cluster
    (:meth:`credible`)."""

    points: ObstaclePoints
    evidence: ColumnEvidence
    sectors: list[SectorPoints]
    columns: BoolArray
    spans: list[tuple[int, int] | None]
    holes: LineHoles | None
    width: int
    found: FloatArray

    def credible(self, s: int) -> Credible | None:
        """:func:`nearest_credible` of sector ``s``'s obstacle points (found for every
        sector in one compiled call,
        :func:`atris_node.pipeline.verdicts_kernels.credible_per_sector`)."""
        distance, sigma, support, nearer = self.found[s].tolist()
        if support < 0:
            return None
        return Credible(distance, sigma, int(support), int(nearer))

    @classmethod
    def of(cls, points: ObstaclePoints, evidence: ColumnEvidence, count: int,
           settings: SectorSettings, columns: SectorColumns | None = None) -> MapView:
        """The view of ``points`` and ``evidence`` for ``count`` sectors (``columns``:
        those of ``evidence.sector``, None: made here)."""
        if columns is None:
            columns = SectorColumns.of(evidence.sector, count)
        width = int(points.column.max()) + 1 if points.size else 1
        holes = None if evidence.seen is None else LineHoles.of(
            points, evidence.seen, evidence.noisy, SHADOW_SNR * settings.snr_min,
            evidence.dimmed)
        sectors = by_sector(points, count)
        found = np.full((0, 4), np.nan)
        if sectors:
            grouped = sectors[0].grouped
            found = verdicts_kernels.credible_per_sector(
                _floats(grouped.range_m), _floats(grouped.sigma_m), _ints(grouped.line),
                _ints(grouped.column), np.array([p.start for p in sectors], dtype=np.int64),
                np.array([p.split for p in sectors], dtype=np.int64), settings.min_points,
                width, _PARAMS)
        return cls(points, evidence, sectors, columns.mask, columns.spans, holes, width,
                   found)


def unseen_columns(s: int, view: MapView, distance_m: float, settings: SectorSettings
                   ) -> int:
    """Columns of sector ``s`` where a nearer surface may stand unseen: inside a *hole*
    of a strong line, with no obstacle point in them at most ``distance_m`` + max(
    DOUBT_REL·d, DOUBT_ABS_M) and none of any line beyond that (within GAP_RUN columns:
    far surfaces return sparsely; a line seen beyond is open that far at its height).

    A strong line has a median SNR of at least GAP_SNR·snr_min on its obstacle points in
    the sector: it would be seen on a surface 40 % as bright. Its hole is a run of at
    least GAP_RUN columns in which it has no peak at all, with its obstacle points on
    both sides, one of them nearer than d − max(DOUBT_REL·d, DOUBT_ABS_M) (``holes``): a
    nearer surface ends where the line stops, and may go on, too dark to return it (a
    black panel whose lit part is in the next sector, a dark box's unlit side). A line
    that ends on one side only (a wall's edge with the far scene too faint beyond) or
    between surfaces no nearer than d makes no hole, unless its band is too noisy to show
    it over most of the run: then what stands there is not known (a pole before a wall,
    its stripes under a threshold that flicker left by the demodulation raised).

    A hole also counts whole, its columns in the neighbouring sectors with it, where it
    enters the sector (:func:`_unseen_whole`): its length says whether it can hide
    something, wherever a boundary cuts it, and the sector holding its edge must not
    read what stands behind (a dark plate seen nearly edge-on, its far end three columns
    into the next sector, there read as the wall behind it, 2.56 m for 1.71 m)."""
    holes, span = view.holes, view.spans[s]
    if holes is None or span is None:
        return 0
    margin = doubt_margin_m(distance_m)
    inside, hits = view.sectors[s].inside, view.sectors[s].hits
    count = verdicts_kernels.unseen(
        holes.nearer_m, holes.noisy, holes.line, holes.start, holes.stop, span[0], span[1],
        distance_m - margin, distance_m + margin, GAP_SNR * settings.snr_min, view.columns[s],
        _ints(hits.line), _ints(hits.column), _floats(hits.range_m), _floats(hits.snr),
        _ints(inside.column), _floats(inside.range_m), GAP_RUN)
    whole = _unseen_whole(s, view, distance_m, settings)
    if count < 0 or whole < 0:  # NaN in an SNR: numpy's median decides
        return _unseen_columns(s, view, distance_m, settings)
    return int(max(count, whole))


def _unseen_whole(s: int, view: MapView, distance_m: float, settings: SectorSettings
                  ) -> int:
    """The longest hole of :func:`unseen_columns` that enters sector ``s``, counted whole
    (its columns in the neighbouring sectors too). Another line seen in the hole's
    columns at the distance found does not clear them: a sheet above seen on the far
    surface says only that what stands there is lower (the plate of the docstring above:
    the two upper sheets passed over it to the wall in the columns where the lowest was
    missing), and a sheet below only that it does not reach down to it (a dark ball
    hanging 0.47-1.10 m up before a car at 2.23 m: the two lower sheets passed under it
    to the car while the two upper ones were missing on its unlit limb, and the car was
    read for the ball's 1.13 m). Columns within GAP_RUN of a point farther than
    ``distance_m`` + max(DOUBT_REL·d, DOUBT_ABS_M), of the sector or its neighbours, are
    open as in :func:`unseen_columns` (the gap between two boxes of a range ladder, 2 m
    and 3 m away, the lowest line seen on the floor beyond in it: taken with the sector's
    own points only, the gap's columns in the 2 m sector counted and the 3 m sector went
    INVALID). A line is strong here on its obstacle points and its low surfaces' points
    (``ObstaclePoints.low``) in the sector: a line that meets the foot of the surface
    found, below the clearance, returns from it as brightly (a sphere approaching at 5.3
    m/s, its stripe ended 10 columns before a car's foot 3 cm up; with obstacle points
    only the line had none in the car's sector, and the car was read for the sphere,
    2.73 m for 1.72 m). -1 when an SNR holds NaN; 0 without line holes (no column
    evidence)."""
    holes, span = view.holes, view.spans[s]
    if holes is None or span is None:
        return 0
    margin = doubt_margin_m(distance_m)
    returns = _returns(view.sectors[s].inside)
    around = [view.sectors[t] for t in (s - 1, s, s + 1) if 0 <= t < len(view.sectors)]
    return int(verdicts_kernels.unseen_whole(
        holes.nearer_m, holes.noisy, holes.line, holes.start, holes.stop, span[0], span[1],
        distance_m - margin, distance_m + margin, GAP_SNR * settings.snr_min, view.columns[s],
        _ints(returns.line), _floats(returns.snr),
        _ints(np.concatenate([a.inside.column for a in around])),
        _floats(np.concatenate([a.inside.range_m for a in around])), GAP_RUN))


def _returns(inside: ObstaclePoints) -> ObstaclePoints:
    """The obstacle points and the low surfaces' points (``low``) of ``inside``: where a
    line returns from something standing, if lower than the clearance."""
    keep = inside.obstacle if inside.low is None else inside.obstacle | inside.low
    return inside.take(np.flatnonzero(keep))


def _unseen_columns(s: int, view: MapView, distance_m: float, settings: SectorSettings
                    ) -> int:
    """:func:`unseen_columns` in numpy steps (the compiled pass leaves an SNR with NaN to
    numpy's median)."""
    holes, span = view.holes, view.spans[s]
    if holes is None or span is None:
        return 0
    margin = doubt_margin_m(distance_m)
    near = (((holes.nearer_m < distance_m - margin) | holes.noisy)
            & (holes.start <= span[1]) & (holes.stop > span[0]))
    if not near.any():
        return 0
    inside, hits = view.sectors[s].inside, view.sectors[s].hits
    width = view.evidence.sector.size
    hole = np.zeros(width, dtype=np.bool_)
    whole = np.zeros(width, dtype=np.bool_)  # noisy runs count beyond the sector's edge
    for k, start, stop, noisy in zip(holes.line[near], holes.start[near], holes.stop[near],
                                     holes.noisy[near], strict=True):
        snr = hits.snr[hits.line == k]
        if snr.size and _median(snr) >= GAP_SNR * settings.snr_min:
            hole[start:stop] = True
            whole[start:stop] |= noisy
    hole &= view.columns[s] | whole
    hole[hits.column[hits.range_m <= distance_m + margin]] = False
    far = inside.column[inside.range_m > distance_m + margin]
    for shift in range(-GAP_RUN, GAP_RUN + 1):
        hole[np.clip(far + shift, 0, width - 1)] = False
    return max(int(hole.sum()), _unseen_whole_steps(s, view, distance_m, settings))


def _unseen_whole_steps(s: int, view: MapView, distance_m: float, settings: SectorSettings
                        ) -> int:
    """:func:`_unseen_whole` in numpy steps (numpy's median of an SNR with NaN)."""
    holes, span = view.holes, view.spans[s]
    if holes is None or span is None:
        return 0
    margin = doubt_margin_m(distance_m)
    near = (((holes.nearer_m < distance_m - margin) | holes.noisy)
            & (holes.start <= span[1]) & (holes.stop > span[0]))
    returns = _returns(view.sectors[s].inside)
    around = [view.sectors[t] for t in (s - 1, s, s + 1) if 0 <= t < len(view.sectors)]
    far = np.concatenate([a.inside.column[a.inside.range_m > distance_m + margin]
                          for a in around])
    width = view.evidence.sector.size
    open_ = _open_columns(far, width)
    longest = 0
    for k, start, stop in zip(holes.line[near], holes.start[near], holes.stop[near],
                              strict=True):
        snr = returns.snr[returns.line == k]
        if not snr.size or not np.median(snr) >= GAP_SNR * settings.snr_min:
            continue
        hole = np.zeros(width, dtype=np.bool_)
        hole[start:stop] = True
        hole &= ~open_
        if (hole & view.columns[s]).any():
            longest = max(longest, int(hole.sum()))
    return longest


def _open_columns(far: IntArray, width: int) -> BoolArray:
    """(width,) the columns within GAP_RUN of a point farther than the distance found
    (``far``, its columns): a line seen beyond is open that far at its height."""
    open_ = np.zeros(width, dtype=np.bool_)
    for shift in range(-GAP_RUN, GAP_RUN + 1):
        open_[np.clip(far + shift, 0, width - 1)] = True
    return open_


def dim_hole(s: int, view: MapView, distance_m: float, settings: SectorSettings) -> bool:
    """True when a line, of any SNR, has a hole (:class:`LineHoles`) entering sector
    ``s`` that is flanked on one side by its obstacle point nearer than ``distance_m`` less
    max(DOUBT_REL·d, DOUBT_ABS_M), and on the other by the surface found (no nearer than
    that), where the line shows in STEADY_SEEN or more of the STEADY_FLANK·``min_points``
    columns beside the hole; and the hole holds ``min_points`` or more columns with no
    point of any line beyond ``distance_m`` plus that margin within GAP_RUN of them. Such a
    line would show the surface found in the hole too: it does not, and a nearer surface
    adjoins it, so that surface may go on there, too dark to return the line. A weak line
    is not :func:`unseen_columns`' strong one (GAP_SNR): a dark glossy post 3.4 m away
    before a wall at 3.8 m, met by the only sheet at SNR 8-10 (1.6-2 snr_min), returned
    it in 3 of its 60 columns; the wall, seen in every column beside them, was read
    (4.28 m for 3.76 m, every map)."""
    holes, span = view.holes, view.spans[s]
    if holes is None or span is None or view.evidence.seen is None:
        return False
    margin = doubt_margin_m(distance_m)
    near = ((holes.nearer_m < distance_m - margin) & ~holes.noisy
            & (holes.start <= span[1]) & (holes.stop > span[0])
            & (holes.stop - holes.start >= settings.min_points))
    if not near.any():
        return False
    points, seen = view.points, view.evidence.seen
    width = seen.shape[1]
    open_ = _open_columns(
        points.column[(points.range_m > distance_m + margin) & (points.column < width)], width)
    flank = STEADY_FLANK * settings.min_points
    for k, start, stop in zip(holes.line[near], holes.start[near], holes.stop[near],
                              strict=True):
        if np.count_nonzero(~open_[start:stop]) < settings.min_points:
            continue
        on_line = points.obstacle & (points.line == k)
        for side in (slice(max(start - flank, 0), start), slice(stop, min(stop + flank, width))):
            beside = on_line & (points.column >= side.start) & (points.column < side.stop)
            if (side.stop - side.start == flank
                    and np.count_nonzero(seen[k, side]) >= STEADY_SEEN * flank
                    and np.count_nonzero(beside)
                    and np.median(points.range_m[beside]) >= distance_m - margin):
                return True
    return False


def _ints(values: npt.NDArray[np.generic]) -> IntArray:
    """``values`` as the kernels take them: int64 (no copy when they are)."""
    return np.asarray(values, dtype=np.int64)


def _floats(values: npt.NDArray[np.generic]) -> FloatArray:
    """``values`` as the kernels take them: float64 (no copy when they are)."""
    return np.asarray(values, dtype=np.float64)


def shadowed_columns(s: int, view: MapView, distance_m: float) -> int:
    """Columns of sector ``s`` in which SHADOW_LINES or more bright lines (seen with an
    SNR of SHADOW_SNR·snr_min in GAP_RUN of the 2·GAP_RUN columns each side: a single
    dropout beside the hole, as clipped stripes on a retro-reflective wall have, leaves a
    line bright) all have a hole
    in one surface, its flanks within
    max(DOUBT_REL·d, DOUBT_ABS_M) of each other and no farther than ``distance_m`` plus
    that, with no obstacle point of any line at most that far in them. A hole at a depth
    edge (flanks on two surfaces) is the projector's shadow of the nearer one, or
    :func:`unseen_columns`'s case. Bright lines that all stop over a few columns of the
    surface they are seen on both sides of meet something standing in their rays,
    too dark or too edge-on to return them (a plate seen edge-on, a thin dark pole): at
    any range between the unit and the surface. Narrower than :func:`unseen_columns`
    asks (GAP_RUN columns, not ``min_points``): a 2 cm plate 1 m long seen edge-on at 7 m
    hides four columns of a wall at 8.7 m."""
    holes, span = view.holes, view.spans[s]
    if holes is None or span is None or not holes.line.size:
        return 0
    margin = doubt_margin_m(distance_m)
    hits = view.sectors[s].hits
    return int(verdicts_kernels.shadowed(
        holes.nearer_m, holes.farther_m, holes.noisy, holes.bright, holes.line, holes.start,
        holes.stop, span[0], span[1], distance_m + margin, margin, SHADOW_LINES,
        2 * GAP_RUN, view.columns[s], _ints(hits.line), _ints(hits.column),
        _floats(hits.range_m)))


def blind_columns(s: int, view: MapView) -> int:
    """Columns of sector ``s`` in which no line is seen and every line's band is too
    noisy to show it (``evidence.noisy``): nothing is known there, at any range, and a
    distance the rest of the sector shows says nothing of them (a bright pole 1.5 m
    ahead under a lamp flickering at 100 Hz raised its columns' noise over 90 columns of
    two sectors, and the wall at 6-7 m, seen beside it, was read in both)."""
    evidence = view.evidence
    if evidence.seen is None or evidence.noisy is None:
        return 0
    blind = np.logical_and.reduce(evidence.noisy & ~evidence.seen, axis=0)
    return int(np.count_nonzero(blind & view.columns[s]))


def missing_on_surface(s: int, view: MapView, distance_m: float, settings: SectorSettings
                       ) -> int:
    """Columns of sector ``s`` in which the surface found at ``distance_m`` should show a
    line that has no peak there at all: something lower stands before it, unseen.

    The surface is the obstacle points within max(DOUBT_REL·d, DOUBT_ABS_M) of d with an
    SNR of at least SURFACE_SNR·snr_min (another line on it, half as bright, would still
    stand out). In each of its columns, at its mean depth there, a line below the
    topmost one seen (a surface standing on the ground meets every lower sheet) that
    would meet it SURFACE_ROWS_PX or more rows above the row where it meets the ground
    clearance, on a row of the image and in a quiet band (``evidence.noisy``), is
    expected on it. A run of at least SURFACE_RUN·``min_points`` such columns in which
    the line has no peak counts, unless a line between it and the surface's lowest
    seen one (or itself) is seen beyond the surface in the run's columns
    (the surface does not reach the ground there, the lines pass under it: a sphere, a
    vehicle's body), or the run is the noise of a patchy surface:
    the other lines seen on it are found in fewer than SURFACE_SOLID of their expected
    columns (median), or the line itself is found, outside the run, in some but fewer
    than that, or it fades into the run (two or more of its points within 2·GAP_RUN
    columns of the run, none of SNR SURFACE_SNR·snr_min).
    A dark kerb before a bright wall: the wall's lines above the kerb are
    seen, the one that would meet the wall at the kerb's height is missing. Needs
    ``evidence.prior``, ``evidence.seen`` and ``points.depth_m`` (0 without them)."""
    evidence = view.evidence
    prior, seen = evidence.prior, evidence.seen
    if prior is None or seen is None or view.points.depth_m is None:
        return 0
    hits = view.sectors[s].hits
    if hits.depth_m is None:
        return 0
    margin = doubt_margin_m(distance_m)
    strong = SURFACE_SNR * settings.snr_min
    # the surface's lines expected and not seen, and their long runs: one compiled pass
    first, onto, bottom, shown, line, start, stop = verdicts_kernels.lost_on_surface(
        _floats(hits.range_m), _floats(hits.snr), _ints(hits.column), _floats(hits.depth_m),
        _ints(hits.line), distance_m, margin, strong, settings.min_points,
        SURFACE_RUN * settings.min_points, prior.image_rank,
        np.asarray(prior.cot_alpha, dtype=np.float64), prior.ground_range_m,
        _NOWHERE if evidence.noisy is None else evidence.noisy, _geometry(prior), seen)
    if not line.size:
        return 0
    inside = view.sectors[s].inside
    on = hits.take(np.flatnonzero(np.abs(hits.range_m - distance_m) <= margin))
    beyond = inside.take(np.flatnonzero(inside.range_m > distance_m + margin))
    rank = prior.image_rank
    hole = np.zeros(onto.shape[1], dtype=np.bool_)
    for k, a, b in zip(line, start, stop, strict=True):
        # a line between the surface's lowest seen one and this one, seen beyond it
        # in the run: the surface does not reach down there, the lines pass under (beside
        # the run is no sign: the wall beside a pole)
        near = (beyond.column >= first + a) & (beyond.column < first + b)
        under = rank[beyond.line[near]]
        passes = ((under > bottom[a:b].max()) & (under <= rank[k])).any()
        if (not passes and _solid(onto, shown, int(k), int(a), int(b), settings.min_points)
                and _abrupt(on, int(k), first + int(a), first + int(b), strong)):
            hole[a:b] = True
    return int(hole.sum())


def _expected_on_surface(surface: ObstaclePoints, evidence: ColumnEvidence,
                         prior: VisibilityPrior
                         ) -> tuple[int, BoolArray, IntArray]:
    """The first column c0 the surface (the points ``surface``) is seen in; (K, n + 1)
    True where line k would show on it in column c0 + j: below the topmost line seen on
    it there, SURFACE_ROWS_PX or more rows above its ground row at the surface's mean
    depth there (SURFACE_SEEN_ROWS_PX for a line seen on the surface in other columns),
    inside the image, its band quiet; and (n + 1,) the image position (0 = top) of the
    lowest line seen on it per column (-1 where it is not seen). n spans the surface's
    columns; the last column is False (a run's end). Compiled
    (:func:`atris_node.pipeline.verdicts_kernels.expected_on_surface`)."""
    noisy = _NOWHERE if evidence.noisy is None else evidence.noisy
    first, onto, bottom = verdicts_kernels.expected_on_surface(
        np.asarray(surface.column, dtype=np.int64),
        np.asarray(surface.depth_m, dtype=np.float64),
        np.asarray(surface.line, dtype=np.int64), prior.image_rank,
        np.asarray(prior.cot_alpha, dtype=np.float64), prior.ground_range_m, noisy,
        _geometry(prior))
    return int(first), onto, bottom


def _geometry(prior: VisibilityPrior) -> FloatArray:
    """(6,) what :func:`atris_node.pipeline.verdicts_kernels.expected_on_surface` takes of
    the prior: focal length px, cy px, image height px, f·b px·m and the margins in rows
    (SURFACE_ROWS_PX, SURFACE_SEEN_ROWS_PX)."""
    return np.array([prior.focal_px, prior.cy_px, prior.height_px,
                     prior.focal_px * prior.baseline_m, SURFACE_ROWS_PX,
                     SURFACE_SEEN_ROWS_PX])


def _solid(onto: BoolArray, shown: BoolArray, line: int, start: int, stop: int,
           min_points: int) -> bool:
    """True when, outside ``line``'s run [start, stop), the other lines that show on the
    surface are found in SURFACE_SOLID or more of the columns they are expected in
    (median), and ``line`` itself in none or as many (or is expected in fewer than
    ``min_points`` columns there, too few to tell): its run is no patch of noise."""
    rest = onto.copy()
    rest[line, start:stop] = False
    found = (rest & shown).sum(axis=1)
    expected = rest.sum(axis=1)
    fraction = found / np.maximum(expected, 1)
    others = np.delete(fraction, line)[np.delete(found, line) > 0]
    own = (found[line] == 0 or fraction[line] >= SURFACE_SOLID
           or expected[line] < min_points)
    return bool(others.size and np.median(others) >= SURFACE_SOLID and own)


def _abrupt(on: ObstaclePoints, line: int, start: int, stop: int, snr: float) -> bool:
    """True when ``line`` stops abruptly at its run [start, stop) on the surface (the
    points ``on``): one of its points there within 2·GAP_RUN columns of the run has an
    SNR of at least ``snr``, or it has fewer than FADE_POINTS there (the other lines
    predict it; two weak points beside a dark platform's run of 60 columns let a wall
    2.3 m behind it be read). A line that fades into the run, near its threshold
    wherever it was last seen (a glossy surface turning its lobe away from that sheet),
    does not count; the point at a blocking object's very edge may be weak, so the
    strongest one counts."""
    reach = 2 * GAP_RUN
    edge = (on.line == line) & (
        ((on.column >= start - reach) & (on.column < start))
        | ((on.column >= stop) & (on.column < stop + reach)))
    if np.count_nonzero(edge) < FADE_POINTS:
        return True
    return bool(on.snr[edge].max() >= snr)


def lost_before(s: int, view: MapView, distance_m: float, settings: SectorSettings) -> bool:
    """True when a line that the ground returns in this map (``evidence.returned_m``) is
    seen, at any row, in at most LOST_SEEN of the LOST_RUN·``min_points`` or more columns
    of sector ``s`` where it would meet the ground clearance nearer than ``distance_m``
    less max(DOUBT_REL·d, DOUBT_ABS_M): something that returns no light stands in its way
    there (a black platform whose top the steep sheets meet, the upper ones passing over
    it to the wall behind), at any range up to that ground hit. A line lost in part of
    the sector is :func:`missing_on_surface`'s and :func:`unseen_columns`' case; the
    whole sector asks no flank."""
    returned, seen = view.evidence.returned_m, view.evidence.seen
    if returned is None or seen is None:
        return False
    columns = view.columns[s]
    nearer = returned[:, columns] < distance_m - doubt_margin_m(distance_m)
    expected = np.count_nonzero(nearer, axis=1)
    shown = np.count_nonzero(nearer & seen[:, columns], axis=1)
    return bool(((expected >= LOST_RUN * settings.min_points)
                 & (shown <= LOST_SEEN * expected)).any())


def hole_before(s: int, view: MapView, distance_m: float, settings: SectorSettings) -> bool:
    """True when a line that the ground returns (``evidence.returned_m``) at
    HOLE_SNR·snr_min or more within GAP_RUN columns on both sides of a run of LOST_RUN·
    ``min_points`` or more quiet columns, where it would meet the ground clearance nearer
    than ``distance_m`` less max(DOUBT_REL·d, DOUBT_ABS_M), shows at no row in that run,
    and ``min_points`` or more of the run's columns lie in sector ``s``: something that
    returns no light stands in its way there (a dark object before a bright floor, met by
    the one line that reaches it), at any range up to that ground hit. Both flanks on the
    ground and bright: not the fan's edge, nor a weak ground line dropping out near its
    threshold. A run that goes on to the image's edge needs one such flank, and other
    lines seen in half of its columns: the fan reaches there (a black box top across
    most of the view 0.88 m ahead took the lowest line from the image's edge to the
    ground returns beside it, the wall at 2.83 m read). A shorter run, GAP_RUN columns or
    more, counts where the line is that bright in each of the GAP_RUN columns on both
    sides (:func:`_held`), and in every sector that holds a column of it: a steady bright
    return does not drop out for a few columns by noise, and a thin object on a sector
    boundary leaves only a few columns on each side (a dark pole 4.5 cm thick at 2.74 m
    cut two ground lines over 6-7 columns, split 4 and 3 by a boundary; the wall at 7 m
    was read in both sectors). :func:`lost_before` asks the whole sector."""
    evidence = view.evidence
    returned, seen, snr = evidence.returned_m, evidence.seen, evidence.ground_snr
    if returned is None or seen is None or snr is None:
        return False
    limit = distance_m - doubt_margin_m(distance_m)
    bright = snr >= HOLE_SNR * settings.snr_min
    run, width = LOST_RUN * settings.min_points, seen.shape[1]
    asked = np.asarray((returned < limit).any(axis=1))[:, None]
    for k, start, stop in zip(*verdicts_kernels.runs(
            np.ascontiguousarray(asked & np.isfinite(returned) & ~seen)), strict=True):
        inside = np.count_nonzero(view.columns[s][start:stop])
        if (stop - start < GAP_RUN or not inside
                or not (returned[k, start:stop] < limit).all()):
            continue
        before = bright[k, max(start - GAP_RUN, 0):start]
        after = bright[k, stop:min(stop + GAP_RUN, width)]
        left, right = bool(before.any()), bool(after.any())
        if stop - start < run or inside < settings.min_points:
            if left and right and _held(before, after):
                return True
            continue
        to_the_edge = (left and stop == width) or (right and start == 0)
        if (left and right) or (to_the_edge and _fan_reaches(seen, k, start, stop)):
            return True
    return False


def _held(before: BoolArray, after: BoolArray) -> bool:
    """True when a line is bright on its ground rows in every one of the GAP_RUN columns
    on each side of a hole (``before`` and ``after`` it, up to GAP_RUN each): a short hole
    between steady bright returns."""
    return bool(before.size == GAP_RUN and after.size == GAP_RUN and before.all()
                and after.all())


def _fan_reaches(seen: BoolArray, k: int, start: int, stop: int) -> bool:
    """True when lines other than ``k`` show in at least half of the columns [start,
    stop): the projector's fan reaches them (its edge is the same for every line), so a
    run of line ``k`` that goes on to the image's edge is no fan's edge."""
    others = np.delete(seen[:, start:stop], k, axis=0)
    return bool(2 * np.count_nonzero(others.any(axis=0)) >= stop - start)


def at_the_near_end(s: int, view: MapView, settings: SectorSettings) -> bool:
    """True when ``min_points`` or more obstacle points of sector ``s`` lie within
    DOUBT_REL·z_min of the near end of the operating range (camera z, ``points.depth_m``):
    a surface that reaches the near end may go on nearer, where no band is read (a dark
    car's flank at 0.21 m was read at 0.32 m, the near end 0.3 m). False without
    ``z_min_m`` or depths."""
    hits = view.sectors[s].hits
    if settings.z_min_m <= 0.0 or hits.depth_m is None:
        return False
    near = hits.depth_m <= (1.0 + DOUBT_REL) * settings.z_min_m
    return bool(np.count_nonzero(near) >= settings.min_points)


def straddles(s: int, view: MapView, distance_m: float, settings: SectorSettings,
              doubt_m: FloatArray) -> bool:
    """True when obstacle points of sector ``s`` nearer than ``distance_m`` by more than
    max(DOUBT_REL·d, DOUBT_ABS_M) (too few to be credible in ``s`` alone) belong to an
    object that is credible across the boundary: ``min_points`` or more obstacle points
    of a neighbouring sector within STRADDLE_COLUMNS columns and the cluster window of
    range of one of them, from more than one line or at the range of that sector's own
    nearest credible cluster (a surface that one line alone shows, over the columns
    that make it credible there); or, credible or not, that makes ``min_points`` points
    with this sector's nearer points within STRADDLE_COLUMNS columns and that window: in
    one sector they would be points nearer than the distance, not credible, which make
    it INVALID, and the boundary must not split them into two sectors that both read
    what stands behind (a ball 0.27 m wide hanging 4.4 m ahead, 4 points of one line on
    either side of a boundary: the wall at 8.0 and 8.8 m read in both). A thin pole on
    a sector boundary stands in both sectors; the one holding its edge must not read
    what stands behind. A neighbour's ambiguous peaks within STRADDLE_COLUMNS count as
    such points where that sector's ``doubt_m`` (S,; its nearest range an ambiguous peak
    may stand for) lies within the window or nearer: a surface whose other
    side's samples could not be identified (a surface at 1.89 m straddling a boundary, 2
    points of one line on this side, ambiguous ones on the other: 2.48 m read)."""
    hits = view.sectors[s].hits
    near = np.flatnonzero(hits.range_m < distance_m - doubt_margin_m(distance_m))
    if near.size == 0:
        return False
    others = [t for t in (s - 1, s + 1) if 0 <= t < len(view.sectors)]
    beside = [view.sectors[t].hits for t in others]
    credible = [c.distance_m for c in map(view.credible, others) if c is not None]
    other_range = np.concatenate([b.range_m for b in beside])
    other_column = np.concatenate([b.column for b in beside])
    other_line = np.concatenate([b.line for b in beside])
    unsure, unsure_m = _ambiguous_beside(view, others, doubt_m)
    if other_range.size + int(unsure.sum()) < settings.min_points:
        return False
    columns = np.arange(unsure.size)
    for i in near:
        r = hits.range_m[i]
        window = max(CLUSTER_REL * r, CLUSTER_ABS_M, SPREAD_SIGMAS * hits.sigma_m[i])
        mine = ((np.abs(other_range - r) <= window)
                & (np.abs(other_column - hits.column[i]) <= STRADDLE_COLUMNS))
        across = int(np.count_nonzero(mine))
        if across >= settings.min_points and (
                np.unique(other_line[mine]).size > 1
                or any(abs(c - r) <= window for c in credible)):
            return True
        close = np.abs(columns - hits.column[i]) <= STRADDLE_COLUMNS
        across += int(unsure[close & (unsure_m <= r + window)].sum())
        if across and across + np.count_nonzero(
                (np.abs(hits.range_m[near] - r) <= window)
                & (np.abs(hits.column[near] - hits.column[i]) <= STRADDLE_COLUMNS)
        ) >= settings.min_points:
            return True
    return False


def _ambiguous_beside(view: MapView, others: list[int], doubt_m: FloatArray
                      ) -> tuple[IntArray, FloatArray]:
    """(W,) the ambiguous peaks of each column in the sectors ``others`` (0 elsewhere) and
    (W,) the nearest range (m) they may stand for (their sector's ``doubt_m``; inf
    elsewhere)."""
    sector = view.evidence.sector
    beside = np.isin(sector, others)
    count = np.where(beside, view.evidence.ambiguous, 0)
    nearest = np.full(sector.size, np.inf)
    nearest[beside] = np.asarray(doubt_m)[sector[beside]]
    return count, nearest


def doubt_margin_m(distance_m: float) -> float:
    """max(DOUBT_REL·d, DOUBT_ABS_M): how near a doubt must come to a distance d (m)."""
    return max(DOUBT_REL * distance_m, DOUBT_ABS_M)


def _median(values: FloatArray) -> float:
    """np.median of a non-empty (n,) float64 array without NaN, as np.median computes it
    (the middle value, or the mean of the middle two), without its overhead."""
    n = values.size
    if n == 1:
        return float(values[0])
    half = n // 2
    part = np.partition(values, (half - 1, half))
    if n % 2:
        return float(part[half])
    return float((part[half - 1] + part[half]) / 2.0)


def _verdict(s: int, view: MapView, layout: SectorLayout, settings: SectorSettings, *,
             ambiguous: int, doubtful: int, doubt_m: float, reach_m: float,
             doubt_all: FloatArray) -> SectorDistance:
    bearing = layout.bearing_of(s)
    samples = view.sectors[s].size
    if samples < settings.min_points:
        return SectorDistance(s, bearing, SectorState.INVALID, point_count=samples)
    hits = view.sectors[s].hits
    if not hits.size:
        inside = view.sectors[s].inside
        conf = _confidence(samples, _median(inside.snr), settings)
        free = ambiguous == 0 and doubtful == 0 and conf >= settings.min_confidence
        return SectorDistance(s, bearing, SectorState.NO_RETURN if free else
                              SectorState.INVALID, 0.0, conf, samples)
    found = view.credible(s)
    if found is None or found.nearer >= settings.min_points or doubt_m < (
            found.distance_m + doubt_margin_m(found.distance_m)) or (
            found.distance_m > reach_m):
        # nothing credible, or something nearer that is not credible, or a peak whose
        # line could not be told may stand as near (the cluster found may be one such
        # guess itself), or a low surface nearer may rise above the clearance unseen:
        # no distance
        return SectorDistance(s, bearing, SectorState.INVALID, point_count=hits.size)
    conf = _confidence(hits.size, _median(hits.snr), settings)
    if conf < settings.min_confidence or found.sigma_m > settings.sigma_limit_m(
            found.distance_m):
        # too little support, or a distance the points do not pin down
        return SectorDistance(s, bearing, SectorState.INVALID, 0.0, conf, found.support)
    if (unseen_columns(s, view, found.distance_m, settings) >= settings.min_points
            or shadowed_columns(s, view, found.distance_m) >= GAP_RUN
            or blind_columns(s, view) >= settings.min_points):
        # a nearer surface may go on, too dark for the lines, where they stop; or
        # something stands in the rays of every bright line over a few columns; or no
        # line can be seen over a few columns at all
        return SectorDistance(s, bearing, SectorState.INVALID, 0.0, conf, found.support)
    if (missing_on_surface(s, view, found.distance_m, settings) >= settings.min_points
            or lost_before(s, view, found.distance_m, settings)
            or hole_before(s, view, found.distance_m, settings)
            or dim_hole(s, view, found.distance_m, settings)):
        # a line missing from the surface, or one the ground returns elsewhere lost
        # before it over the whole sector or between bright ground returns, or a steady
        # line's hole beside a nearer point: something stands there, unseen
        return SectorDistance(s, bearing, SectorState.INVALID, 0.0, conf, found.support)
    if at_the_near_end(s, view, settings):
        # a surface reaching the near end of the range may stand nearer, unseen
        return SectorDistance(s, bearing, SectorState.INVALID, 0.0, conf, found.support)
    if straddles(s, view, found.distance_m, settings, doubt_all):
        # an object credible across the boundary stands nearer in this sector's edge
        return SectorDistance(s, bearing, SectorState.INVALID, 0.0, conf, found.support)
    return SectorDistance(s, bearing, SectorState.VALID, found.distance_m, conf,
                          found.support, found.sigma_m)


def _confidence(count: int, median_snr: float, settings: SectorSettings) -> float:
    """0..1: grows with the point count (full at 3·min_points) and the median SNR (full
    at SNR_FULL·snr_min: every sample already passed snr_min, and a median half as much
    again above it is not noise)."""
    by_count = min(1.0, count / (3.0 * settings.min_points))
    by_snr = min(1.0, median_snr / (SNR_FULL * settings.snr_min))
    return by_count * by_snr
