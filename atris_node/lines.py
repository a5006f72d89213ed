"""Sub-pixel line extraction, line identification and ROI bands on the distortion map.

A projected line k can only be imaged between its rows at ``z_min`` and ``z_max``
(``u = f·cot α_k - f·b/z``, see :mod:`atris_node.geometry`), widened by the lens distortion
and a margin: its *band*. Each column of each band is searched for its strongest pixel
(vectorised ``argmax``), which is refined to a sub-pixel row by one of five peak methods on
a few neighbours taken with fancy indexing. Rows outside every band are never read.

Peak methods (``PEAK_METHODS``), all on the column profile around the integer maximum:

- ``cog``: centre of gravity of the values above 3 noise floors within ±2.5 σ_stripe;
- ``parabolic``: vertex of the parabola through 3 points;
- ``gaussian``: vertex of the parabola through the logarithms of 3 points (exact for a
  sampled Gaussian);
- ``blais_rioux``: zero crossing of the 4th-order derivative filter
  ``g(i) = f(i-2) + f(i-1) - f(i+1) - f(i+2)`` (Blais & Rioux 1986);
- ``steger``: zero of the first Gaussian derivative of the profile (Steger's ridge
  detector along the column), refined by Newton steps with kernels sampled at the
  sub-pixel position.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.errors import ConfigError
from atris_node.geometry import distort_pixels, line_row_at_range

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

PEAK_METHODS = ("cog", "parabolic", "gaussian", "blais_rioux", "steger")
#: distance from the median to the lower quartile of a normal distribution, in σ
QUARTILE_TO_SIGMA = 0.6745
#: the smallest noise floor used, DN (quantisation of an integer map is 0.29 DN)
MIN_NOISE_DN = 0.5
#: uncertainty given to the centre of a flat-topped (saturated) stripe, pixels
SATURATED_SIGMA_PX = 0.5
#: half window (px) searched for the saturated run of a flat-topped stripe
SATURATION_WINDOW_PX = 8
#: columns per block of the continuity reference used to resolve overlapping bands
CONTINUITY_BLOCK = 32


@dataclass(frozen=True)
class Band:
    """Rows ``[row_lo, row_hi)`` of the observed image where line ``line`` can appear."""

    line: int
    row_lo: int
    row_hi: int

    @property
    def empty(self) -> bool:
        """True when the band lies entirely outside the image."""
        return self.row_hi <= self.row_lo


@dataclass(frozen=True)
class ExtractorSettings:
    """How peaks are found: method, acceptance SNR, stripe σ (px), pair separation (px)."""

    peak_method: str = "gaussian"
    snr_min: float = 6.0
    stripe_sigma_px: float = 1.5
    min_separation_px: int = 3

    def __post_init__(self) -> None:
        if self.peak_method not in PEAK_METHODS:
            raise ConfigError(f"peak_method {self.peak_method!r} is not one of {PEAK_METHODS}")
        if not self.stripe_sigma_px > 0:
            raise ConfigError(f"stripe_sigma_px must be > 0, got {self.stripe_sigma_px}")

    @property
    def radius(self) -> int:
        """Half window (px) the peak method reads around the integer maximum."""
        s = self.stripe_sigma_px
        return {"cog": max(2, int(np.ceil(2.5 * s))), "parabolic": 1, "gaussian": 1,
                "blais_rioux": 3, "steger": int(np.ceil(3.0 * s)) + 2}[self.peak_method]


@dataclass(frozen=True)
class LineSamples:
    """Accepted sub-pixel line samples, all arrays (n,).

    ``row_px`` is the observed (distorted) sub-pixel image row, ``col_px`` the column (px),
    ``snr`` the peak over the noise floor, ``sigma_u_px`` the row uncertainty (px),
    ``saturated`` True for centres of flat-topped stripes.
    """

    line: IntArray
    row_px: FloatArray
    col_px: FloatArray
    snr: FloatArray
    sigma_u_px: FloatArray
    saturated: BoolArray

    def __len__(self) -> int:
        return int(self.line.size)


@dataclass(frozen=True)
class Extraction:
    """Samples plus the counts that say how the search went."""

    samples: LineSamples
    noise_floor_dn: float
    weak: int  # column slots without a peak above snr_min
    dropped: int  # peaks above snr_min rejected (window off the image, failed fit)
    ambiguous: int  # peaks whose line could not be told from order and continuity
    rows_read: int  # map rows read (union of bands plus fit padding)
    line_snr: tuple[float, ...]  # median SNR of the accepted samples per line, 0 if none


# --------------------------------------------------------------------------- bands


def line_bands(camera: CameraModel, laser: LaserCalibration, z_min_m: float,
               z_max_m: float, margin_px: float) -> tuple[Band, ...]:
    """Observed row band of every line for ranges ``[z_min_m, z_max_m]``.

    The band edges are the rows at z_min and z_max, pushed through the lens distortion
    at 17 columns across the image, widened by ``margin_px`` and clipped to the image.
    """
    cols = np.linspace(0.0, camera.width_px - 1.0, 17)
    bands = []
    for k in range(len(laser.alpha_rad)):
        u = [line_row_at_range(k, z, camera, laser) for z in (z_min_m, z_max_m)]
        rows = np.concatenate([distort_pixels(np.full_like(cols, ui + camera.cy_px), cols,
                                              camera)[0] for ui in u])
        lo = max(int(np.floor(rows.min() - margin_px)), 0)
        hi = min(int(np.ceil(rows.max() + margin_px)) + 1, camera.height_px)
        bands.append(Band(k, lo, max(hi, lo)))
    return tuple(bands)


def read_padding(settings: ExtractorSettings) -> int:
    """Rows read beyond each band edge: the fit window and the saturation window."""
    return max(settings.radius, SATURATION_WINDOW_PX)


def read_rows(bands: tuple[Band, ...], pad: int, height: int) -> list[tuple[int, int]]:
    """Merged row intervals ``[lo, hi)`` covering every band plus ``pad`` rows each side."""
    spans = sorted((max(b.row_lo - pad, 0), min(b.row_hi + pad, height))
                   for b in bands if not b.empty)
    merged: list[tuple[int, int]] = []
    for lo, hi in spans:
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged


# --------------------------------------------------------------------------- noise


def noise_floor(values: npt.NDArray[np.generic], spans: list[tuple[int, int]]) -> tuple[
        float, float]:
    """(median, robust σ) in DN of the map rows in ``spans`` (a 2×2 subsample).

    σ comes from the lower quartile, ``(median - q25) / 0.6745``: laser pixels only add
    positive values, so the lower half of the distribution is background noise alone.
    """
    parts = [values[lo:hi:2, ::2].ravel() for lo, hi in spans]
    if not parts or sum(p.size for p in parts) == 0:
        return 0.0, MIN_NOISE_DN
    sample = np.concatenate(parts).astype(np.float32)
    q25, median = np.percentile(sample, [25.0, 50.0])
    return float(median), max(float(median - q25) / QUARTILE_TO_SIGMA, MIN_NOISE_DN)


# --------------------------------------------------------------------------- sub-pixel


def _parabolic(win: FloatArray, r: int) -> tuple[FloatArray, BoolArray]:
    a, b, c = win[:, r - 1], win[:, r], win[:, r + 1]
    den = a - 2.0 * b + c
    ok = den < 0
    return 0.5 * np.divide(a - c, den, out=np.zeros_like(a), where=ok), ok


def _gaussian(win: FloatArray, r: int) -> tuple[FloatArray, BoolArray]:
    three = win[:, r - 1:r + 2]
    positive = (three > 0).all(axis=1)
    lg = np.log(np.maximum(three, 1e-9))
    offset, ok = _parabolic(lg, 1)
    return offset, ok & positive


def _cog(win: FloatArray, r: int, threshold: float) -> tuple[FloatArray, BoolArray]:
    w = np.maximum(win - threshold, 0.0)
    total = w.sum(axis=1)
    ok = total > 0
    idx = np.arange(-r, r + 1, dtype=np.float64)
    return np.divide(w @ idx, total, out=np.zeros_like(total), where=ok), ok


def _blais_rioux(win: FloatArray, r: int) -> tuple[FloatArray, BoolArray]:
    def g(j: int) -> FloatArray:
        return win[:, j - 2] + win[:, j - 1] - win[:, j + 1] - win[:, j + 2]

    gm, g0, g1 = g(r - 1), g(r), g(r + 1)
    right = g0 < 0  # still rising at the maximum: the crossing is between r and r + 1
    den = np.where(right, g0 - g1, gm - g0)
    ok = den != 0
    t = np.divide(np.where(right, g0, gm), den, out=np.zeros_like(g0), where=ok)
    return np.where(right, t, t - 1.0), ok & (t >= 0) & (t <= 1)


def _steger(win: FloatArray, r: int, sigma: float) -> tuple[FloatArray, BoolArray]:
    k = np.arange(-r, r + 1, dtype=np.float64)
    t = np.zeros(win.shape[0])
    second = np.full(win.shape[0], -1.0)
    for _ in range(3):
        x = t[:, None] - k[None, :]
        gauss = np.exp(-0.5 * (x / sigma) ** 2)
        first = (win * (-x / sigma**2) * gauss).sum(axis=1)
        second = (win * ((x * x / sigma**2 - 1.0) / sigma**2) * gauss).sum(axis=1)
        step = np.divide(first, second, out=np.zeros_like(t), where=second < 0)
        t = np.clip(t - step, -1.0, 1.0)
    return t, (second < 0) & (np.abs(t) < 1.0)


def subpixel_offset(window: FloatArray, settings: ExtractorSettings,
                    noise_dn: float = 0.0) -> tuple[FloatArray, BoolArray]:
    """Sub-pixel offset (px, in [-1, 1]) of the peak in each row of ``window``.

    ``window`` is (n, 2R+1) float64, the column profile centred on the integer maximum,
    R = ``settings.radius``. Returns (offset (n,) float64, ok (n,) bool).
    """
    r = settings.radius
    methods: dict[str, Callable[[], tuple[FloatArray, BoolArray]]] = {
        "cog": lambda: _cog(window, r, 3.0 * noise_dn),
        "parabolic": lambda: _parabolic(window, r),
        "gaussian": lambda: _gaussian(window, r),
        "blais_rioux": lambda: _blais_rioux(window, r),
        "steger": lambda: _steger(window, r, settings.stripe_sigma_px),
    }
    offset, ok = methods[settings.peak_method]()
    return offset, ok & (np.abs(offset) <= 1.0)


def _windows(values: npt.NDArray[np.generic], rows: IntArray, cols: IntArray,
             r: int) -> tuple[FloatArray, BoolArray]:
    """(n, 2r+1) profiles of ``values`` around (rows, cols); ok False where clipped."""
    idx = rows[:, None] + np.arange(-r, r + 1)[None, :]
    inside = (idx[:, 0] >= 0) & (idx[:, -1] < values.shape[0])
    idx = np.clip(idx, 0, values.shape[0] - 1)
    return values[idx, cols[:, None]].astype(np.float64), inside


def saturated_centre(saturated: BoolArray, rows: IntArray, cols: IntArray,
                     r: int = SATURATION_WINDOW_PX) -> FloatArray:
    """Centre row (px) of the saturated pixels within ±r rows of (rows, cols), float64."""
    mask, _ = _windows(saturated.astype(np.float64), rows, cols, r)
    offsets = np.arange(-r, r + 1, dtype=np.float64)
    count = np.maximum(mask.sum(axis=1), 1.0)
    return rows + (mask @ offsets) / count


# --------------------------------------------------------------------------- search


def _band_maxima(values: npt.NDArray[np.generic], band: Band) -> IntArray:
    """(W,) absolute row of the largest value of each column inside ``band``."""
    if band.empty:
        return np.full(values.shape[1], -1, dtype=np.int64)
    return band.row_lo + np.argmax(values[band.row_lo:band.row_hi], axis=0).astype(np.int64)


def _masked_maxima(values: npt.NDArray[np.generic], band: Band, cols: IntArray,
                   allowed_lo: IntArray, allowed_hi: IntArray) -> IntArray:
    """Re-search ``band`` in ``cols`` only between rows [allowed_lo, allowed_hi) per column."""
    if cols.size == 0 or band.empty:
        return np.full(cols.size, -1, dtype=np.int64)
    block = values[band.row_lo:band.row_hi][:, cols].astype(np.float64)
    rows = np.arange(band.row_lo, band.row_hi)[:, None]
    block[(rows < allowed_lo[None, :]) | (rows >= allowed_hi[None, :])] = -np.inf
    best = np.argmax(block, axis=0)
    found = np.isfinite(block[best, np.arange(cols.size)])
    return np.where(found, band.row_lo + best, -1).astype(np.int64)


def _snr_at(values: npt.NDArray[np.generic], rows: IntArray, background: float,
            noise: float) -> FloatArray:
    """(W,) SNR of ``values[rows[c], c]``; 0 where ``rows`` is -1."""
    cols = np.arange(rows.size)
    peak = values[np.maximum(rows, 0), cols].astype(np.float64)
    return np.where(rows >= 0, (peak - background) / noise, 0.0)


def _continuity_reference(rows: IntArray, good: BoolArray) -> FloatArray:
    """(W,) block median of the good rows around each column; inf where a block has none."""
    w = rows.size
    nb = -(-w // CONTINUITY_BLOCK)
    padded = np.full(nb * CONTINUITY_BLOCK, np.inf)
    padded[:w] = np.where(good, rows, np.inf)
    blocks = np.sort(padded.reshape(nb, CONTINUITY_BLOCK), axis=1)
    count = np.isfinite(blocks).sum(axis=1)
    median = np.where(count > 0, blocks[np.arange(nb), count // 2], np.inf)
    return np.asarray(np.repeat(median, CONTINUITY_BLOCK)[:w], dtype=np.float64)


@dataclass
class _Search:
    """Working state of the per-line search: rows (K, W), -1 where no candidate."""

    values: npt.NDArray[np.generic]
    bands: tuple[Band, ...]
    rows: IntArray
    background: float
    noise: float
    snr_min: float
    sep: int
    ambiguous: int = 0

    def ok(self, k: int) -> BoolArray:
        return _snr_at(self.values, self.rows[k], self.background, self.noise) >= self.snr_min

    def swap_crossed(self, k: int) -> None:
        """Order: line k is above line k+1; two distinct peaks found crossed are swapped."""
        crossed = self.ok(k) & self.ok(k + 1) & (self.rows[k + 1] < self.rows[k] - self.sep)
        self.rows[k, crossed], self.rows[k + 1, crossed] = (self.rows[k + 1, crossed],
                                                            self.rows[k, crossed])

    def resolve_shared(self, k: int) -> None:
        """A peak claimed by lines k and k+1 goes to the line that leaves the other one a
        stripe of its own (searched again away from the peak), else to the line it
        continues; peaks neither rule can place are dropped and counted ambiguous."""
        ok_k, ok_k1 = self.ok(k), self.ok(k + 1)
        cols = np.flatnonzero(ok_k & ok_k1 & (self.rows[k + 1] - self.rows[k] < self.sep))
        if cols.size == 0:
            return
        peak = self.rows[k, cols]
        above = self._strong(k, cols, np.zeros_like(peak), peak - self.sep + 1)
        below = self._strong(k + 1, cols, peak + self.sep, np.full_like(peak, 1 << 30))
        good_k, good_k1 = ok_k.copy(), ok_k1.copy()
        good_k[cols] = good_k1[cols] = False
        d_k = np.abs(peak - _continuity_reference(self.rows[k], good_k)[cols])
        d_k1 = np.abs(peak - _continuity_reference(self.rows[k + 1], good_k1)[cols])
        to_k = (below >= 0) & (above < 0)
        to_k1 = (above >= 0) & (below < 0)
        tie = ~to_k & ~to_k1
        to_k |= tie & np.isfinite(d_k) & (d_k + self.sep <= d_k1)
        to_k1 |= tie & np.isfinite(d_k1) & (d_k1 + self.sep <= d_k)
        self.rows[k + 1, cols] = np.where(to_k, below, np.where(to_k1, peak, -1))
        self.rows[k, cols] = np.where(to_k1, above, np.where(to_k, peak, -1))
        self.ambiguous += int((~to_k & ~to_k1).sum())

    def _strong(self, k: int, cols: IntArray, lo: IntArray, hi: IntArray) -> IntArray:
        """Strongest row of line k's band in ``cols`` between [lo, hi); -1 if below SNR."""
        rows = _masked_maxima(self.values, self.bands[k], cols, lo, hi)
        peak = self.values[np.maximum(rows, 0), cols].astype(np.float64)
        strong = (rows >= 0) & ((peak - self.background) / self.noise >= self.snr_min)
        return np.where(strong, rows, -1)


def search_roi(values: npt.NDArray[np.generic], bands: tuple[Band, ...], background: float,
               noise: float, settings: ExtractorSettings) -> tuple[IntArray, int]:
    """(K, W) integer peak rows per line (-1 = none) from each line's own band, and the
    number of ambiguous peaks; overlapping bands are resolved by order and continuity."""
    rows = np.stack([_band_maxima(values, b) for b in bands])
    state = _Search(values, bands, rows, background, noise, settings.snr_min,
                    settings.min_separation_px)
    for k in range(len(bands) - 1):
        if bands[k].row_hi > bands[k + 1].row_lo:
            state.swap_crossed(k)
            state.resolve_shared(k)
    return state.rows, state.ambiguous


def _top_peaks(values: npt.NDArray[np.generic], count: int, sep: int) -> IntArray:
    """(count, W) rows of the ``count`` largest peaks of each column, ±sep suppressed."""
    work = values.astype(np.float32)
    cols = np.arange(values.shape[1])
    found = np.empty((count, values.shape[1]), dtype=np.int64)
    for i in range(count):
        found[i] = np.argmax(work, axis=0)
        for d in range(-sep, sep + 1):
            work[np.clip(found[i] + d, 0, values.shape[0] - 1), cols] = -np.inf
    return np.sort(found, axis=0)


def _band_count(rows: IntArray, bands: tuple[Band, ...]) -> IntArray:
    """How many bands hold each entry of ``rows`` (any shape of row numbers)."""
    return sum((((rows >= b.row_lo) & (rows < b.row_hi)).astype(np.int64) for b in bands),
               np.zeros(rows.shape, dtype=np.int64))


def search_full(values: npt.NDArray[np.generic], bands: tuple[Band, ...], background: float,
                noise: float, settings: ExtractorSettings) -> tuple[IntArray, int]:
    """(K, W) peak rows per line (-1 = none) from the K strongest peaks of each whole
    column (ROI bands off). Peaks are given to lines in row order within each line's band;
    a peak inside two bands in a column with fewer than K peaks is ambiguous and dropped."""
    k_lines, width = len(bands), values.shape[1]
    peaks = _top_peaks(values, k_lines, settings.min_separation_px)
    strong = np.stack([_snr_at(values, p, background, noise) >= settings.snr_min
                       for p in peaks])
    rows = np.full((k_lines, width), -1, dtype=np.int64)
    taken = np.full(width, -1)
    order = np.arange(k_lines)[:, None]
    for k, band in enumerate(bands):
        free = strong & (peaks >= band.row_lo) & (peaks < band.row_hi) & (order > taken)
        has = free.any(axis=0)
        first = np.argmax(free, axis=0)
        rows[k] = np.where(has, peaks[first, np.arange(width)], -1)
        taken = np.where(has, first, taken)
    short = (strong & (_band_count(peaks, bands) > 0)).sum(axis=0) < k_lines
    unsure = (rows >= 0) & (_band_count(rows, bands) >= 2) & short[None, :]
    rows[unsure] = -1
    return rows, int(unsure.sum())


# --------------------------------------------------------------------------- extraction


def _refine(values: npt.NDArray[np.generic], saturated: BoolArray, rows: IntArray,
            cols: IntArray, *, settings: ExtractorSettings, noise: float,
            snr: FloatArray) -> tuple[FloatArray, FloatArray, BoolArray, BoolArray]:
    """Sub-pixel rows, σ_u (px), saturated flags and ok for integer peaks (n,)."""
    r = settings.radius
    window, inside = _windows(values, rows, cols, r)
    local_max = (window[:, r] >= window[:, r - 1]) & (window[:, r] >= window[:, r + 1])
    offset, ok = subpixel_offset(window, settings, noise)
    near, _ = _windows(saturated.astype(np.float64), rows, cols, 1)
    flat = np.asarray(near.any(axis=1), dtype=np.bool_)
    row = np.where(flat, saturated_centre(saturated, rows, cols), rows + offset)
    crlb = np.sqrt(2.0 * settings.stripe_sigma_px / np.sqrt(np.pi))
    sigma = np.where(flat, SATURATED_SIGMA_PX, crlb / np.maximum(snr, 1.0))
    return row, sigma, flat, inside & (flat | (ok & local_max))


def _median_per_line(line: IntArray, snr: FloatArray, count: int) -> tuple[float, ...]:
    """Median SNR of the samples of each of ``count`` lines, 0.0 for a line without any."""
    return tuple(float(np.median(snr[line == k])) if (line == k).any() else 0.0
                 for k in range(count))


def extract_lines(values: npt.NDArray[np.generic], saturated: BoolArray,
                  bands: tuple[Band, ...], settings: ExtractorSettings,
                  roi_bands: bool = True) -> Extraction:
    """Line samples of a distortion map.

    Args:
        values: (H, W) int16/int32 (or float) demodulated map, DN.
        saturated: (H, W) bool saturation mask of the same map.
        bands: one :class:`Band` per line, from :func:`line_bands`.
        settings: peak method, SNR threshold, stripe σ.
        roi_bands: True reads only the bands (plus :func:`read_padding` rows); False
            searches every whole column for the K strongest peaks and identifies them by
            band and order.
    """
    height = values.shape[0]
    spans = read_rows(bands, read_padding(settings), height) if roi_bands else [(0, height)]
    background, noise = noise_floor(values, spans)
    search = search_roi if roi_bands else search_full
    rows, ambiguous = search(values, bands, background, noise, settings)
    line, cols = np.nonzero(rows >= 0)
    peak_rows = rows[line, cols]
    snr = (values[peak_rows, cols].astype(np.float64) - background) / noise
    strong = snr >= settings.snr_min
    line, cols, peak_rows, snr = line[strong], cols[strong], peak_rows[strong], snr[strong]
    row, sigma, flat, ok = _refine(values, saturated, peak_rows, cols,
                                   settings=settings, noise=noise, snr=snr)
    samples = LineSamples(line[ok].astype(np.int64), row[ok], cols[ok].astype(np.float64),
                          snr[ok], sigma[ok], flat[ok])
    searched = sum(values.shape[1] for b in bands if not b.empty)
    return Extraction(samples, noise, weak=max(searched - int(strong.sum()) - ambiguous, 0),
                      dropped=int((~ok).sum()), ambiguous=ambiguous,
                      rows_read=sum(hi - lo for lo, hi in spans),
                      line_snr=_median_per_line(samples.line, samples.snr, len(bands)))
