"""The processing chain of one unit: distortion map -> line samples -> points -> sectors.

>>> from atris_node.calibration import Calibration, CameraModel, LaserCalibration
>>> from atris_node.mounting import Mounting
>>> cal = Calibration(CameraModel(640, 400, 381.5, 319.5, 199.5),
...                   LaserCalibration(0.075, (1.40,)))
>>> config = PipelineConfig(peak_method="steger")
>>> pipe = Pipeline(config, cal, Mounting(z_m=0.4, pitch_rad=0.1), config.layout())
>>> len(pipe.bands)
1
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from atris_node.calibration import Calibration
from atris_node.errors import ConfigError, check_setting
from atris_node.mounting import Mounting
from atris_node.pipeline import (
    alignment_kernels,
    dimming,
    identity_kernels,
    peaks_kernels,
    persistence,
    radiometry,
    radiometry_kernels,
    rivals,
    verdicts_kernels,
)
from atris_node.pipeline import objects as objects_mod
from atris_node.pipeline.bands import Band, line_bands
from atris_node.pipeline.evidence import SectorJudge
from atris_node.pipeline.faint import faint_sectors
from atris_node.pipeline.geometry import Points, rows_where, triangulate_pixels
from atris_node.pipeline.identity import VisibilityPrior, masking_px
from atris_node.pipeline.near import near_stripes, topmost
from atris_node.pipeline.obstacles import (
    ClosingTracker,
    GroundPlane,
    SectorInput,
    SectorSettings,
    estimate_ground,
    nearest_obstacle,
)
from atris_node.pipeline.peaks import (
    IDENTITY_MODES,
    PEAK_METHODS,
    Extraction,
    ExtractorSettings,
    LineSamples,
    extract_lines,
    narrowest_stripe_px,
    per_column,
    select,
    smooth_along_lines,
    supported_along_lines,
)
from atris_node.pipeline.roi import RoiSettings, RoiTracker
from atris_node.pipeline.sectors import SectorLayout
from atris_node.types import (
    DistortionMap,
    FaultBits,
    Measurement,
    SectorDistance,
    SectorState,
)

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]
#: columns next to one with foreign light that are not trusted either
FOREIGN_MARGIN_COLUMNS = 4
GROUND_MODES = ("calibrated", "estimate")


@dataclass(frozen=True)
class PipelineConfig:
    """Every setting of the chain; units in the names (m, px, deg), fractions 0..1."""

    peak_method: str = "gaussian"
    snr_min: float = 6.0
    z_min_m: float = 0.3
    z_max_m: float = 10.0
    roi_bands: bool = True
    band_margin_px: float = 3.0
    stripe_sigma_px: float = 1.5
    sector_count: int = 8
    fov_deg: float = 70.0
    min_points: int = 5
    min_confidence: float = 0.6  # below: INVALID (e.g. only peaks barely above snr_min)
    #: a VALID distance d has a standard error of at most max(max_sigma_rel·d,
    #: max_sigma_m): half the accuracy it is held to, max(3 %, 5 cm)
    max_sigma_rel: float = 0.015
    max_sigma_m: float = 0.025
    ground_clearance_m: float = 0.1
    ground_plane: str = "calibrated"
    ground_estimate_every: int = 30
    objects: bool = False
    object_eps_m: float = 0.3
    object_min_points: int = 10
    export_dir: Path | None = None
    export_every: int = 1
    sigma_u_px: float = 0.05  # calibration floor, added in quadrature to the fit's σ_u
    #: foreign light is flagged when the negative/positive map energy or the fraction of
    #: peaks that belong to no line (per line and column) exceeds this
    foreign_limit: float = 0.02
    invalid_on_interference: bool = False  # True: flagged foreign light blanks every sector
    smooth_columns: int = 5  # median of this many columns along each line (1 = off)
    drop_lone_samples: bool = True  # a sample needs a neighbour on its line (±2 columns)
    roi_narrowing: bool = False  # search lines near their recent rows (atris_node.pipeline.roi)
    identity: str = "aligned"  # or "greedy": the greedy matchings only (~0.3 ms less)
    #: drop samples whose line has a rival (atris_node.pipeline.rivals); off only to
    #: measure what it does
    unique_identity: bool = True
    #: a still stripe keeps its line: the identity checked against the map before
    #: (:mod:`atris_node.pipeline.persistence`; off only to measure what it does)
    still_lines: bool = True
    roi_full_every: int = 16  # maps between whole-band searches while narrowing
    #: ρ cos i under which a sample is too faint for its range (pipeline.radiometry; 0 = off)
    min_reflectance: float = radiometry.MIN_REFLECTANCE
    #: ρ cos i under which a sample whose line continuity chose over farther rivals is too
    #: faint (pipeline.radiometry.TIED_REFLECTANCE; at most ``min_reflectance``: as that)
    tied_reflectance: float = radiometry.TIED_REFLECTANCE

    def __post_init__(self) -> None:
        _check(self.peak_method in PEAK_METHODS, "peak_method", self.peak_method,
               f"one of {PEAK_METHODS}")
        _check(self.ground_plane in GROUND_MODES, "ground_plane", self.ground_plane,
               f"one of {GROUND_MODES}")
        _check(self.identity in IDENTITY_MODES, "identity", self.identity,
               f"one of {IDENTITY_MODES}")
        _check(0.0 < self.z_min_m < self.z_max_m, "z_min_m", self.z_min_m,
               f"> 0 and below z_max_m ({self.z_max_m})")
        for name in ("snr_min", "stripe_sigma_px", "fov_deg", "object_eps_m", "max_sigma_rel",
                     "max_sigma_m"):
            _check(getattr(self, name) > 0, name, getattr(self, name), "> 0")
        for name in ("band_margin_px", "sigma_u_px", "foreign_limit", "ground_clearance_m"):
            _check(getattr(self, name) >= 0, name, getattr(self, name), ">= 0")
        for name in ("sector_count", "min_points", "ground_estimate_every",
                     "object_min_points", "export_every", "smooth_columns", "roi_full_every"):
            _check(getattr(self, name) >= 1, name, getattr(self, name), "an integer >= 1")
        _check(0.0 <= self.min_confidence <= 1.0, "min_confidence", self.min_confidence,
               "in [0, 1]")
        for name in ("min_reflectance", "tied_reflectance"):
            _check(0.0 <= getattr(self, name) < 1.0, name, getattr(self, name), "in [0, 1)")

    def layout(self) -> SectorLayout:
        """The :class:`SectorLayout` of ``sector_count`` and ``fov_deg``."""
        return SectorLayout(self.sector_count, float(np.deg2rad(self.fov_deg)))

    def extractor(self) -> ExtractorSettings:
        """The line-extraction part of the configuration."""
        return ExtractorSettings(self.peak_method, self.snr_min, self.stripe_sigma_px,
                                 identity=self.identity, unique=self.unique_identity)

    def sectors(self) -> SectorSettings:
        """The sector part of the configuration."""
        return SectorSettings(self.min_points, self.min_confidence, self.snr_min,
                              self.max_sigma_rel, self.max_sigma_m, self.z_min_m)


def _check(ok: bool, name: str, value: object, accepted: str) -> None:
    check_setting(ok, f"pipeline.{name}", value, accepted)


@dataclass(frozen=True)
class Diagnostics:
    """How one frame went. Counts are per frame; fractions 0..1; SNR per line (K,)."""

    noise_floor_dn: float
    valid_fraction: float
    weak: int
    dropped: int
    ambiguous: int
    saturated: int
    no_return: int
    rows_read: int
    line_snr: tuple[float, ...]
    foreign_energy: float
    #: peaks in the bands that belong to no line, per line slot (moving edges included)
    unassigned_fraction: float
    foreign_columns: int  # columns with foreign light in or next to them
    #: foreign light: the energy or the unassigned peaks that are neither moving edges of
    #: own stripes nor steps exceed ``foreign_limit`` (another projector, a same-code unit)
    interference: bool
    ground: GroundPlane
    timings_ms: dict[str, float] = field(default_factory=dict)
    #: of ``unassigned_fraction``, the peaks set aside as moving edges (own light moved
    #: within the window: they blank their columns' sectors but are not interference)
    moving_fraction: float = 0.0
    #: of ``unassigned_fraction``, the maxima set aside as one side of a step (no stripe:
    #: flicker residual, motion smear; they blank their columns' sectors too)
    step_fraction: float = 0.0
    #: samples too faint for the range their line gives: doubts, not points
    #: (atris_node.pipeline.radiometry)
    too_faint: int = 0
    #: stripes above every band, of a surface nearer than z_min: doubts
    #: (atris_node.pipeline.near)
    near: int = 0


@dataclass(frozen=True)
class PipelineResult:
    """Everything one distortion map gave.

    ``samples`` are all accepted line samples (n,); ``valid`` (n,) marks those with a
    return within range; ``points_camera_m`` / ``points_vehicle_m`` (m, 3) float64 and
    ``sigma_z_m`` (m,) belong to the valid samples only, in the same order.
    """

    measurement: Measurement
    samples: LineSamples
    valid: npt.NDArray[np.bool_]
    points_camera_m: FloatArray
    points_vehicle_m: FloatArray
    sigma_z_m: FloatArray
    diagnostics: Diagnostics
    objects: tuple[objects_mod.ObjectBox, ...] | None = None

    @property
    def faults(self) -> FaultBits:
        """FOREIGN_CODE when interference was detected, LOW_SIGNAL when no line was seen."""
        bits = FaultBits.NONE
        if self.diagnostics.interference:
            bits |= FaultBits.FOREIGN_CODE
        if len(self.samples) == 0:
            bits |= FaultBits.LOW_SIGNAL
        return bits


def foreign_energy(dmap: DistortionMap, spans: tuple[tuple[int, int], ...],
                   background_dn: float, threshold_dn: float) -> tuple[float, BoolArray]:
    """Energy of significantly negative map pixels over that of significantly positive
    ones (0..inf, 0.0 when neither), and the (W,) columns holding such negative pixels.
    Our own laser only adds positive values; a foreign or non-orthogonal modulation leaves
    residuals of both signs. Only line-like negative pixels count (their left and right
    neighbours are negative too), so shot noise in bright patches is not taken for
    foreign light. Saturated pixels are left out (clipping breaks the sum). One compiled
    pass over the rows read (:func:`atris_node.pipeline.peaks_kernels.signed_energy`)."""
    columns = np.zeros(dmap.values.shape[1], dtype=np.bool_)
    negative, positive = peaks_kernels.signed_energy(
        peaks_kernels.map_values(dmap.values), np.ascontiguousarray(dmap.saturated),
        np.array(spans, dtype=np.int64).reshape(-1, 2), np.float32(background_dn),
        np.float32(threshold_dn), columns)
    if negative == 0.0:
        return 0.0, columns
    return negative / max(positive, threshold_dn, 1.0), columns


def _with_doubts(doubts: tuple[IntArray, IntArray, IntArray], samples: LineSamples,
                 which: BoolArray) -> tuple[IntArray, IntArray, IntArray]:
    """``doubts`` (row, column, line) with the ``which`` samples added on their own line
    (rows and columns rounded): the range that line gives is where they cannot be, and
    which line is theirs is not known; a sector cannot be VALID farther nor free."""
    row, col, line = doubts
    return (np.concatenate([row, np.rint(samples.row_px[which]).astype(np.int64)]),
            np.concatenate([col, np.rint(samples.col_px[which]).astype(np.int64)]),
            np.concatenate([line, samples.line[which].astype(np.int64)]))


def _with_near(doubts: tuple[IntArray, IntArray, IntArray],
               stripes: tuple[IntArray, IntArray], top: Band | None, width: int
               ) -> tuple[tuple[IntArray, IntArray, IntArray], IntArray]:
    """``doubts`` (row, column, line) with the near guard's ``stripes`` (rows, columns)
    added on the ``top`` band's line (a range nearer than z_min: a sector they look into
    can be neither VALID nor free), and (W,) int64 the stripes per column."""
    row, col = stripes
    if top is None or not row.size:
        return doubts, np.zeros(width, dtype=np.int64)
    return ((np.concatenate([doubts[0], row]), np.concatenate([doubts[1], col]),
             np.concatenate([doubts[2], np.full(row.size, top.line, dtype=np.int64)])),
            per_column(col.astype(np.float64), width))


def _kept(samples: LineSamples, points: Points, vehicle: FloatArray, keep: BoolArray
          ) -> tuple[LineSamples, Points, FloatArray]:
    """The samples, their points and vehicle-frame points where ``keep`` is True."""
    return (select(samples, keep),
            Points(rows_where(points.xyz_m, keep), points.valid[keep], points.sigma_z_m[keep]),
            rows_where(vehicle, keep))


def _widen(columns: BoolArray, margin: int) -> BoolArray:
    """(W,) ``columns`` dilated by ``margin`` columns each side (one compiled pass,
    :func:`atris_node.pipeline.verdicts_kernels.widened`)."""
    return verdicts_kernels.widened(np.ascontiguousarray(columns, dtype=np.bool_), margin)


class Pipeline:
    """Distortion map -> :class:`PipelineResult` for one calibrated, mounted unit.

    Stateful only where the method needs history: the measurement counter, the closing
    speed tracker and the estimated ground plane.
    """

    def __init__(self, config: PipelineConfig, calibration: Calibration, mounting: Mounting,
                 layout: SectorLayout) -> None:
        self.config = config
        self.calibration = calibration
        self.mounting = mounting
        self.layout = layout
        cam, laser = calibration.camera, calibration.laser
        self.bands: tuple[Band, ...] = line_bands(cam, laser, config.z_min_m, config.z_max_m,
                                                  config.band_margin_px)
        self._extractor = replace(config.extractor(), narrowest_sigma_px=narrowest_stripe_px(
            calibration.laser.stripe_sigma_px))
        self._sectors = config.sectors()
        self._tracker = ClosingTracker()
        self._ground = GroundPlane()
        self._prior = visibility_prior(calibration, mounting, self._ground, config)
        self._counter = 0
        self._width = cam.width_px
        self._no_samples = np.zeros(cam.width_px, dtype=np.int64)  # (W,), read-only
        #: (K, W) the rows of the last map's samples by line (persistence.rows_by_line;
        #: None before the first map and with ``still_lines`` off)
        self._earlier_rows: FloatArray | None = None
        self._no_samples.flags.writeable = False
        self._judge = SectorJudge(calibration, mounting, layout, self._sectors,
                                  (config.z_min_m, config.z_max_m), config.ground_clearance_m)
        self.roi = (RoiTracker(self.bands, RoiSettings(
            full_every=config.roi_full_every)) if config.roi_narrowing and config.roi_bands
            else None)
        for kernels in (peaks_kernels, identity_kernels, alignment_kernels, rivals,
                        verdicts_kernels, radiometry_kernels, persistence, dimming):
            kernels.warm_up()  # the first map does not wait for the compiled code
        logger.debug("pipeline bands: %s", self.bands)
        if config.min_reflectance > 0.0 and not radiometry.calibrated(calibration.laser):
            logger.info("no radiometric calibration (return_dn_m2): a return too faint for "
                        "its range is not looked for; 'atris calib radiometry' measures it")
        if self.bands and not self._prior.looks_beyond.any():
            # every sheet meets the ground within z_max in every column: nothing beyond
            # the farthest ground hit is looked at, so no sector can be free (NO_RETURN)
            reach = np.asarray(self._prior.ground_range_m)
            logger.warning("every sheet meets the ground within z_max %.2f m (the farthest "
                           "at %.2f m camera range): no sector can be reported free; set "
                           "z_max_m below that to have free sectors", config.z_max_m,
                           float(np.max(reach[np.isfinite(reach)], initial=0.0)))

    def process(self, dmap: DistortionMap) -> PipelineResult:
        """Run the chain on one map of the calibrated image size."""
        self._check_shape(dmap)
        timings: dict[str, float] = {}
        start = time.perf_counter()
        extraction, whole = self._extract(dmap)
        timings["lines"] = _lap(start)
        samples, removed = self._clean_samples(extraction.samples)
        points, vehicle = self._triangulate(samples)
        faint = radiometry.whole_columns(samples.col_px,
                                         self._too_faint(dmap, extraction, samples, points))
        doubts, near = _with_near(extraction.doubts, self._near_stripes(dmap),
                                  topmost(self.bands), self._width)
        if faint.any():  # not at the range their line gives: doubts, not points
            doubts = _with_doubts(doubts, samples, faint)
            removed = removed + per_column(samples.col_px[faint], self._width)
            samples, points, vehicle = _kept(samples, points, vehicle, ~faint)
        flipped, earlier = self._flipped(samples, points)
        if flipped.any():  # a still stripe given another line than a map earlier: doubts
            doubts = _with_doubts(_with_doubts(doubts, samples, flipped), earlier,
                                  np.ones(len(earlier), dtype=np.bool_))
            removed = removed + per_column(samples.col_px[flipped], self._width)
            samples, points, vehicle = _kept(samples, points, vehicle, ~flipped)
        if self.config.still_lines:
            self._earlier_rows = persistence.rows_by_line(samples, len(self.bands),
                                                          self._width)
        dim = dimming.dimmed(samples, len(self.bands), self._width, self.config.snr_min)
        dims = None
        if dim.any():  # a bright line dimmed over a few columns: its rays partly blocked
            removed = removed + per_column(samples.col_px[dim], self._width)
            dims = dimming.grid(samples, dim, len(self.bands), self._width)
            samples, points, vehicle = _kept(samples, points, vehicle, ~dim)
        timings["triangulate"] = _lap(start)
        if self._ground_due():
            self._update_ground(rows_where(vehicle, points.valid))
        # the samples dropped by the cleaning count as doubtful in their columns
        result = self._assemble(dmap, replace(
            extraction, samples=samples, dropped=extraction.dropped + int(removed.sum()),
            doubtful_columns=extraction.doubtful_columns + removed + near, doubts=doubts,
            too_faint=int(faint.sum()), near=int(near.sum()), dimmed=dims), points, vehicle,
            timings)
        timings["sectors"] = _lap(start)
        if self.roi is not None:
            self.roi.update(extraction.samples, whole, result.diagnostics.interference)
        self._export(result, dmap.last_sequence)
        timings["total"] = _lap(start)
        self._counter += 1
        return result

    def _extract(self, dmap: DistortionMap) -> tuple[Extraction, bool]:
        """Line samples of ``dmap``, and True when the whole bands were searched (always
        without ROI narrowing; with it, when a full search was due or something showed
        outside the recent rows)."""
        search = None if self.roi is None else self.roi.search_rows()
        extraction = extract_lines(dmap.values, dmap.saturated, self.bands, self._extractor,
                                   roi_bands=self.config.roi_bands, prior=self._prior,
                                   search=search, window=dmap.window)
        return extraction, not extraction.narrowed

    def _clean_samples(self, samples: LineSamples) -> tuple[LineSamples, IntArray]:
        """Lone samples (no neighbour on their line) dropped, then the median along lines;
        and (W,) int64 how many samples were dropped in each column."""
        width, lines = self.calibration.camera.width_px, len(self.bands)
        removed = self._no_samples
        if self.config.drop_lone_samples:
            keep = supported_along_lines(samples, lines, width)
            removed = per_column(samples.col_px[~keep], width)
            samples = select(samples, keep)
        return smooth_along_lines(samples, lines, width, self.config.smooth_columns), removed

    def _too_faint(self, dmap: DistortionMap, extraction: Extraction, samples: LineSamples,
                   points: Points) -> BoolArray:
        """(n,) the samples too faint for the range their line gives: under
        ``min_reflectance``, or under ``tied_reflectance`` where continuity chose their
        line, the nearest hypothesis, over farther rivals (``extraction.tied``): a tie the
        physics left open is settled by rows from other columns, which a comb shifted by
        whole lines matches as well (a far wall's comb one line off reads as the comb of a
        pole 0.97 m away), and a return that dark for the near range is no evidence of
        it. Where a rival is nearer, the chosen range is the farther one, and a faint
        return there says nothing against it (a black glossy wall at 3.7 m)."""
        tied, stricter = extraction.tied, None
        if tied is not None and self.config.tied_reflectance > self.config.min_reflectance:
            col = np.clip(np.rint(samples.col_px).astype(np.int64), 0, tied.shape[1] - 1)
            stricter = (self.config.tied_reflectance, tied[samples.line, col])
        return radiometry.too_faint(dmap.values, samples, points, dmap.code_length,
                                    self.calibration.laser, dmap.exposure_us or None,
                                    self.config.min_reflectance, stricter,
                                    extraction.noise_map)

    def _near_stripes(self, dmap: DistortionMap) -> tuple[IntArray, IntArray]:
        """(rows, columns) of the stripes above every band: a surface nearer than z_min
        (:mod:`atris_node.pipeline.near`; none where no row lies above the bands)."""
        return near_stripes(dmap.values, dmap.saturated, self.bands, self._extractor,
                            self.calibration.camera, self.calibration.laser,
                            code_length=dmap.code_length,
                            exposure_us=dmap.exposure_us or None,
                            min_reflectance=self.config.min_reflectance, window=dmap.window)

    def _flipped(self, samples: LineSamples, points: Points) -> tuple[BoolArray, LineSamples]:
        """(n,) the samples of the columns where a still stripe was given another line than
        in the map before, the two lines putting it on different obstacles
        (:mod:`atris_node.pipeline.persistence`), and the flipped samples under the
        earlier map's line: every sample of such a column is a doubt, the flipped ones at
        both lines' ranges (none without an earlier map or with ``still_lines`` off)."""
        flip, before = persistence.flipped(samples, self._earlier_rows)
        earlier = replace(select(samples, flip), line=before[flip])
        if len(earlier):  # only a flip between lines that give another obstacle counts
            conflict = persistence.conflicts(
                Points(rows_where(points.xyz_m, flip), points.valid[flip],
                       points.sigma_z_m[flip]), self._triangulate(earlier)[0])
            flip[flip] = conflict
            earlier = select(earlier, conflict)
        return radiometry.whole_columns(samples.col_px, flip), earlier

    def _check_shape(self, dmap: DistortionMap) -> None:
        cam = self.calibration.camera
        if dmap.values.shape != (cam.height_px, cam.width_px):
            raise ConfigError(f"distortion map is {dmap.values.shape[1]}x"
                              f"{dmap.values.shape[0]} but the calibration is for "
                              f"{cam.width_px}x{cam.height_px}")

    def _triangulate(self, samples: LineSamples) -> tuple[Points, FloatArray]:
        """Eq. 1 on undistorted samples; vehicle-frame points (n, 3) of every sample."""
        sigma_u = np.hypot(samples.sigma_u_px, self.config.sigma_u_px)
        points = triangulate_pixels(samples.row_px, samples.col_px, samples.line,
                                    self.calibration.camera, self.calibration.laser,
                                    z_max_m=self.config.z_max_m, sigma_u_px=sigma_u)
        return points, self.mounting.camera_to_vehicle(points.xyz_m.reshape(-1, 3))

    def _ground_due(self) -> bool:
        """True when this map's valid points are to refit the ground plane."""
        cfg = self.config
        return cfg.ground_plane == "estimate" and not self._counter % cfg.ground_estimate_every

    def _update_ground(self, vehicle: FloatArray) -> None:
        """Refit the ground plane to the (n, 3) vehicle-frame valid points (m) and, when a
        plane is found, the visibility prior over it."""
        cfg = self.config
        plane = estimate_ground(vehicle, self._ground)
        if plane is not None:
            self._ground = plane
            self._prior = visibility_prior(self.calibration, self.mounting, plane, cfg)
        logger.debug("ground plane: %s (fit %s)", self._ground, plane is not None)

    def _assemble(self, dmap: DistortionMap, extraction: Extraction, points: Points,
                  vehicle: FloatArray, timings: dict[str, float]) -> PipelineResult:
        samples, valid = extraction.samples, points.valid
        energy, negative = foreign_energy(dmap, extraction.spans, extraction.background_dn,
                                          self.config.snr_min * extraction.noise_floor_dn)
        foreign = _widen(extraction.foreign_columns | negative, FOREIGN_MARGIN_COLUMNS)
        clean = np.ones(len(samples), dtype=np.bool_)
        flagged = max(energy, extraction.unassigned / (len(self.bands) * foreign.size)) > (
            self.config.foreign_limit)
        blanked: set[int] = set()
        if flagged and self.config.invalid_on_interference:
            clean[:] = False
        elif flagged:
            clean = ~foreign[samples.col_px.astype(np.int64)]
            blanked = self._judge.sectors_of(foreign)
        height = self._ground.height(vehicle)
        obstacle = valid & (height > self.config.ground_clearance_m)
        data = (SectorInput(vehicle, obstacle, samples.snr, height) if clean.all() else
                SectorInput(rows_where(vehicle, clean), obstacle[clean], samples.snr[clean]))
        sectors = _blank(self._judge.judge(extraction, points, data, clean, foreign,
                                           self._prior, self._ground), blanked)
        sectors = _blank(sectors, faint_sectors(
            dmap.values, self.bands, samples, self._judge.column_sector,
            {s.index for s in sectors if s.state is SectorState.NO_RETURN},
            self.config.min_points))
        nearest = nearest_obstacle(sectors, data, self.layout)
        closing, ttc = self._tracker.update(
            None if nearest is None else nearest.distance_m,
            0.5 * (dmap.first_time_s + dmap.last_time_s), dmap.last_time_s,
            0.0 if nearest is None else nearest.sigma_m)
        measurement = Measurement(self._counter, sectors, dmap.last_time_s,
                                  dmap.last_sequence, nearest, closing, ttc)
        found = (self._objects(rows_where(vehicle, obstacle & clean)) if self.config.objects
                 else None)
        diagnostics = self._diagnostics(extraction, valid, (energy, int(foreign.sum())),
                                        timings)
        kept = np.flatnonzero(valid)  # by index: boolean indexing of (n, 3) is slow
        return PipelineResult(measurement, samples, valid, points.xyz_m.take(kept, axis=0),
                              vehicle.take(kept, axis=0), points.sigma_z_m.take(kept),
                              diagnostics, found)

    def _diagnostics(self, extraction: Extraction, valid: npt.NDArray[np.bool_],
                     foreign: tuple[float, int], timings: dict[str, float]) -> Diagnostics:
        slots = len(self.bands) * extraction.foreign_columns.size
        energy, columns = foreign
        unassigned = extraction.unassigned / slots
        foreign_unassigned = (extraction.unassigned - extraction.moving
                              - extraction.steps) / slots
        # the blanking above counts moving edges and steps too (they may hide the nearest
        # obstacle); the flag says foreign light, stripes of another projector, which own
        # moving stripes and the steps of a background are not
        return Diagnostics(
            noise_floor_dn=extraction.noise_floor_dn,
            valid_fraction=float(valid.sum()) / slots,
            weak=extraction.weak, dropped=extraction.dropped, ambiguous=extraction.ambiguous,
            saturated=int(extraction.samples.saturated.sum()),
            no_return=int((~valid).sum()), rows_read=extraction.rows_read,
            line_snr=extraction.line_snr, foreign_energy=energy,
            unassigned_fraction=unassigned, foreign_columns=columns,
            interference=max(energy, foreign_unassigned) > self.config.foreign_limit,
            ground=self._ground, timings_ms=timings,
            moving_fraction=extraction.moving / slots, step_fraction=extraction.steps / slots,
            too_faint=extraction.too_faint, near=extraction.near)

    def _objects(self, obstacle_points: FloatArray) -> tuple[objects_mod.ObjectBox, ...]:
        return objects_mod.cluster_objects(obstacle_points, self.config.object_eps_m,
                                           self.config.object_min_points)

    def _export(self, result: PipelineResult, sequence: int) -> None:
        cfg = self.config
        if cfg.export_dir is None or self._counter % cfg.export_every:
            return
        objects_mod.export_cloud(result.points_vehicle_m,
                                 Path(cfg.export_dir) / f"cloud_{sequence:08d}.ply")


def visibility_prior(calibration: Calibration, mounting: Mounting, ground: GroundPlane,
                     config: PipelineConfig) -> VisibilityPrior:
    """The :class:`VisibilityPrior` of a calibrated, mounted unit over ``ground``: for each
    line and column, the camera range z (m) where the line's plane comes down to the
    ground clearance (inf where it never does)."""
    cam, laser = calibration.camera, calibration.laser
    cot = 1.0 / np.tan(np.asarray(laser.alpha_rad, dtype=np.float64))
    v = (np.arange(cam.width_px) - cam.cx_px) / cam.focal_px
    n_cam = np.asarray(ground.normal) @ mounting.rotation  # plane normal in the camera frame
    origin = np.asarray(ground.normal) @ (
        mounting.rotation @ np.array([0.0, -laser.baseline_m, 0.0]) + mounting.translation)
    slope = n_cam[0] * v[None, :] + n_cam[1] * cot[:, None] + n_cam[2]  # (K, W) per metre
    rise = config.ground_clearance_m - origin - ground.offset_m
    ok = slope < 0
    z = np.where(ok, rise / np.where(ok, slope, -1.0), np.inf)
    return VisibilityPrior(cot, cam.focal_px, cam.cy_px, cam.height_px, laser.baseline_m,
                           config.z_max_m, np.where(z > 0, z, np.inf),
                           masking_px(cot, cam.focal_px, config.extractor().min_separation_px))


def _blank(sectors: tuple[SectorDistance, ...], indices: set[int]
           ) -> tuple[SectorDistance, ...]:
    """``sectors`` with those in ``indices`` made INVALID: columns with foreign light were
    left out, so what remains of such a sector may miss the nearest obstacle; or a faint
    return shows where the sector would have been free (:mod:`atris_node.pipeline.faint`)."""
    return tuple(SectorDistance(s.index, s.bearing_rad, SectorState.INVALID)
                 if s.index in indices else s for s in sectors)


def _lap(start: float) -> float:
    """Milliseconds since ``start`` (a ``time.perf_counter()`` value)."""
    return (time.perf_counter() - start) * 1e3
