"""Sub-pixel line extraction, line identification and ROI bands on the distortion map.

A projected line k can only be imaged between its rows at ``z_min`` and ``z_max``
(``u = f·cot α_k - f·b/z``, see :mod:`atris_node.geometry`), widened by the lens distortion
and a margin: its *band*. The local maxima of the bands' rows are found (compiled, per
pixel), each line takes its peak in each column (line identity), and each peak is refined
to a sub-pixel row by one of five peak methods on its column profile (compiled, per
sample). Rows outside every band are never read.

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
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node import identity_kernels, line_identity
from atris_node import line_kernels as kernels
from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.errors import ConfigError
from atris_node.geometry import distort_pixels, line_row_at_range

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

PEAK_METHODS = ("cog", "parabolic", "gaussian", "blais_rioux", "steger")
#: greedy: the two greedy matchings, prior and continuity; aligned: also the cheapest
#: alignment per column (atris_node.line_identity), about 0.3 ms more at 640x400
IDENTITY_MODES = ("greedy", "aligned")
#: distance from the median to the lower quartile of a normal distribution, in σ
QUARTILE_TO_SIGMA = 0.6745
#: the smallest noise floor used, DN (quantisation of an integer map is 0.29 DN)
MIN_NOISE_DN = 0.5
#: side of the square tiles of the local noise estimate, pixels
NOISE_TILE_PX = 32
#: uncertainty given to the centre of a flat-topped (saturated) stripe, pixels
SATURATED_SIGMA_PX = 0.5
#: half window (px) searched for the saturated run of a flat-topped stripe
SATURATION_WINDOW_PX = 8
#: peaks kept per column beyond one per line (reflections, foreign light)
EXTRA_PEAKS = 4
#: agreed samples a block of columns / a whole line needs to serve as continuity reference
MIN_BLOCK_SAMPLES = 4
MIN_LINE_SAMPLES = 16
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
    identity: str = "aligned"

    def __post_init__(self) -> None:
        if self.peak_method not in PEAK_METHODS:
            raise ConfigError(f"peak_method {self.peak_method!r} is not one of {PEAK_METHODS}")
        if self.identity not in IDENTITY_MODES:
            raise ConfigError(f"identity {self.identity!r} is not one of {IDENTITY_MODES}")
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
    background_dn: float  # median of the map rows read
    spans: tuple[tuple[int, int], ...]  # row intervals [lo, hi) read
    weak: int  # column slots without a peak above snr_min
    dropped: int  # peaks above snr_min rejected (window off the image, failed fit)
    ambiguous: int  # peaks whose line could not be told from order and continuity
    rows_read: int  # map rows read (union of bands plus fit padding)
    unassigned: int  # strong peaks inside the bands that belong to no line (foreign light)
    foreign_columns: BoolArray  # (W,) columns holding such peaks
    line_snr: tuple[float, ...]  # median SNR of the accepted samples per line, 0 if none
    narrowed: bool = False  # peaks were looked for on the ``search`` rows only


# --------------------------------------------------------------------------- bands


def _band(line: int, u_px: tuple[float, float], camera: CameraModel,
          margin_px: float) -> Band:
    """Observed rows of the undistorted row interval ``u_px`` (px from cy) of one line,
    through the distortion at 17 columns; empty when the interval misses the image by
    more than half its height (lines of α near 0 or π)."""
    h, cy = camera.height_px, camera.cy_px
    lo_u, hi_u = min(u_px) + cy, max(u_px) + cy
    if hi_u < -h / 2 or lo_u > 1.5 * h:
        return Band(line, 0, 0)
    cols = np.linspace(0.0, camera.width_px - 1.0, 17)
    rows = np.concatenate([distort_pixels(np.full_like(cols, r), cols, camera)[0]
                           for r in np.clip([lo_u, hi_u], -h / 2, 1.5 * h)])
    lo = max(int(np.floor(rows.min() - margin_px)), 0)
    hi = min(int(np.ceil(rows.max() + margin_px)) + 1, h)
    return Band(line, lo, max(hi, lo))


def line_bands(camera: CameraModel, laser: LaserCalibration, z_min_m: float,
               z_max_m: float, margin_px: float) -> tuple[Band, ...]:
    """Observed row band of every line for ranges ``[z_min_m, z_max_m]``.

    The band edges are the rows ``u = f·cot α_k - f·b/z`` at z_min and z_max, pushed
    through the lens distortion, widened by ``margin_px`` and clipped to the image.
    """
    return tuple(_band(k, (line_row_at_range(k, z_min_m, camera, laser),
                           line_row_at_range(k, z_max_m, camera, laser)), camera, margin_px)
                 for k in range(len(laser.alpha_rad)))


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
    q25, median = _quartile_and_median(np.concatenate(parts))
    return float(median), max(float(median - q25) / QUARTILE_TO_SIGMA, MIN_NOISE_DN)


def _quartile_and_median(a: npt.NDArray[Any]) -> tuple[Any, Any]:
    """(25th percentile, median) along the last axis of ``a`` (any real dtype), float32,
    as ``np.percentile`` computes them on ``a.astype(np.float32)`` (linear interpolation).

    One sort in the input's own dtype: numpy's vectorised sort is several times faster
    than a partition at four indices, and converting only the picked values to float32
    gives the same numbers (the conversion keeps the order).
    """
    n = a.shape[-1]
    lo25, f25 = divmod((n - 1) * 0.25, 1.0)
    lo50, f50 = divmod((n - 1) * 0.5, 1.0)
    ordered = np.sort(a, axis=-1)

    def at(i: int, frac: float) -> Any:
        low = ordered[..., i].astype(np.float32)
        if not frac:
            return low
        return low + frac * (ordered[..., min(i + 1, n - 1)].astype(np.float32) - low)

    return at(int(lo25), f25), at(int(lo50), f50)


@dataclass(frozen=True)
class NoiseMap:
    """Local background and noise σ (DN) per NOISE_TILE_PX square tile of the rows read.

    Shot noise grows with the ambient light, so a sunlit patch is noisier than the rest:
    one global threshold would take its noise for peaks. Each NOISE_TILE_PX square tile
    of the rows read gets its own median and ``(median - q25) / 0.6745`` (2×2 subsample).

    ``background_tiles`` and ``sigma_tiles`` (R + 1, C) float32 hold the tiles of every
    span stacked, and in their last row the values outside the rows read (0 and
    MIN_NOISE_DN); ``tile_row`` (H,) int64 gives each image row its row of tiles (-1, the
    last, outside the rows read). Column c lies in tile column ``c // NOISE_TILE_PX``.
    Per-pixel (H, W) float32 images are made only where asked for.
    """

    tile_row: IntArray
    background_tiles: npt.NDArray[np.float32]
    sigma_tiles: npt.NDArray[np.float32]
    width: int

    @property
    def background(self) -> npt.NDArray[np.float32]:
        """(H, W) float32 local background, DN."""
        return self._image(self.background_tiles)

    @property
    def sigma(self) -> npt.NDArray[np.float32]:
        """(H, W) float32 local noise σ, DN."""
        return self._image(self.sigma_tiles)

    def threshold(self, snr_min: float) -> npt.NDArray[np.float32]:
        """(H, W) float32 ``background + snr_min · σ``, DN, computed per tile."""
        return self._image(self.threshold_tiles(snr_min))

    def threshold_tiles(self, snr_min: float) -> npt.NDArray[np.float32]:
        """(R + 1, C) float32 ``background + snr_min · σ`` per tile, DN."""
        return self.background_tiles + np.float32(snr_min) * self.sigma_tiles

    def _image(self, tiles: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """(H, W) float32 image of per-tile values (one broadcast copy)."""
        t = NOISE_TILE_PX
        rows = tiles[self.tile_row]  # (H, C)
        full = np.broadcast_to(rows[:, :, None], (*rows.shape, t)).reshape(rows.shape[0], -1)
        return np.ascontiguousarray(full[:, :self.width])



def _tile_statistics(block: npt.NDArray[Any]) -> tuple[npt.NDArray[np.float32],
                                                        npt.NDArray[np.float32]]:
    """Per NOISE_TILE_PX tile of ``block`` (h, w): (median, σ), each (nr, nc) float32,
    tiles from the top left corner."""
    t = NOISE_TILE_PX // 2
    sub = block[::2, ::2]
    nr, nc = -(-sub.shape[0] // t), -(-sub.shape[1] // t)
    padded = np.pad(sub, ((0, nr * t - sub.shape[0]), (0, nc * t - sub.shape[1])), "symmetric")
    tiles = padded.reshape(nr, t, nc, t).transpose(0, 2, 1, 3).reshape(nr, nc, t * t)
    q25, median = _quartile_and_median(tiles)
    return median, np.maximum((median - q25) / QUARTILE_TO_SIGMA, np.float32(MIN_NOISE_DN))


def noise_map(values: npt.NDArray[np.generic], spans: list[tuple[int, int]]) -> NoiseMap:
    """The :class:`NoiseMap` of the rows in ``spans``."""
    height, width = values.shape
    tile_row = np.full(height, -1, dtype=np.int64)
    nc = -(-width // NOISE_TILE_PX)
    background = [np.zeros((0, nc), dtype=np.float32)]
    sigma = [np.zeros((0, nc), dtype=np.float32)]
    for lo, hi in spans:
        if hi > lo:
            tile_row[lo:hi] = sum(b.shape[0] for b in background) + (
                np.arange(hi - lo) // NOISE_TILE_PX)
            median, noise = _tile_statistics(values[lo:hi])
            background.append(median)
            sigma.append(noise)
    background.append(np.zeros((1, nc), dtype=np.float32))
    sigma.append(np.full((1, nc), MIN_NOISE_DN, dtype=np.float32))
    return NoiseMap(tile_row, np.concatenate(background), np.concatenate(sigma), width)


# --------------------------------------------------------------------------- sub-pixel


# The methods run in one compiled pass per map (atris_node.line_kernels.line_samples,
# called by _samples below); the module docstring describes them.


# --------------------------------------------------------------------------- search


def strong_maxima(values: npt.NDArray[Any], spans: list[tuple[int, int]], noise: NoiseMap,
                  snr_min: float, sep: int, per_column: int,
                  inside: BoolArray | None = None) -> IntArray:
    """(per_column, W) rows of the local maxima in ``spans`` that reach the local threshold
    ``background + snr_min · σ`` of ``noise`` (DN), sorted top to bottom in each column,
    -1 padded. A maximum is strictly above the ``sep`` rows over it and not below the
    ``sep`` rows under it (a plateau counts once). With ``inside`` ((H,) bool) only maxima
    on those rows are kept; the rows around them are still compared, so each kept maximum
    is one the whole span would have found. ``values`` int16, int32, float32 or float64.

    One compiled pass over the rows (:func:`atris_node.line_kernels.strong_maxima`)
    compares each pixel with its tile's threshold: no (H, W) threshold image is made.
    """
    height, width = values.shape
    out = np.full((per_column, width), -1, dtype=np.int64)
    bounds = np.array(spans, dtype=np.int64).reshape(-1, 2)
    rows = np.zeros(height, dtype=np.bool_) if inside is None else inside
    kernels.strong_maxima(kernels.map_values(values), bounds,
                          noise.threshold_tiles(snr_min), noise.tile_row, NOISE_TILE_PX, sep,
                          rows, inside is not None, out, np.zeros(width, dtype=np.int64))
    return out


def _in_image_order(bands: tuple[Band, ...]) -> tuple[IntArray, IntArray, IntArray]:
    """(K,) ``row_lo``, ``row_hi`` and line of the bands, top of the image first."""
    ordered = sorted(bands, key=lambda b: b.row_lo + b.row_hi)
    return (np.array([b.row_lo for b in ordered], dtype=np.int64),
            np.array([b.row_hi for b in ordered], dtype=np.int64),
            np.array([b.line for b in ordered], dtype=np.int64))


def _continuity_reference(rows: IntArray, good: BoolArray) -> FloatArray:
    """(The kernel :func:`identify_lines` uses, with this module's constants.) (K, W) per
    line: the median of the good rows in each block of CONTINUITY_BLOCK
    columns (at least MIN_BLOCK_SAMPLES of them; the upper median of an even count);
    elsewhere the median of all the line's good rows when there are at least
    MIN_LINE_SAMPLES; inf where no reference can be trusted. ``rows`` (K, W) int,
    ``good`` (K, W) bool."""
    return np.asarray(identity_kernels.continuity_reference(
        np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(good, dtype=np.bool_),
        CONTINUITY_BLOCK, MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES))


@dataclass(frozen=True)
class VisibilityPrior:
    """Where each line would be seen if a surface were there, from the calibration and
    the mounting: it tells a missing line that is explained (below the ground, off the
    image, out of range) from one that is not.

    ``cot_alpha`` (K,) cot α_k; ``ground_range_m`` (K, W) float64 camera range z (m) at
    which line k's plane meets the ground (plus clearance) in column c, ``np.inf`` when it
    never does; other fields in pixels and metres.
    """

    cot_alpha: FloatArray
    focal_px: float
    cy_px: float
    height_px: int
    baseline_m: float
    z_max_m: float
    ground_range_m: FloatArray

    def unexplained(self, rows: IntArray, columns: IntArray | None = None) -> IntArray:
        """(n,) number of unassigned lines that should be visible at the range of their
        nearest assigned neighbour (above ground, inside the image, within z_max).
        ``rows`` (K, n) by line are those of the image ``columns`` (default: all W)."""
        ground = self.ground_range_m if columns is None else self.ground_range_m[:, columns]
        return np.asarray(identity_kernels.unexplained(
            np.ascontiguousarray(rows, dtype=np.int64), self.cot_alpha, self.geometry,
            np.ascontiguousarray(ground, dtype=np.float64), self.image_order))

    @cached_property
    def geometry(self) -> FloatArray:
        """(5,) focal px, cy px, height px, baseline m, z_max m (as the kernels take them)."""
        return np.array([self.focal_px, self.cy_px, self.height_px, self.baseline_m,
                         self.z_max_m], dtype=np.float64)

    @cached_property
    def image_order(self) -> IntArray:
        """(K,) the lines from the top of the image down (ascending cot α)."""
        return np.argsort(self.cot_alpha)


def identify_lines(peaks: IntArray, bands: tuple[Band, ...], sep: int,
                   prior: VisibilityPrior | None = None, *,
                   aligned: bool = False) -> tuple[IntArray, IntArray]:
    """(K, W) row of each line per column (-1 = none) and (W,) ambiguous samples per column.

    Order: lines keep their top-to-bottom order and each stays in its band. Both greedy
    matchings (top down and bottom up) have the most pairs; where they agree the identity
    is certain. Where they differ, the ``prior`` (if given) prefers the matching that
    leaves fewer lines missing without a reason; then continuity decides: the matching
    whose differing rows lie closer (by at least ``sep`` px) to each line's rows in the
    neighbouring columns wins; otherwise the differing samples are dropped and counted
    ambiguous. With ``aligned``, a confident choice is then replaced where the cheapest
    alignment of :mod:`atris_node.line_identity` is clearly cheaper (a line missing in the
    middle of a column, which both greedy matchings answer with a shifted run of lines).
    """
    lo, hi, line = _in_image_order(bands)
    rows, unsure, unsettled, certain = identity_kernels.greedy_identity(
        np.ascontiguousarray(peaks, dtype=np.int64), lo, hi, line, int(sep), aligned,
        *line_identity.prior_arrays(prior, (len(bands), peaks.shape[1])), CONTINUITY_BLOCK,
        MIN_BLOCK_SAMPLES, MIN_LINE_SAMPLES)
    if not aligned or not unsettled.any():
        return rows, unsure
    return line_identity.improve(peaks, (lo, hi), line, (rows, unsure), unsettled, certain,
                                 prior, sep)


# --------------------------------------------------------------------------- extraction


def _samples(values: npt.NDArray[np.generic], saturated: BoolArray, rows: IntArray,
             local: NoiseMap, settings: ExtractorSettings, noise: float
             ) -> tuple[LineSamples, int, int]:
    """The samples of the identified peaks ``rows`` (K, W) with SNR >= snr_min that the
    peak method accepts, the number of peaks that strong and how many of them were
    dropped: one compiled pass (:func:`atris_node.line_kernels.line_samples`; the methods
    are described at the top of this module). An offset beyond ±1 px is dropped. A flat
    top (a saturated pixel next to the peak) takes the centre of the saturated run and
    σ_u SATURATED_SIGMA_PX; other samples σ_u = CRLB / SNR."""
    any_saturated = bool(saturated.any())
    mask = np.require(saturated, np.bool_, ["W"]) if any_saturated else _NO_MASK
    crlb = float(np.sqrt(2.0 * settings.stripe_sigma_px / np.sqrt(np.pi)))
    line, row, col, snr, sigma, flat, strong, dropped = kernels.line_samples(
        kernels.map_values(values), mask, any_saturated, np.asarray(rows, dtype=np.int64),
        local.tile_row, local.background_tiles, local.sigma_tiles, NOISE_TILE_PX,
        float(settings.snr_min), kernels.METHOD_CODES[settings.peak_method], settings.radius,
        3.0 * noise, settings.stripe_sigma_px, crlb, SATURATED_SIGMA_PX, SATURATION_WINDOW_PX)
    return LineSamples(line, row, col, snr, sigma, flat), int(strong), int(dropped)


#: the saturation mask passed to the kernel when nothing is saturated (never read)
_NO_MASK = np.zeros((1, 1), dtype=np.bool_)


def _count_in_bands(peaks: IntArray, bands: tuple[Band, ...]) -> IntArray:
    """(W,) entries of (M, W) ``peaks`` (rows, -1 = none) inside at least one band, looked
    up in a table of the rows some band covers (its last entry, for -1 and for rows
    below every band, False)."""
    top = max((b.row_hi for b in bands), default=0)
    covered = np.zeros(top + 1, dtype=np.bool_)
    for b in bands:
        covered[b.row_lo:max(b.row_hi, b.row_lo)] = True
    return np.asarray(covered[np.minimum(peaks, top)].sum(axis=0), dtype=np.int64)


def _median_per_line(line: IntArray, snr: FloatArray, count: int) -> tuple[float, ...]:
    """Median SNR (as ``np.median``) of the samples of each of ``count`` lines, 0.0 for a
    line without any."""
    medians = kernels.line_medians(np.ascontiguousarray(line, dtype=np.int64),
                                   np.ascontiguousarray(snr, dtype=np.float64), count)
    return tuple(float(m) for m in medians)


def _runs(mask: BoolArray) -> list[tuple[int, int]]:
    """Intervals ``[lo, hi)`` where the (H,) ``mask`` is True."""
    edges = np.flatnonzero(np.diff(np.concatenate(([False], mask, [False]))))
    return [(int(lo), int(hi)) for lo, hi in zip(edges[::2], edges[1::2], strict=True)]


@dataclass(frozen=True)
class _Search:
    """Where :func:`strong_maxima` looks: ``scan`` spans, the (H,) ``inside`` rows whose
    maxima count (None: every row of ``scan``), the ``elsewhere`` spans read but skipped."""

    scan: list[tuple[int, int]]
    inside: BoolArray | None = None
    elsewhere: tuple[tuple[int, int], ...] = ()


def _search_rows(spans: list[tuple[int, int]], search: list[tuple[int, int]] | None,
                 sep: int, height: int) -> _Search:
    """``search`` within ``spans``, scanned ``sep`` rows wider so edge rows compare as in
    the whole span; the rows of ``spans`` left out are ``elsewhere``."""
    if search is None:
        return _Search(spans)
    read = np.zeros(height, dtype=np.bool_)
    for lo, hi in spans:
        read[lo:hi] = True
    inside = np.zeros(height, dtype=np.bool_)
    scan = np.zeros(height, dtype=np.bool_)
    for lo, hi in search:
        inside[max(lo, 0):max(hi, 0)] = True
        scan[max(lo - sep, 0):max(hi + sep, 0)] = True
    inside &= read
    return _Search(_runs(scan & read), inside, tuple(_runs(read & ~inside)))


def _above_elsewhere(values: npt.NDArray[Any], noise: NoiseMap, snr_min: float,
                     elsewhere: tuple[tuple[int, int], ...]) -> bool:
    """True when a pixel of the ``elsewhere`` rows reaches the local threshold. Every
    maximum :func:`strong_maxima` keeps reaches it, so False proves that searching the
    other rows alone finds every maximum of the rows read."""
    if not elsewhere:
        return False
    threshold = noise.threshold(snr_min)
    return any(bool((values[lo:hi] >= threshold[lo:hi]).any()) for lo, hi in elsewhere)


def extract_lines(values: npt.NDArray[np.generic], saturated: BoolArray,
                  bands: tuple[Band, ...], settings: ExtractorSettings, *,
                  roi_bands: bool = True, prior: VisibilityPrior | None = None,
                  search: list[tuple[int, int]] | None = None) -> Extraction:
    """Line samples of a distortion map.

    Args:
        values: (H, W) int16/int32 (or float) demodulated map, DN.
        saturated: (H, W) bool saturation mask of the same map.
        bands: one :class:`Band` per line, from :func:`line_bands`.
        settings: peak method, SNR threshold, stripe σ.
        roi_bands: True reads only the bands (plus :func:`read_padding` rows); False
            searches every whole column for the K strongest peaks and identifies them by
            band and order.
        prior: optional geometry that helps tell lines apart (see :func:`identify_lines`).
        search: row intervals ``[lo, hi)`` where peaks are looked for (ROI narrowing,
            :mod:`atris_node.roi`); None looks in every row read. When a pixel of another
            row read reaches the peak threshold, every row read is searched after all, so
            the peaks are always those of the whole search. Noise statistics, line
            identity and the foreign-light counts use every row read.
    """
    height = values.shape[0]
    spans = read_rows(bands, read_padding(settings), height) if roi_bands else [(0, height)]
    background, noise = noise_floor(values, spans)
    local = noise_map(values, spans)
    where = _search_rows(spans, search, settings.min_separation_px, height)
    if _above_elsewhere(values, local, settings.snr_min, where.elsewhere):
        where = _Search(spans)  # something outside the recent rows: search them all
    peaks = strong_maxima(values, where.scan, local, settings.snr_min, settings.min_separation_px,
                          len(bands) + EXTRA_PEAKS, where.inside)
    rows, unsure = identify_lines(peaks, bands, settings.min_separation_px, prior,
                                  aligned=settings.identity == "aligned")
    ambiguous = int(unsure.sum())
    unassigned = np.maximum(_count_in_bands(peaks, bands) - (rows >= 0).sum(axis=0) - unsure, 0)
    samples, strong, dropped = _samples(values, saturated, rows, local, settings, noise)
    searched = sum(values.shape[1] for b in bands if not b.empty)
    return Extraction(samples, noise, background, tuple(spans),
                      weak=max(searched - strong - ambiguous, 0),
                      dropped=dropped, ambiguous=ambiguous,
                      rows_read=sum(hi - lo for lo, hi in spans),
                      unassigned=int(unassigned.sum()), foreign_columns=unassigned > 0,
                      line_snr=_median_per_line(samples.line, samples.snr, len(bands)),
                      narrowed=where.inside is not None)


def smooth_along_lines(samples: LineSamples, lines: int, width: int,
                       taps: int = 5, max_step_px: float = 2.0) -> LineSamples:
    """Median of ``taps`` neighbouring columns of the same line for each sample whose
    neighbours all exist and lie within ``max_step_px`` of each other (one surface);
    other samples (edges, gaps) keep their row. Returns new samples, σ_u unchanged."""
    if taps < 3 or len(samples) == 0:
        return samples
    row = kernels.smooth(*_on_grid(samples), lines, width, taps | 1, max_step_px)
    return LineSamples(samples.line, row, samples.col_px, samples.snr, samples.sigma_u_px,
                       samples.saturated)


def supported_along_lines(samples: LineSamples, lines: int, width: int, reach: int = 2,
                          max_step_px: float = 2.0) -> BoolArray:
    """(n,) True for samples with a sample of the same line within ``reach`` columns and
    ``max_step_px`` rows: a lone sample is more likely a wrong identity than a surface."""
    if len(samples) == 0:
        return np.zeros(0, dtype=np.bool_)
    return np.asarray(kernels.supported(*_on_grid(samples), lines, width, reach, max_step_px))


def _on_grid(samples: LineSamples) -> tuple[IntArray, IntArray, FloatArray]:
    """(line, column, row) of the samples as the kernels take them: int64, int64 (whole
    columns), float64 px."""
    return (np.ascontiguousarray(samples.line, dtype=np.int64),
            np.ascontiguousarray(samples.col_px, dtype=np.int64),
            np.ascontiguousarray(samples.row_px, dtype=np.float64))


def select(samples: LineSamples, keep: BoolArray) -> LineSamples:
    """The samples where ``keep`` is True."""
    return LineSamples(samples.line[keep], samples.row_px[keep], samples.col_px[keep],
                       samples.snr[keep], samples.sigma_u_px[keep], samples.saturated[keep])
