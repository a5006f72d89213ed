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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from atris_node import objects as objects_mod
from atris_node.calibration import Calibration
from atris_node.errors import ConfigError
from atris_node.geometry import Points, triangulate, undistort_pixels
from atris_node.lines import (
    PEAK_METHODS,
    Band,
    Extraction,
    ExtractorSettings,
    LineSamples,
    extract_lines,
    line_bands,
)
from atris_node.mounting import Mounting
from atris_node.obstacles import (
    ClosingTracker,
    GroundPlane,
    SectorInput,
    SectorSettings,
    estimate_ground,
    nearest_obstacle,
    sector_distances,
)
from atris_node.sectors import SectorLayout
from atris_node.types import DistortionMap, FaultBits, Measurement

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
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
    quantile: float = 0.1
    min_confidence: float = 0.2
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
    foreign_limit: float = 0.05

    def __post_init__(self) -> None:
        _check(self.peak_method in PEAK_METHODS, "peak_method", self.peak_method,
               f"one of {PEAK_METHODS}")
        _check(self.ground_plane in GROUND_MODES, "ground_plane", self.ground_plane,
               f"one of {GROUND_MODES}")
        _check(0.0 < self.z_min_m < self.z_max_m, "z_min_m", self.z_min_m,
               f"> 0 and below z_max_m ({self.z_max_m})")
        for name in ("snr_min", "stripe_sigma_px", "fov_deg", "object_eps_m"):
            _check(getattr(self, name) > 0, name, getattr(self, name), "> 0")
        for name in ("band_margin_px", "sigma_u_px", "foreign_limit", "ground_clearance_m"):
            _check(getattr(self, name) >= 0, name, getattr(self, name), ">= 0")
        for name in ("sector_count", "min_points", "ground_estimate_every",
                     "object_min_points", "export_every"):
            _check(getattr(self, name) >= 1, name, getattr(self, name), "an integer >= 1")
        _check(0.0 <= self.quantile <= 0.5, "quantile", self.quantile, "in [0, 0.5]")
        _check(0.0 <= self.min_confidence <= 1.0, "min_confidence", self.min_confidence,
               "in [0, 1]")

    def layout(self) -> SectorLayout:
        """The :class:`SectorLayout` of ``sector_count`` and ``fov_deg``."""
        return SectorLayout(self.sector_count, float(np.deg2rad(self.fov_deg)))

    def extractor(self) -> ExtractorSettings:
        """The line-extraction part of the configuration."""
        return ExtractorSettings(self.peak_method, self.snr_min, self.stripe_sigma_px)

    def sectors(self) -> SectorSettings:
        """The sector part of the configuration."""
        return SectorSettings(self.min_points, self.quantile, self.min_confidence,
                              self.snr_min)


def _check(ok: bool, name: str, value: object, accepted: str) -> None:
    if not ok:
        raise ConfigError(f"pipeline.{name} = {value!r} is not accepted; it must be {accepted}")


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
    unassigned_fraction: float
    interference: bool
    ground: GroundPlane
    timings_ms: dict[str, float] = field(default_factory=dict)


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


def foreign_energy(values: npt.NDArray[np.generic], spans: list[tuple[int, int]],
                   background_dn: float, threshold_dn: float) -> float:
    """Energy of significantly negative map pixels over that of significantly positive
    ones (0..inf, 0.0 when neither). Our own laser only adds positive values; a foreign
    or non-orthogonal modulation leaves residuals of both signs."""
    negative = positive = 0.0
    for lo, hi in spans:
        block = values[lo:hi].astype(np.float32) - np.float32(background_dn)
        negative += float(-block[block < -threshold_dn].sum())
        positive += float(block[block > threshold_dn].sum())
    if negative == 0.0:
        return 0.0
    return negative / max(positive, threshold_dn, 1.0)


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
        self._extractor = config.extractor()
        self._sectors = config.sectors()
        self._tracker = ClosingTracker()
        self._ground = GroundPlane()
        self._counter = 0
        logger.debug("pipeline bands: %s", self.bands)

    def process(self, dmap: DistortionMap) -> PipelineResult:
        """Run the chain on one map of the calibrated image size."""
        self._check_shape(dmap)
        timings: dict[str, float] = {}
        start = time.perf_counter()
        extraction = extract_lines(dmap.values, dmap.saturated, self.bands, self._extractor,
                                   self.config.roi_bands)
        timings["lines"] = _lap(start)
        points, vehicle = self._triangulate(extraction.samples)
        timings["triangulate"] = _lap(start)
        self._update_ground(vehicle[points.valid])
        result = self._assemble(dmap, extraction, points, vehicle, timings)
        timings["sectors"] = _lap(start)
        self._export(result, dmap.last_sequence)
        timings["total"] = _lap(start)
        self._counter += 1
        return result

    def _check_shape(self, dmap: DistortionMap) -> None:
        cam = self.calibration.camera
        if dmap.values.shape != (cam.height_px, cam.width_px):
            raise ConfigError(f"distortion map is {dmap.values.shape[1]}x"
                              f"{dmap.values.shape[0]} but the calibration is for "
                              f"{cam.width_px}x{cam.height_px}")

    def _triangulate(self, samples: LineSamples) -> tuple[Points, FloatArray]:
        """Eq. 1 on undistorted samples; vehicle-frame points (n, 3) of every sample."""
        cam = self.calibration.camera
        u, v = undistort_pixels(samples.row_px, samples.col_px, cam)
        sigma_u = np.hypot(samples.sigma_u_px, self.config.sigma_u_px)
        points = triangulate(u, v, samples.line, cam, self.calibration.laser,
                             z_max_m=self.config.z_max_m, sigma_u_px=sigma_u)
        return points, self.mounting.camera_to_vehicle(points.xyz_m.reshape(-1, 3))

    def _update_ground(self, vehicle: FloatArray) -> None:
        cfg = self.config
        if cfg.ground_plane != "estimate" or self._counter % cfg.ground_estimate_every:
            return
        plane = estimate_ground(vehicle, self._ground)
        if plane is not None:
            self._ground = plane
        logger.debug("ground plane: %s (fit %s)", self._ground, plane is not None)

    def _assemble(self, dmap: DistortionMap, extraction: Extraction, points: Points,
                  vehicle: FloatArray, timings: dict[str, float]) -> PipelineResult:
        samples, valid = extraction.samples, points.valid
        obstacle = valid & (self._ground.height(vehicle) > self.config.ground_clearance_m)
        data = SectorInput(vehicle, obstacle, samples.snr)
        sectors = sector_distances(data, self.layout, self._sectors)
        nearest = nearest_obstacle(sectors, data, self.layout)
        closing, ttc = self._tracker.update(
            None if nearest is None else nearest.distance_m, dmap.last_time_s)
        measurement = Measurement(self._counter, sectors, dmap.last_time_s,
                                  dmap.last_sequence, nearest, closing, ttc)
        found = self._objects(vehicle[obstacle]) if self.config.objects else None
        return PipelineResult(measurement, samples, valid, points.xyz_m[valid], vehicle[valid],
                              points.sigma_z_m[valid],
                              self._diagnostics(dmap, extraction, valid, timings), found)

    def _diagnostics(self, dmap: DistortionMap, extraction: Extraction,
                     valid: npt.NDArray[np.bool_], timings: dict[str, float]) -> Diagnostics:
        slots = len(self.bands) * dmap.values.shape[1]
        energy = foreign_energy(dmap.values, list(extraction.spans), extraction.background_dn,
                                self.config.snr_min * extraction.noise_floor_dn)
        return Diagnostics(
            noise_floor_dn=extraction.noise_floor_dn,
            valid_fraction=float(valid.sum()) / slots,
            weak=extraction.weak, dropped=extraction.dropped, ambiguous=extraction.ambiguous,
            saturated=int(extraction.samples.saturated.sum()),
            no_return=int((~valid).sum()), rows_read=extraction.rows_read,
            line_snr=extraction.line_snr, foreign_energy=energy,
            unassigned_fraction=extraction.unassigned / slots,
            interference=max(energy, extraction.unassigned / slots) > self.config.foreign_limit,
            ground=self._ground,
            timings_ms=timings)

    def _objects(self, obstacle_points: FloatArray) -> tuple[objects_mod.ObjectBox, ...]:
        return objects_mod.cluster_objects(obstacle_points, self.config.object_eps_m,
                                           self.config.object_min_points)

    def _export(self, result: PipelineResult, sequence: int) -> None:
        cfg = self.config
        if cfg.export_dir is None or self._counter % cfg.export_every:
            return
        objects_mod.export_cloud(result.points_vehicle_m,
                                 Path(cfg.export_dir) / f"cloud_{sequence:08d}.ply")


def _lap(start: float) -> float:
    """Milliseconds since ``start`` (a ``time.perf_counter()`` value)."""
    return (time.perf_counter() - start) * 1e3
