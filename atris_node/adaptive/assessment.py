"""Scene assessment of one output frame (issue 11.1): what the scene asks of the unit.

Everything is read from data the unit already has: the distortion map's statistics
(``extra``: ``ambient_level``, ``saturated_fraction``, ``signal_dn`` = I_S and
``residual_dn`` = delta, paper Eq. 3-6), the pipeline's per-sample line SNR, and the
newest plain sub-frame (brightest ambient). The laser level per sub-frame follows from
``I_S = l N / 2 + delta``: ``l = 2 (I_S - delta) / N``, and the paper's Eq. 6 gives
``SNR = l N / (2 delta) + 1``.

Range error. A valid sample's range sigma is ``sigma_z = z^2 sigma_u / (f b)`` (DESIGN.md
section 2; m, with z in m, sigma_u in px, f in px, b in m), where the pipeline's row sigma is
``sigma_u = hypot(CRLB / SNR, sigma_cal)``: the sub-pixel fit's part falls as the line SNR
grows, the calibration floor ``sigma_cal`` does not. The assessment keeps the median fit
part over the valid samples, the floor and ``f b``, so that :meth:`SceneAssessment.range_sigma_m`
can predict ``sigma_z`` at any range and at another N (the SNR times a gain).

Motion shows as "gray trails": a moving edge leaves residuals of both signs in the map,
while the own laser only adds. ``motion`` is the energy of the significantly negative
strip pixels over that of the positive ones (0 for a still scene without foreign light).

Example:
    >>> a = SceneAssessment(16, 1000.0, 0.2, 0.5, 0.0, (9.0,), np.array([9.0], np.float32),
    ...                     640, 30.0, 20.0, 0.0, 0.0)
    >>> round(a.model_snr, 1)
    13.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.demod import strip_sample
from atris_node.types import DistortionMap, SubFrame

FloatArray = npt.NDArray[np.float32]
#: quantile of the plain sub-frame's strip pixels taken as "the brightest ambient"
PEAK_QUANTILE = 0.995
#: a map pixel is significant beyond this many robust sigmas (motion energy)
MOTION_SIGMAS = 6.0


@dataclass(frozen=True)
class SceneAssessment:
    """How the scene looked in one output frame. Levels are fractions of full scale;
    ``laser_dn`` (l, per sub-frame) and ``delta_dn`` are in DN of the map;
    ``column_snr`` (n,) float32 holds the SNR of every accepted line sample (one per line
    and column), ``slots`` the number of line-column places (lines x width).
    ``row_sigma_px`` is the median sub-pixel fit sigma (CRLB / SNR) of the ``valid_samples``
    samples with a range, ``row_floor_px`` the calibration's row sigma added to it in
    quadrature, ``focal_baseline_px_m`` the product f b (px m; 0.0 when unknown)."""

    code_length: int
    exposure_us: float
    ambient_level: float
    peak_level: float
    saturated_fraction: float
    line_snr: tuple[float, ...]
    column_snr: FloatArray
    slots: int
    laser_dn: float
    delta_dn: float
    foreign_energy: float
    motion: float
    row_sigma_px: float = 0.0
    row_floor_px: float = 0.0
    focal_baseline_px_m: float = 0.0
    valid_samples: int = 0

    @property
    def model_snr(self) -> float:
        """Paper Eq. 6, ``l N / (2 delta) + 1`` (delta floored above zero by the demod)."""
        return self.laser_dn * self.code_length / (2.0 * max(self.delta_dn, 1e-6)) + 1.0

    def share_above(self, snr: float, gain: float = 1.0) -> float:
        """Share of line-column places whose SNR times ``gain`` reaches ``snr`` (0..1)."""
        if self.slots <= 0:
            return 0.0
        return int(np.count_nonzero(self.column_snr * gain >= snr)) / self.slots

    def range_sigma_m(self, range_m: float, gain: float = 1.0) -> float | None:
        """Predicted range sigma (m) of a typical valid sample at ``range_m`` (m) when its
        SNR is multiplied by ``gain`` (> 0): ``range_m^2 hypot(row_sigma_px / gain,
        row_floor_px) / (f b)``. None when no sample had a range or f b is unknown: no
        prediction without data."""
        if self.valid_samples <= 0 or self.focal_baseline_px_m <= 0.0 or gain <= 0.0:
            return None
        sigma_u_px = math.hypot(self.row_sigma_px / gain, self.row_floor_px)
        return range_m * range_m * sigma_u_px / self.focal_baseline_px_m

    def log_fields(self) -> str:
        """One log line of the assessment."""
        lines = ",".join(f"{s:.1f}" for s in self.line_snr)
        return (f"N={self.code_length} exposure={self.exposure_us:.1f}us "
                f"ambient={self.ambient_level:.3f} peak={self.peak_level:.3f} "
                f"saturated={self.saturated_fraction:.4f} l={self.laser_dn:.2f}DN "
                f"delta={self.delta_dn:.2f}DN line_snr=[{lines}] "
                f"foreign={self.foreign_energy:.3f} motion={self.motion:.3f} "
                f"row_sigma={self.row_sigma_px:.3f}px valid={self.valid_samples}")


def laser_level_dn(signal_dn: float, delta_dn: float, code_length: int) -> float:
    """``l = 2 (I_S - delta) / N`` in DN per sub-frame, 0.0 when no laser was found."""
    if signal_dn <= 0.0 or code_length <= 0:
        return 0.0
    return max(2.0 * (signal_dn - delta_dn) / code_length, 0.0)


def peak_level(sub: SubFrame | None) -> float:
    """The brightest ambient of a plain sub-frame: the PEAK_QUANTILE of its column strips,
    as a fraction of full scale (0.0 without a sub-frame)."""
    if sub is None:
        return 0.0
    full_scale = float((1 << sub.bits) - 1)
    sample = np.asarray(strip_sample(sub.pixels), dtype=np.float32)
    return float(np.quantile(sample, PEAK_QUANTILE)) / full_scale


def motion_energy(dmap: DistortionMap) -> float:
    """Energy of significantly negative strip pixels over that of positive ones (>= 0).

    The robust sigma (1.4826 MAD) of the strip sample sets the significance level; the
    positive energy is floored at one DN^2 per sampled pixel so a dark map gives 0."""
    sample = strip_sample(dmap.values).astype(np.float32).ravel()
    centre = float(np.median(sample))
    sigma = 1.4826 * float(np.median(np.abs(sample - centre))) + 0.5
    high = sample[sample > centre + MOTION_SIGMAS * sigma] - centre
    low = sample[sample < centre - MOTION_SIGMAS * sigma] - centre
    positive = max(float(high @ high), float(sample.size))
    return float(low @ low) / positive


@dataclass(frozen=True)
class RangeModel:
    """What the range sigma of a map's samples is made of: ``row_sigma_px`` (m,) the fit
    sigma of the samples with a range (px), ``row_floor_px`` the calibration's row sigma
    (px) and ``focal_baseline_px_m`` = f b (px m)."""

    row_sigma_px: FloatArray
    row_floor_px: float
    focal_baseline_px_m: float


def assess(dmap: DistortionMap, samples_snr: FloatArray, line_snr: tuple[float, ...],
           foreign_energy: float, sub: SubFrame | None,
           ranges: RangeModel | None = None) -> SceneAssessment:
    """The :class:`SceneAssessment` of one map, its pipeline result and the newest
    plain sub-frame. ``samples_snr`` (n,) are the accepted samples' SNRs; ``ranges`` the
    row sigmas of the samples with a range (None: no range prediction)."""
    extra = dmap.extra
    delta = float(extra.get("residual_dn", 0.0))
    laser = laser_level_dn(float(extra.get("signal_dn", 0.0)), delta, dmap.code_length)
    width = int(dmap.values.shape[1])
    sigma = _finite(ranges.row_sigma_px) if ranges is not None else np.zeros(0)
    return SceneAssessment(
        code_length=dmap.code_length,
        exposure_us=0.0 if sub is None else float(sub.exposure_us),
        ambient_level=float(extra.get("ambient_level", 0.0)), peak_level=peak_level(sub),
        saturated_fraction=float(extra.get("saturated_fraction", 0.0)),
        line_snr=tuple(float(s) for s in line_snr),
        column_snr=np.asarray(samples_snr, dtype=np.float32),
        slots=max(len(line_snr), 1) * width, laser_dn=laser, delta_dn=delta,
        foreign_energy=float(foreign_energy), motion=motion_energy(dmap),
        row_sigma_px=float(np.median(sigma)) if sigma.size else 0.0,
        row_floor_px=0.0 if ranges is None else float(ranges.row_floor_px),
        focal_baseline_px_m=0.0 if ranges is None else float(ranges.focal_baseline_px_m),
        valid_samples=int(sigma.size))


def _finite(values: FloatArray) -> npt.NDArray[np.float64]:
    """``values`` as float64 without NaN or inf."""
    out = np.asarray(values, dtype=np.float64)
    return out[np.isfinite(out)]
