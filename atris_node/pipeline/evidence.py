"""What each image column holds, gathered for the sector verdicts of
:mod:`atris_node.pipeline.verdicts`: per column its sector, its doubtful and ambiguous
peaks and the lines missing where the ground should show them; per sector the nearest
range an ambiguous peak may stand for.

Columns are placed in sectors by their horizontal ray (vehicle frame), once per
calibration and mounting. Counts are int64 (W,), ranges float64 m, inf where none.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from atris_node.calibration import Calibration
from atris_node.mounting import Mounting
from atris_node.pipeline import verdicts_kernels
from atris_node.pipeline.geometry import Points, rows_where, triangulate_pixels
from atris_node.pipeline.identity import VisibilityPrior
from atris_node.pipeline.obstacles import GroundPlane, SectorInput, SectorSettings
from atris_node.pipeline.peaks import Extraction
from atris_node.pipeline.sectors import SectorLayout
from atris_node.pipeline.tops import (
    GROUND_ROW_PX,
    TOP_ROWS_PX,
    Tops,
    below_ground,
    corroborated,
    foot_reach_m,
    height_sigma_m,
    rows_off_ground,
    unseen_tops,
)
from atris_node.pipeline.verdicts import (
    LOST_RETURNED,
    LOST_SNR,
    ColumnEvidence,
    ObstaclePoints,
    SectorColumns,
    doubt_margin_m,
    sector_verdicts,
    top_reach_m,
)
from atris_node.types import SectorDistance

#: a line is not seen for lack of a surface only where its band's noise σ is at most
#: CLEAN_NOISE times the map's typical tile noise (a return that the rest of the map
#: would show may be lost under more: a sun patch, the edge of a surface under flicker
#: that the code does not cancel)
CLEAN_NOISE = 2.0
#: a sample within this many rows of where its sheet meets the ground, and within the
#: clearance of it, is the ground's return of its line (a face's foot a few centimetres
#: up, met square on and far brighter, lies a row or more off for the shallow sheets that
#: meet the ground far off: SectorJudge._returned)
ON_GROUND_ROWS_PX = 0.5
#: px; a valid sample below the clearance lying more than this above its sheet's ground
#: row is a low surface's, not the ground's (twice ON_GROUND_ROWS_PX: peak noise)
LOW_ROWS_PX = 2 * ON_GROUND_ROWS_PX
#: m; a foot hidden under a gap to the sheet above taller than this (an obstacle that
#: size stands there met only at its foot) lets no distance stand beyond where it starts
#: (:meth:`SectorJudge._foot_reach`); shorter gaps only keep a sector from being free
HIDDEN_GAP_M = 0.5
#: a return beyond z_max by less than this many of its σ (or than max(DOUBT_REL·z_max,
#: DOUBT_ABS_M)) may stand within the range (:meth:`SectorJudge._at_the_edge`)
EDGE_SIGMAS = 3.0
#: the range (m) up to which the returns beyond z_max are triangulated for that test
_NO_LIMIT_M = 1.0e6
#: no flagged sample (:meth:`SectorJudge._evidence`)
_NO_COLUMNS = np.zeros(0, dtype=np.int64)

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
ScalarT = TypeVar("ScalarT", bound=np.generic)


@dataclass(frozen=True)
class Sheet:
    """Each sample (n,) on its light sheet, from the ground plane: ``height_m`` above it
    and its σ ``height_sigma_m``, horizontal ``distance_m`` from the projector,
    ``rows_off`` (image rows from where the sheet meets the ground,
    :func:`atris_node.pipeline.tops.rows_off_ground`); the projector's height (m) and
    f·b (px·m)."""

    height_m: FloatArray
    height_sigma_m: FloatArray
    distance_m: FloatArray
    projector_height_m: float
    focal_baseline: float
    rows_off: FloatArray


class SectorJudge:
    """Sector verdicts of one calibrated, mounted unit from a map's samples and evidence.

    Args:
        calibration, mounting, layout: the unit's.
        settings: the sector part of the pipeline configuration.
        z_range_m: (z_min, z_max) of the operating range, m.
        clearance_m: the ground clearance, m: lower surfaces are ground.
    """

    def __init__(self, calibration: Calibration, mounting: Mounting, layout: SectorLayout,
                 settings: SectorSettings, z_range_m: tuple[float, float],
                 clearance_m: float = 0.1) -> None:
        self.calibration = calibration
        self.mounting = mounting
        self.layout = layout
        self.settings = settings
        self.z_range_m = z_range_m
        self.clearance_m = clearance_m
        self.column_sector = sectors_by_column(calibration, mounting, layout)
        self.column_sector.flags.writeable = False  # the sectors' columns are kept
        self._columns = SectorColumns.of(self.column_sector, layout.count)
        self.projector_m = mounting.camera_to_vehicle(
            np.array([[0.0, -calibration.laser.baseline_m, 0.0]]))[0]
        #: the last prior and its lines expected on the ground (the prior changes only
        #: with the ground plane)
        self._expected: tuple[VisibilityPrior, BoolArray] | None = None
        #: the last ground plane and the camera's and projector's heights above it, m
        self._heights: tuple[GroundPlane, float, float] | None = None
        #: the last prior and where each sheet leaves the range (:meth:`_sheet_exits`)
        self._exits: tuple[VisibilityPrior, FloatArray, FloatArray, BoolArray] | None = None
        #: the last prior and where each sheet meets the ground clearance (:meth:`_ground_hits`)
        self._hits: tuple[VisibilityPrior, FloatArray] | None = None
        #: the last prior and its columns with hidden feet (:meth:`_hidden_feet`)
        self._feet: tuple[VisibilityPrior, IntArray] | None = None
        #: the last prior and the sectors' ranges from which a foot is hidden
        self._onset: tuple[VisibilityPrior, FloatArray] | None = None

    def sectors_of(self, columns: BoolArray) -> set[int]:
        """The sectors the given (W,) columns look into."""
        return {int(i) for i in np.unique(self.column_sector[columns]) if i >= 0}

    def judge(self, extraction: Extraction, points: Points, data: SectorInput,
              clean: BoolArray, foreign: BoolArray, prior: VisibilityPrior,
              ground: GroundPlane | None = None) -> tuple[SectorDistance, ...]:
        """The verdicts for the ``clean`` samples (``data`` holds them, ``points`` has
        every sample), with the evidence of every column (``foreign`` (W,) columns with
        foreign light) under the visibility ``prior``. With the ``ground`` plane, a
        sample within GROUND_ROW_PX rows of where its sheet meets the ground is an
        obstacle point only where another line corroborates it (elsewhere, over the
        clearance, it lets no distance stand more than its tolerance or a row of range
        beyond it), low surfaces whose top
        no line saw count as doubts, and samples clearly below the ground keep their
        columns from being free (:mod:`atris_node.pipeline.tops`)."""
        samples = extraction.samples
        sector, range_m = data.placed(self.layout)
        pick = _Clean(clean)
        sigma_m = pick(points.sigma_z_m)
        sheet = None if ground is None else self._sheet(data, ground, sigma_m)
        line, column = pick(samples.line), pick(samples.col_px).astype(np.int64)
        obstacle = data.obstacle if sheet is None else self._credible_obstacle(
            data.obstacle, line, column, sheet)
        low_surface = None if sheet is None else (
            ~obstacle & pick(points.valid) & (sheet.rows_off > LOW_ROWS_PX))
        found = ObstaclePoints(range_m, sector, obstacle, line, column, sigma_m, data.snr,
                               points.xyz_m[:, 2][clean], low_surface)
        doubt_m = self._doubt_ranges(extraction)
        reach_m = np.full(self.layout.count, np.inf)
        flagged = _NO_COLUMNS  # samples that keep their columns from being free
        on_ground: tuple[IntArray, IntArray, FloatArray] | None = None
        if sheet is not None and ground is not None:
            valid = pick(points.valid)
            low = valid & (np.abs(sheet.height_m) <= self.clearance_m) & (
                np.abs(sheet.rows_off) <= ON_GROUND_ROWS_PX)
            on_ground = (line[low], column[low], data.snr[low])
            tops = self._unseen_tops(found, valid, sheet,
                                     self._passing(prior, ground, line[~valid], column[~valid]))
            under = below_ground(sheet.height_m, sheet.rows_off, sheet.height_sigma_m, valid)
            low = tops.unseen | tops.at_foot
            flagged = found.column[low | under]
            doubt_m = np.minimum(doubt_m, self._any_line_ranges(
                pick(samples.row_px)[under], pick(samples.col_px)[under]))
            verdicts_kernels.least_per_sector(
                reach_m, np.where(low, sector, -1),
                np.where(tops.unseen, top_reach_m(range_m), foot_reach_m(range_m)))
            # a sample over the clearance but within GROUND_ROW_PX rows of its ground
            # row that no line corroborates is no obstacle point, yet it is the ground
            # a pixel off, a wall's foot stripe a pixel short, or a low surface the rows
            # cannot resolve (a ramp's risen part): no distance stands beyond its
            # tolerance or a row of range (d²/(f·b)) beyond it, whichever is more
            verdicts_kernels.least_per_sector(
                reach_m, np.where(data.obstacle & ~obstacle & valid, sector, -1),
                np.maximum(foot_reach_m(range_m), range_m + range_m**2 / sheet.focal_baseline))
        flagged = np.concatenate([flagged, self._at_the_edge(extraction, points, clean, ground),
                                  self._hidden_feet(prior)])
        np.minimum(reach_m, self._foot_reach(prior), out=reach_m)
        evidence = self._evidence(extraction, foreign, prior, points.valid, flagged, on_ground)
        return sector_verdicts(found, evidence, self.layout, self.settings, doubt_m, reach_m,
                               self._columns)

    def _at_the_edge(self, extraction: Extraction, points: Points, clean: BoolArray,
                     ground: GroundPlane | None) -> IntArray:
        """(m,) the columns of the ``clean`` samples that triangulate beyond z_max by no
        more than max(DOUBT_REL·z_max, DOUBT_ABS_M, EDGE_SIGMAS·σ), higher than the
        clearance above the ``ground`` (any height without one): a surface there may
        stand within the range (a calibration off by its tolerance, the horizontal range
        the distances are given in against the camera z the range is cut at), so its
        columns are not free. A sheet seen on the ground beyond z_max met nothing before
        it, and a return farther beyond is the clean band's evidence of that too."""
        beyond = np.flatnonzero(clean & ~points.valid)
        if not beyond.size:
            return _NO_COLUMNS
        samples = extraction.samples
        z_max = self.z_range_m[1]
        margin = doubt_margin_m(z_max)
        far = triangulate_pixels(samples.row_px[beyond], samples.col_px[beyond],
                                 samples.line[beyond], self.calibration.camera,
                                 self.calibration.laser, z_max_m=_NO_LIMIT_M,
                                 sigma_u_px=samples.sigma_u_px[beyond])
        over = far.xyz_m[:, 2] - z_max
        edge = far.valid & (over <= np.maximum(margin, EDGE_SIGMAS * far.sigma_z_m))
        if ground is not None and edge.any():
            vehicle = self.mounting.camera_to_vehicle(far.xyz_m)
            edge &= ground.height(vehicle) > self.clearance_m
        return samples.col_px[beyond[edge]].astype(np.int64)

    def _credible_obstacle(self, obstacle: BoolArray, line: IntArray, column: IntArray,
                           sheet: Sheet) -> BoolArray:
        """``obstacle`` without the samples within GROUND_ROW_PX rows of their sheet's
        ground row that no other line corroborates (:func:`tops.corroborated`)."""
        clear = obstacle & (sheet.rows_off > GROUND_ROW_PX)
        doubtful = obstacle & ~clear
        if not doubtful.any():
            return obstacle
        return clear | corroborated(line, column, sheet.distance_m, clear, doubtful,
                                    lines=len(self.calibration.laser.alpha_rad),
                                    width=self.column_sector.size,
                                    focal_baseline_px_m=sheet.focal_baseline)

    def _sheet(self, data: SectorInput, ground: GroundPlane, sigma_m: FloatArray) -> Sheet:
        """Where each sample (range σ ``sigma_m``) lies on its sheet, measured from the
        ``ground`` plane (``data.height_m`` when given: the heights above it)."""
        height = ground.height(data.points) if data.height_m is None else data.height_m
        origin = self.projector_m
        distance = np.hypot(data.points[:, 0] - origin[0], data.points[:, 1] - origin[1])
        camera = self.mounting.translation
        camera_h, projector_h = self._unit_heights(ground)
        sigma_h = height_sigma_m(
            sigma_m, height, camera_h,
            np.hypot(data.points[:, 0] - camera[0], data.points[:, 1] - camera[1]))
        fb = self.calibration.camera.focal_px * self.calibration.laser.baseline_m
        return Sheet(height, sigma_h, distance, projector_h, fb,
                     rows_off_ground(distance, height, projector_h, fb))

    def _unit_heights(self, ground: GroundPlane) -> tuple[float, float]:
        """The camera's and the projector's height (m) above ``ground``, kept while the
        plane is the same (it changes only with a new ground fit)."""
        if self._heights is None or self._heights[0] is not ground:
            camera = self.mounting.translation
            self._heights = (ground, float(ground.height(camera[None, :])[0]),
                             float(ground.height(self.projector_m[None, :])[0]))
        return self._heights[1], self._heights[2]

    def _unseen_tops(self, found: ObstaclePoints, valid: BoolArray, sheet: Sheet,
                     passing: tuple[FloatArray, FloatArray, BoolArray]) -> Tops:
        """The valid samples that are no obstacle point and whose top no line above
        bounds (``passing``: see :func:`atris_node.pipeline.tops.unseen_tops`)."""
        return unseen_tops(found.line, found.column, sheet.distance_m, sheet.height_m,
                           found.sigma_m, found.obstacle, valid,
                           lines=len(self.calibration.laser.alpha_rad),
                           width=self.column_sector.size, clearance_m=self.clearance_m,
                           projector_height_m=sheet.projector_height_m,
                           height_sigma=sheet.height_sigma_m, rows_off=sheet.rows_off,
                           focal_baseline_px_m=sheet.focal_baseline, passing=passing)

    def _passing(self, prior: VisibilityPrior, ground: GroundPlane, beyond_line: IntArray,
                 beyond_column: IntArray) -> tuple[FloatArray, FloatArray, BoolArray]:
        """(K, W) distance and height (m) of each sheet where it leaves the operating
        range, where its line is known to pass over every nearer distance: its sheet
        meets the ground only beyond z_max (not seen within the range, it is taken as
        meeting nothing there), or the line was seen beyond the range (``beyond_line``,
        ``beyond_column``: its samples with no return within it; (K, W) True there);
        nan elsewhere (:func:`atris_node.pipeline.tops.unseen_tops`)."""
        distance, height, leaves = self._sheet_exits(prior, ground)
        lines, width = leaves.shape
        seen = np.zeros((lines, width), dtype=np.bool_)
        inside = (beyond_line >= 0) & (beyond_line < lines) & (beyond_column >= 0) & (
            beyond_column < width)
        seen[beyond_line[inside], beyond_column[inside]] = True
        known = leaves | seen
        return np.where(known, distance, np.nan), np.where(known, height, np.nan), seen

    def _sheet_exits(self, prior: VisibilityPrior, ground: GroundPlane
                     ) -> tuple[FloatArray, FloatArray, BoolArray]:
        """(K, W) horizontal distance from the projector and height above ``ground`` (m)
        of each line's sheet at camera z = z_max in each column (the point
        [v·z/f, z·cot α_k − b, z] of Eq. 1's plane), and where the sheet meets the
        ground only beyond z_max (``prior``); kept while the prior is the same."""
        if self._exits is None or self._exits[0] is not prior:
            z = self.z_range_m[1]
            k, w = len(self.calibration.laser.alpha_rad), self.calibration.camera.width_px
            vehicle = self._on_sheets(np.full((k, w), z))
            origin = self.projector_m
            distance = np.hypot(vehicle[:, 0] - origin[0], vehicle[:, 1] - origin[1])
            self._exits = (prior, distance.reshape(k, w), ground.height(vehicle).reshape(k, w),
                           np.asarray(prior.ground_range_m > z))
        return self._exits[1], self._exits[2], self._exits[3]

    def _on_sheets(self, z_m: FloatArray) -> FloatArray:
        """(K·W, 3) vehicle-frame points (m) of each line's sheet at camera z ``z_m``
        (K, W) on each column's ray: [v·z/f, z·cot α_k − b, z], Eq. 1's plane (pinhole)."""
        cam, laser = self.calibration.camera, self.calibration.laser
        cot = 1.0 / np.tan(np.asarray(laser.alpha_rad, dtype=np.float64))[:, None]
        x = (np.arange(cam.width_px, dtype=np.float64) - cam.cx_px) * z_m / cam.focal_px
        return self.mounting.camera_to_vehicle(
            np.stack([x, z_m * cot - laser.baseline_m, z_m], axis=-1).reshape(-1, 3))

    def _evidence(self, extraction: Extraction, foreign: BoolArray,
                  prior: VisibilityPrior, valid: BoolArray, flagged: IntArray,
                  on_ground: tuple[IntArray, IntArray, FloatArray] | None = None
                  ) -> ColumnEvidence:
        """The column evidence of one map; ``valid`` (n,) marks the samples of
        ``extraction`` that triangulate within the operating range, the columns
        ``flagged`` (m,) hold samples that keep them from being free (unseen tops, below
        the ground; counted among the doubtful), ``on_ground`` the (line, column, SNR) of
        the samples on the ground (None: no ground plane). The per-column counts in one
        compiled pass (:func:`atris_node.pipeline.verdicts_kernels.column_evidence`)."""
        samples = extraction.samples
        expected = self._expected_on_ground(prior)
        noisy = None if extraction.band_noise_dn is None else (
            extraction.band_noise_dn > CLEAN_NOISE * extraction.tile_noise_dn)
        if noisy is not None and extraction.blinded is not None:
            noisy = noisy | extraction.blinded
        # where every line meets the ground within z_max and none is seen beyond the range
        # (no ground there), nothing beyond the farthest ground hit is looked at: free up
        # to z_max is not known there
        seen, doubtful, missing = verdicts_kernels.column_evidence(
            np.ascontiguousarray(samples.line, dtype=np.int64),
            samples.col_px.astype(np.int64), np.ascontiguousarray(samples.saturated),
            np.ascontiguousarray(valid), expected, np.ascontiguousarray(prior.looks_beyond),
            np.ascontiguousarray(extraction.doubtful_columns, dtype=np.int64),
            np.ascontiguousarray(foreign, dtype=np.bool_), flagged)
        returned = ground_snr = None
        if on_ground is not None:
            ground_snr = _ground_snr(expected.shape, on_ground)
            returned = self._returned(prior, expected, _Noise.of(extraction, noisy),
                                      on_ground, ground_snr > 0.0)
        return ColumnEvidence(self.column_sector, doubtful=doubtful,
                              ambiguous=extraction.ambiguous_columns, missing=missing,
                              seen=seen, noisy=noisy, expected=expected, prior=prior,
                              returned_m=returned,
                              ground_snr=None if returned is None else ground_snr,
                              dimmed=extraction.dimmed)

    def _returned(self, prior: VisibilityPrior, expected: BoolArray, noise: _Noise,
                  on_ground: tuple[IntArray, IntArray, FloatArray], on: BoolArray
                  ) -> FloatArray | None:
        """(K, W) :attr:`ColumnEvidence.returned_m`: where line k meets the ground
        clearance (horizontal range, m) in the columns where it is ``expected`` on the
        ground and its return would show through the band's noise, for the lines that the
        ground returns in this map: found on it (``on`` (K, W); ``on_ground``: line,
        column, SNR of the ground samples) in LOST_RETURNED of the expected columns where
        it is found or its band is quiet (:attr:`_Noise.noisy` not set), with a median SNR
        of LOST_SNR·snr_min; inf elsewhere. None when the ground returns no line so. (A
        bright line raises its own band's noise: counted over the quiet columns alone, the
        ground's brightest line, at SNR 300-500, was found in none of them and was not
        taken for returned.)

        A band noisier than CLEAN_NOISE times the map's tile noise (``noise.ratio``) still
        shows a line returned at median SNR m wherever m / ratio is LOST_SNR·snr_min or
        more (the standard of a returned line, in that band's noise): the ground's return
        there is as bright as beside it. (A low crate's face lit
        at SNR 1000 by the lines below raised the noise of the lowest line's band over the
        crate 2-10 times; that line, on the ground at SNR 400 on both sides, was missing
        there without counting, and the face's comb read one line up gave 2.3 m for 1.1 m.)
        A band blinded in every sub-frame shows nothing."""
        line, _, snr = on_ground
        quiet = expected if noise.noisy is None else expected & (~noise.noisy | on)
        count = quiet.sum(axis=1)
        fraction = (on & quiet).sum(axis=1) / np.maximum(count, 1)
        returned = (count > 0) & (fraction >= LOST_RETURNED)
        median = np.zeros(returned.size)
        for k in np.flatnonzero(returned):
            median[k] = np.median(snr[line == k])
        returned &= median >= LOST_SNR * self.settings.snr_min
        if not returned.any():
            return None
        shows = quiet
        if noise.ratio is not None:
            through = noise.ratio * (LOST_SNR * self.settings.snr_min) <= median[:, None]
            shows = quiet | (expected & through & ~noise.blinded)
        return np.where(shows & returned[:, None], self._ground_hits(prior), np.inf)

    def _ground_hits(self, prior: VisibilityPrior) -> FloatArray:
        """(K, W) horizontal range (m, vehicle frame) of the point where each line's
        sheet meets the ground clearance in each column (camera z ``prior.ground_range_m``
        on the column's ray), inf where it does not; kept while the prior is the same."""
        if self._hits is None or self._hits[0] is not prior:
            z = np.asarray(prior.ground_range_m, dtype=np.float64)
            meets = np.isfinite(z) & (z > 0.0)
            z = np.where(meets, z, 1.0)
            vehicle = self._on_sheets(z)
            hits = self.layout.horizontal_range(vehicle[:, 0], vehicle[:, 1]).reshape(z.shape)
            self._hits = (prior, np.where(meets, hits, np.inf))
        return self._hits[1]

    def _foot_reach(self, prior: VisibilityPrior) -> FloatArray:
        """(S,) per sector the nearest range (m, horizontal) from which some line's foot
        is hidden in one of its columns (:func:`hidden_foot_onset`), inf where none is;
        kept while the prior is the same."""
        if self._onset is None or self._onset[0] is not prior:
            z = hidden_foot_onset(
                prior.ground_range_m, self._expected_on_ground(prior),
                float(self.projector_m[2]),
                self.calibration.camera.focal_px * self.calibration.laser.baseline_m,
                self.clearance_m, HIDDEN_GAP_M)
            hidden = np.isfinite(z)
            onset = np.full(z.shape, np.inf)
            if hidden.any():
                vehicle = self._on_sheets(np.where(hidden, z, 1.0))
                horizontal = self.layout.horizontal_range(vehicle[:, 0], vehicle[:, 1])
                onset = np.where(hidden, horizontal.reshape(z.shape), np.inf)
            reach = np.full(self.layout.count, np.inf)
            column = np.broadcast_to(self.column_sector, z.shape)
            verdicts_kernels.least_per_sector(
                reach, np.where(hidden, column, -1).ravel().astype(np.int64),
                onset.ravel())
            reach.flags.writeable = False
            self._onset = (prior, reach)
        return self._onset[1]

    def _hidden_feet(self, prior: VisibilityPrior) -> IntArray:
        """(m,) the columns where a line meets the ground within the range with a foot
        no row resolves under a gap to the sheet above taller than the clearance
        (:func:`hidden_feet`), kept while the prior is the same."""
        if self._feet is None or self._feet[0] is not prior:
            feet = np.flatnonzero(hidden_feet(
                prior.ground_range_m, self._expected_on_ground(prior),
                float(self.projector_m[2]),
                self.calibration.camera.focal_px * self.calibration.laser.baseline_m,
                self.clearance_m)).astype(np.int64)
            feet.flags.writeable = False
            self._feet = (prior, feet)
        return self._feet[1]

    def _expected_on_ground(self, prior: VisibilityPrior) -> BoolArray:
        """:func:`expected_on_ground` of ``prior``, kept while the prior is the same."""
        if self._expected is None or self._expected[0] is not prior:
            expected = expected_on_ground(prior, self.calibration, self.z_range_m)
            expected.flags.writeable = False  # shared by the maps' evidence
            self._expected = (prior, expected)
        return self._expected[1]

    def _any_line_ranges(self, row_px: FloatArray, col_px: FloatArray) -> FloatArray:
        """(S,) per sector the nearest horizontal range (m) the given peaks stand for
        under any line that puts them within the operating range (a sample under the
        ground was given the wrong line: it may be any of them), inf where none."""
        lines = len(self.calibration.laser.alpha_rad)
        line = np.tile(np.arange(lines, dtype=np.int64), row_px.size)
        return self._nearest_per_sector(np.repeat(row_px, lines), np.repeat(col_px, lines),
                                        line, self.z_range_m[0])

    def _doubt_ranges(self, extraction: Extraction) -> FloatArray:
        """(S,) per sector the nearest horizontal range (m) an ambiguous peak may stand
        for (its nearest hypothesis triangulated), inf where none."""
        row, col, line = extraction.doubts
        return self._nearest_per_sector(row.astype(np.float64), col.astype(np.float64),
                                        line, 0.0)

    def _nearest_per_sector(self, row_px: FloatArray, col_px: FloatArray, line: IntArray,
                            z_min_m: float) -> FloatArray:
        """(S,) per sector the nearest horizontal range (m) of the peaks (row, column)
        triangulated with the given lines, camera z in [``z_min_m``, z_max]; inf where
        none."""
        out = np.full(self.layout.count, np.inf)
        if row_px.size == 0:
            return out
        points = triangulate_pixels(row_px, col_px, line, self.calibration.camera,
                                    self.calibration.laser, z_max_m=self.z_range_m[1])
        xyz = points.xyz_m.reshape(-1, 3)
        vehicle = rows_where(self.mounting.camera_to_vehicle(xyz),
                             points.valid & (xyz[:, 2] >= z_min_m))
        x, y = vehicle[:, 0], vehicle[:, 1]
        verdicts_kernels.least_per_sector(out, self.layout.index_of(x, y),
                                          self.layout.horizontal_range(x, y))
        return out


class _Clean:
    """The clean samples' values of per-sample (n,) arrays: ``array[clean]``, or the array
    itself (not a copy) when every sample is clean (the arrays are only read)."""

    def __init__(self, clean: BoolArray) -> None:
        self.clean = clean
        self.every = bool(clean.all())

    def __call__(self, values: npt.NDArray[ScalarT]) -> npt.NDArray[ScalarT]:
        return values if self.every else values[self.clean]


def sectors_by_column(calibration: Calibration, mounting: Mounting, layout: SectorLayout
                      ) -> IntArray:
    """(W,) the sector each image column looks into (its horizontal ray), -1 outside."""
    cam = calibration.camera
    v = np.arange(cam.width_px, dtype=np.float64) - cam.cx_px
    rays = np.stack([v, np.zeros_like(v), np.full_like(v, cam.focal_px)], axis=1)
    directions = rays @ mounting.rotation.T
    return np.asarray(layout.index_of(directions[:, 0], directions[:, 1]), dtype=np.int64)


def expected_on_ground(prior: VisibilityPrior, calibration: Calibration,
                       z_range_m: tuple[float, float]) -> BoolArray:
    """(K, W) True where line k meets the ground within the operating range in column c on
    a row of the image: with nothing standing there, the line is seen there."""
    cam = calibration.camera
    z = prior.ground_range_m
    cot = np.asarray(prior.cot_alpha)[:, None]
    with np.errstate(divide="ignore"):
        row = cam.cy_px + cam.focal_px * cot - cam.focal_px * prior.baseline_m / z
    z_min, z_max = z_range_m
    return np.asarray((z <= z_max) & (z >= z_min) & (row >= 0) & (row < cam.height_px))


def hidden_feet(ground_range_m: FloatArray, expected: BoolArray, projector_height_m: float,
                focal_baseline_px_m: float, clearance_m: float) -> BoolArray:
    """(W,) True in the columns where a line that meets the ground within the range
    (``expected`` (K, W)) has a *hidden foot*: a face it meets near where it meets the
    ground lies less than TOP_ROWS_PX rows off its ground row (f·b·h/(d·h0) rows at
    height h, distance d), which the ground's own stripe cannot be told from, and the
    sheet above passes there higher than the clearance, so an obstacle standing in that
    gap is met only at its unresolved foot. Such a column cannot show that nothing
    stands within the range (a dark low box 34 cm tall 4.7 m ahead, met 5 cm up by the
    one sheet that meets the ground, 0.3 rows off its ground row, the other sheet above
    the horizon: the sector read free).

    Geometry in each column's vertical plane, camera z for range (a coarse bound: the
    pitch and the plane the ground fit gives are left out): a sheet meeting the
    clearance at z_c (``ground_range_m``, inf: never) meets the ground at
    g = z_c·h0/(h0 − c) and is at h0·(1 − d/g) at d; its foot is unresolved from
    d_r = 1/(1/g + TOP_ROWS_PX/(f·b)) on; the sheet above is the one meeting the ground
    next farther (at h0 or higher when none does)."""
    onset = hidden_foot_onset(ground_range_m, expected, projector_height_m,
                              focal_baseline_px_m, clearance_m, clearance_m)
    return np.asarray(np.isfinite(onset).any(axis=0))


def hidden_foot_onset(ground_range_m: FloatArray, expected: BoolArray,
                      projector_height_m: float, focal_baseline_px_m: float,
                      clearance_m: float, gap_m: float) -> FloatArray:
    """(K, W) camera z (m) from which line k's foot in column c is hidden
    (:func:`hidden_feet`), inf where it has none. Beyond it up to the sheet above, an
    obstacle lower than that sheet is met only at a foot the rows cannot tell from the
    ground: no distance farther than this stands in the column's sector (a crate 0.95 m
    tall at 4.67 m, met 3 cm up by the one sheet that meets the ground, the other above
    the horizon: the wall behind, 5.96 m, read VALID)."""
    h0 = float(projector_height_m)
    if h0 <= clearance_m or focal_baseline_px_m <= 0.0:
        return np.full(expected.shape, np.inf)
    z = np.asarray(ground_range_m, dtype=np.float64)
    meets = np.isfinite(z) & (z > 0.0)
    ground = np.where(meets, z, np.inf) * (h0 / (h0 - clearance_m))
    resolved_to = 1.0 / (1.0 / ground + TOP_ROWS_PX / focal_baseline_px_m)
    farther = np.where(ground[None, :, :] > ground[:, None, :], ground[None, :, :], np.inf)
    above = farther.min(axis=1)
    with np.errstate(invalid="ignore"):
        gap = np.where(np.isfinite(above), h0 * (1.0 - resolved_to / above), h0)
    return np.where(expected & meets & (gap > gap_m), resolved_to, np.inf)


@dataclass(frozen=True)
class _Noise:
    """How noisy each line's band is in each column of a map: ``noisy`` (K, W) where a
    return the rest of the map would show may be lost (band noise over CLEAN_NOISE times
    the tile noise, or blinded), ``ratio`` (K, W) float64 band noise over tile noise (1
    where not measured), ``blinded`` (K, W) bands blinded in every sub-frame; None
    where the map does not measure them."""

    noisy: BoolArray | None
    ratio: FloatArray | None
    blinded: BoolArray

    @staticmethod
    def of(extraction: Extraction, noisy: BoolArray | None) -> _Noise:
        """The noise of ``extraction``'s bands, with ``noisy`` as :meth:`SectorJudge._evidence`
        takes it."""
        band, tile = extraction.band_noise_dn, extraction.tile_noise_dn
        if band is None or noisy is None:
            return _Noise(noisy, None, np.zeros(0, dtype=np.bool_))
        ratio = band.astype(np.float64) / tile if tile > 0.0 else np.ones(band.shape)
        blinded = (np.zeros(band.shape, dtype=np.bool_) if extraction.blinded is None
                   else np.asarray(extraction.blinded, dtype=np.bool_))
        return _Noise(noisy, np.nan_to_num(ratio, nan=np.inf, posinf=np.inf), blinded)


def _ground_snr(shape: tuple[int, ...], on_ground: tuple[IntArray, IntArray, FloatArray]
                ) -> FloatArray:
    """(K, W) the highest SNR of line k's samples on its ground rows in column c (0: none;
    a sample's SNR is at least ``snr_min`` > 0, so the positive entries are where line k
    is on the ground); ``on_ground`` the (line, column, SNR) of those samples."""
    out = np.zeros(shape, dtype=np.float64)
    line, column, snr = on_ground
    np.maximum.at(out, (line, column), np.nan_to_num(snr, nan=0.0))
    return out
