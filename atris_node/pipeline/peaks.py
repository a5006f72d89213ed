"""Sub-pixel line samples of a distortion map: peaks in the bands, their line, their row.

Inside the row bands of :mod:`atris_node.pipeline.bands`, the local maxima that reach the
local noise threshold (:mod:`atris_node.pipeline.noise`) are found (compiled, per pixel),
those that fall on one side only (a step of the background, no stripe: :func:`one_sided`)
are set aside, each line takes its peak in each column
(:mod:`atris_node.pipeline.identity`), and each peak is refined to a sub-pixel row by one
of five peak methods on its column profile (compiled, per sample,
:mod:`atris_node.pipeline.peaks_kernels`).

Peak methods (``PEAK_METHODS``), all on the column profile around the integer maximum,
over the local background of its noise tile (light the code does not cancel leaves a
pedestal of hundreds of DN of either sign: on it a centre of gravity is pulled to the
integer row, and a Gaussian's logarithms have no positive stripe to fit,
tests/test_pedestal.py):

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
from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError
from atris_node.pipeline import peaks_kernels as kernels
from atris_node.pipeline.bands import Band, count_in_bands, read_rows
from atris_node.pipeline.identity import VisibilityPrior, identify_lines, off_masked_pairs
from atris_node.pipeline.noise import (
    NOISE_TILE_PX,
    NoiseMap,
    median_of,
    noise_floor,
    noise_map,
)
from atris_node.pipeline.rivals import robust_identity, set_aside, stripe_peaks
from atris_node.pipeline.temporal import not_own_light
from atris_node.types import WindowFrames

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

PEAK_METHODS = ("cog", "parabolic", "gaussian", "blais_rioux", "steger")
#: greedy: the two greedy matchings, prior and continuity; aligned: also the cheapest
#: alignment per column (atris_node.pipeline.identity), about 0.3 ms more at 640x400
IDENTITY_MODES = ("greedy", "aligned")
#: uncertainty given to the centre of a flat-topped (saturated) stripe, pixels
SATURATED_SIGMA_PX = 0.5
#: px; a flat-topped stripe's saturated run is at most 2·SATURATION_WINDOW_PX + 1 rows
#: long (a longer one is a clipped patch, and its peaks give no sample)
SATURATION_WINDOW_PX = 8
#: a peak below WEAK_SNR·snr_min is weak: identity must also stand without it
WEAK_SNR = 1.5
#: px; a peak's flanks, where its own noise is measured: rows FLANK_NEAR_PX to
#: FLANK_FAR_PX above and below it (a stripe has fallen to about 1 % at 3 px, σ ≤ 1.2 px),
#: less those within FLANK_NEAR_PX of another peak (a neighbouring stripe is not noise)
FLANK_NEAR_PX, FLANK_FAR_PX = 3, 12
#: a peak's SNR against its flanks FLANK_RATIO or more times below its SNR against its
#: tile says the tile's σ (taken from its quiet part) is not this peak's noise. On the
#: noise maxima where a region an 8-bit camera leaves at 0 DN meets a noisier one, its
#: median was 4.5 (2.5 or more for 92 % of them); on the shipped scenes' peaks weak
#: against their flanks but not their tiles (4 maps each), 1.4-1.6, and 2.5 or more for
#: 0.5-13 % of them (ten rows give a noisy σ): those must then be needless for the
#: identity, which changed no shipped sector-frame
FLANK_RATIO = 2.5
#: DN; the least σ of a peak's flanks (the map's quantum is 1 DN)
FLANK_FLOOR_DN = 0.5
#: peaks at FLANK_SNR_CAP·snr_min or more against their tile are not asked their flanks:
#: a noise maximum stands at a few σ of its true noise, and the tile's σ was at most a
#: ninth of that where measured; a bright stripe's flanks hold its own tails (a clipped
#: one's, its plateau), not noise
FLANK_SNR_CAP = 8.0
#: peaks kept per column beyond one per line (reflections, foreign light)
EXTRA_PEAKS = 4
#: a stripe's flanks (:func:`one_sided`) are looked at from EDGE_NEAR_PX rows away out to
#: 3 stripe σ plus EDGE_REACH_PX (where a stripe has fallen to about 1 % of its peak)
EDGE_NEAR_PX = 2
EDGE_REACH_PX = 3
#: a maximum whose smaller drop to a flank is under EDGE_RATIO times its larger drop, or
#: under EDGE_SIGMAS noise σ, stands above one side only: a step's edge, not a stripe
EDGE_RATIO = 0.5
EDGE_SIGMAS = 3.0


@dataclass(frozen=True)
class ExtractorSettings:
    """How peaks are found: method, acceptance SNR, stripe σ (px), pair separation (px)."""

    peak_method: str = "gaussian"
    snr_min: float = 6.0
    stripe_sigma_px: float = 1.5
    min_separation_px: int = 3
    identity: str = "aligned"
    unique: bool = True  # drop samples whose line has a rival (atris_node.pipeline.rivals)
    #: px; a peak narrower than a stripe of this σ is cut (0 = no test;
    #: :func:`narrowest_stripe_px` of the calibration's stripe width)
    narrowest_sigma_px: float = 0.0

    def __post_init__(self) -> None:
        if self.peak_method not in PEAK_METHODS:
            raise ConfigError(f"peak_method {self.peak_method!r} is not one of {PEAK_METHODS}")
        if self.identity not in IDENTITY_MODES:
            raise ConfigError(f"identity {self.identity!r} is not one of {IDENTITY_MODES}")
        if not self.stripe_sigma_px > 0:
            raise ConfigError(f"stripe_sigma_px must be > 0, got {self.stripe_sigma_px}")
        if not (np.isfinite(self.narrowest_sigma_px) and self.narrowest_sigma_px >= 0.0):
            raise ConfigError(f"narrowest_sigma_px must be a number >= 0 (0: no test), got "
                              f"{self.narrowest_sigma_px}")

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
    #: (W,) ambiguous peaks per column (no order/continuity choice, or a rival identity)
    ambiguous_columns: IntArray
    #: (W,) peaks per column left out before the samples: isolated peaks (no stripe) and
    #: identified peaks that gave no sample (weak or failed fit)
    doubtful_columns: IntArray
    #: the ambiguous peaks as (row, column, line) (n,) int64 each, the line being the one
    #: among their hypotheses that puts them nearest (atris_node.pipeline.rivals.Identity)
    doubts: tuple[IntArray, IntArray, IntArray]
    narrowed: bool = False  # peaks were looked for on the ``search`` rows only
    #: of ``unassigned``, the peaks set aside as moving edges (not own light in place,
    #: atris_node.pipeline.temporal): own stripes of a moving object, not foreign light
    moving: int = 0
    #: of ``unassigned``, the maxima set aside as one side of a step (:func:`one_sided`):
    #: no stripe, so no other projector's either (flicker left by the demodulation, own
    #: stripes smeared by motion); they blank their columns' sectors like the rest
    steps: int = 0
    #: (K, W) float32, DN: the highest local noise σ over the rows of line k's band in
    #: column c (where a return within the operating range would show it); None: not
    #: measured. A band much noisier than ``tile_noise_dn`` hides a return the rest of
    #: the map would show (:func:`band_noise`)
    band_noise_dn: npt.NDArray[np.float32] | None = None
    #: DN, the median over the tiles read of their local noise σ: the map's typical noise
    #: (``noise_floor_dn`` pools every tile, and a background that changes from tile to
    #: tile, such as flicker left by the demodulation, inflates it)
    tile_noise_dn: float = 0.0
    #: (K, W) line k's band in column c holds pixels blinded in every sub-frame (saturated
    #: without laser light above the threshold): the line cannot be seen there; None: none
    blinded: BoolArray | None = None
    #: samples too faint for the range their line gives (atris_node.pipeline.radiometry):
    #: kept as doubts, not points (counted by the chain after triangulation)
    too_faint: int = 0
    #: stripes above every band (atris_node.pipeline.near): a surface nearer than z_min;
    #: kept as doubts at the topmost line's range (counted by the chain)
    near: int = 0
    #: (K, W) True where line k's sample in column c was identified by continuity over
    #: farther rivals the physics could not rule out
    #: (:attr:`atris_node.pipeline.rivals.Identity.tied`); None: no rival test
    tied: BoolArray | None = None
    #: (K, W) True where line k's sample in column c was dropped as a dim of a bright line
    #: (atris_node.pipeline.dimming; set by the chain); None: none
    dimmed: BoolArray | None = None
    #: the local background and σ the peaks were measured against (their brightness is
    #: over it); None: not kept
    noise_map: NoiseMap | None = None


# --------------------------------------------------------------------------- rows read


def read_padding(settings: ExtractorSettings) -> int:
    """Rows read beyond each band edge: the fit window and the saturation window."""
    return max(settings.radius, SATURATION_WINDOW_PX)


# --------------------------------------------------------------------------- sub-pixel


# The methods run in one compiled pass per map (atris_node.pipeline.peaks_kernels.line_samples,
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

    One compiled pass over the rows (:func:`atris_node.pipeline.peaks_kernels.strong_maxima`)
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


# --------------------------------------------------------------------------- extraction


def _samples(values: npt.NDArray[np.generic], saturated: BoolArray | None, rows: IntArray,
             local: NoiseMap, settings: ExtractorSettings, noise: float
             ) -> tuple[LineSamples, int, int]:
    """The samples of the identified peaks ``rows`` (K, W) with SNR >= snr_min that the
    peak method accepts, the number of peaks that strong and how many of them were
    dropped: one compiled pass (:func:`atris_node.pipeline.peaks_kernels.line_samples`; the methods
    are described at the top of this module). An offset beyond ±1 px is dropped. A flat
    top (a saturated pixel next to the peak) takes the centre fitted to the flanks of its
    own saturated run (:func:`atris_node.pipeline.peaks_kernels._clipped_centre`) and σ_u
    SATURATED_SIGMA_PX; other samples σ_u = CRLB / SNR. ``saturated`` as
    :func:`saturation_mask` gives it."""
    crlb = float(np.sqrt(2.0 * settings.stripe_sigma_px / np.sqrt(np.pi)))
    line, row, col, snr, sigma, flat, strong, dropped = kernels.line_samples(
        kernels.map_values(values), _NO_MASK if saturated is None else saturated,
        saturated is not None, np.asarray(rows, dtype=np.int64),
        local.tile_row, local.background_tiles, local.sigma_tiles, NOISE_TILE_PX,
        float(settings.snr_min), kernels.METHOD_CODES[settings.peak_method], settings.radius,
        3.0 * noise, settings.stripe_sigma_px, crlb, SATURATED_SIGMA_PX, SATURATION_WINDOW_PX,
        settings.narrowest_sigma_px)
    return LineSamples(line, row, col, snr, sigma, flat), int(strong), int(dropped)


#: how much narrower than the calibrated stripes a whole stripe may be (a surface that the
#: camera sees more obliquely than the sheet meets it: near and slanted)
NARROWING = 1.6


def narrowest_stripe_px(stripe_sigma_px: float) -> float:
    """σ (px) of the narrowest whole stripe, for stripes of width ``stripe_sigma_px`` (the
    calibration's, px, as the three-point Gaussian fit reads it); a narrower peak is cut
    by an edge (:func:`atris_node.pipeline.peaks_kernels._cut`). 0.0 (no test) when the
    width was not measured (0)."""
    return stripe_sigma_px / NARROWING if stripe_sigma_px > 0.0 else 0.0


#: no ambiguous peaks (identity without the rival test)
_NO_DOUBTS = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
#: the saturation mask passed to the kernel when nothing is saturated (never read)
_NO_MASK = np.zeros((1, 1), dtype=np.bool_)


def saturation_mask(saturated: BoolArray) -> BoolArray | None:
    """The (H, W) saturation mask as the kernels read it (bool, C order, writable), None
    when no pixel is saturated (the kernels then look for no flat top)."""
    return np.require(saturated, np.bool_, ["C", "W"]) if saturated.any() else None


def _median_per_line(line: IntArray, snr: FloatArray, count: int) -> tuple[float, ...]:
    """Median SNR (as ``np.median``) of the samples of each of ``count`` lines, 0.0 for a
    line without any."""
    medians = kernels.line_medians(np.ascontiguousarray(line, dtype=np.int64),
                                   np.ascontiguousarray(snr, dtype=np.float64), count)
    return tuple(float(m) for m in medians)


def true_runs(mask: BoolArray) -> list[tuple[int, int]]:
    """Intervals ``[lo, hi)`` where the 1-D ``mask`` is True."""
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
    return _Search(true_runs(scan & read), inside, tuple(true_runs(read & ~inside)))


def _above_elsewhere(values: npt.NDArray[Any], noise: NoiseMap, snr_min: float,
                     elsewhere: tuple[tuple[int, int], ...]) -> bool:
    """True when a pixel of the ``elsewhere`` rows reaches the local threshold. Every
    maximum :func:`strong_maxima` keeps reaches it, so False proves that searching the
    other rows alone finds every maximum of the rows read. One compiled pass over those
    rows (:func:`atris_node.pipeline.peaks_kernels.any_reaches`), per tile."""
    if not elsewhere:
        return False
    rows = np.array([slice(lo, hi).indices(values.shape[0])[:2] for lo, hi in elsewhere],
                    dtype=np.int64).reshape(-1, 2)
    return bool(kernels.any_reaches(kernels.map_values(values), rows,
                                    noise.threshold_tiles(snr_min), noise.tile_row,
                                    NOISE_TILE_PX))


def extract_lines(values: npt.NDArray[np.generic], saturated: BoolArray,
                  bands: tuple[Band, ...], settings: ExtractorSettings, *,
                  roi_bands: bool = True, prior: VisibilityPrior | None = None,
                  search: list[tuple[int, int]] | None = None,
                  window: WindowFrames | None = None) -> Extraction:
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
            :mod:`atris_node.pipeline.roi`); None looks in every row read. When a pixel of another
            row read reaches the peak threshold, every row read is searched after all, so
            the peaks are always those of the whole search. Noise statistics, line
            identity and the foreign-light counts use every row read.
        window: the map's raw sub-frames; with them, peaks whose time course cannot be
            own light (a moving edge, :mod:`atris_node.pipeline.temporal`) are set aside.
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
    flat = saturation_mask(saturated)
    lone = np.zeros(peaks.shape[1], dtype=np.int64)
    moved = np.zeros(peaks.shape[1], dtype=np.int64)
    edges = moved
    striped = peaks
    aligned = settings.identity == "aligned"
    doubts = _NO_DOUBTS
    tied = None
    if settings.unique:
        peaks, lone = stripe_peaks(peaks)
        striped = peaks  # light that is no line's stripe still counts as foreign below
        peaks, moved = set_aside(peaks, not_own_light(peaks, window, local))
        steps = one_sided(values, flat, peaks, local, settings)
        step_rows = np.where(steps, peaks, -1)
        peaks, edges = set_aside(peaks, steps)
        lone = lone + moved + edges  # no sample, no evidence of free space either
        identity = robust_identity(
            peaks, lambda r: _weak(values, local, r, peaks, settings.snr_min),
            bands, settings.min_separation_px, prior, aligned=aligned)
        rows, unsure, tied = identity.rows, identity.unsure, identity.tied
        rows, on_steps = off_step_runs(rows, step_rows)
        lone = lone + on_steps
        rows, merged, (m_row, m_col, m_line) = off_masked_pairs(rows, prior)
        unsure = unsure + merged
        doubts = (np.concatenate([identity.doubt_row, m_row]),
                  np.concatenate([identity.doubt_col, m_col]),
                  np.concatenate([identity.doubt_line, m_line]))
    else:
        rows, unsure = identify_lines(peaks, bands, settings.min_separation_px, prior,
                                      aligned=aligned)
    ambiguous = int(unsure.sum())
    identified = _present_per_column(rows)
    unassigned = np.maximum(count_in_bands(striped, bands) - identified - unsure, 0)
    samples, strong, dropped = _samples(values, flat, rows, local, settings, noise)
    searched = sum(values.shape[1] for b in bands if not b.empty)
    return Extraction(samples, noise, background, tuple(spans),
                      weak=max(searched - strong - ambiguous, 0),
                      dropped=dropped, ambiguous=ambiguous,
                      rows_read=sum(hi - lo for lo, hi in spans),
                      unassigned=int(unassigned.sum()), foreign_columns=unassigned > 0,
                      line_snr=_median_per_line(samples.line, samples.snr, len(bands)),
                      narrowed=where.inside is not None, ambiguous_columns=unsure,
                      doubtful_columns=lone + _unsampled(identified, samples), doubts=doubts,
                      moving=int(np.minimum(moved, unassigned).sum()),
                      steps=int((np.minimum(moved + edges, unassigned)
                                 - np.minimum(moved, unassigned)).sum()),
                      band_noise_dn=band_noise(local, bands), noise_map=local,
                      tile_noise_dn=median_of(local.sigma_tiles[:-1])
                      if local.sigma_tiles.shape[0] > 1 else noise,
                      blinded=blinded_bands(values, flat, local, bands, settings.snr_min),
                      tied=tied)


#: columns each side, px and share: an identified peak with one-sided maxima (steps) set
#: aside within STEP_ROW_PX of its row in STEP_SHARE or more of the columns within
#: STEP_REACH that hold either, is part of a step (:func:`off_step_runs`)
STEP_REACH = 6
STEP_ROW_PX = 1
STEP_SHARE = 0.25


def off_step_runs(rows: IntArray, step_rows: IntArray) -> tuple[IntArray, IntArray]:
    """``rows`` (K, W) without the peaks that lie on a run of step maxima, and (W,) how
    many were taken out per column. A step (flicker left at a surface's edge) gives
    one-sided maxima along its row, which the step test sets aside; with noise some of
    them pass it and are identified as a line's stripe (a 13 cm obstacle at 4.1 m read from
    a step at a box's foot, one line over 21 columns, between 14 set aside at its row). A
    peak with set-aside step maxima (``step_rows`` (M, W), -1 = none) within STEP_ROW_PX
    of its row in STEP_SHARE or more, and at least two, of the columns within STEP_REACH
    that hold either them or its own line at that row, belongs to that step.
    (One compiled pass, :func:`atris_node.pipeline.peaks_kernels.off_steps`.)"""
    out, removed = kernels.off_steps(np.ascontiguousarray(rows, dtype=np.int64),
                                     np.ascontiguousarray(step_rows, dtype=np.int64),
                                     STEP_REACH, STEP_ROW_PX, STEP_SHARE)
    return np.asarray(out), np.asarray(removed)


def band_noise(local: NoiseMap, bands: tuple[Band, ...]) -> npt.NDArray[np.float32]:
    """(K, W) float32, DN: per line and column the highest tile σ of ``local`` over the
    line's band rows (0 for an empty band): the noise a return anywhere in the operating
    range has to rise above. One compiled pass
    (:func:`atris_node.pipeline.peaks_kernels.band_noise`)."""
    rows = np.array([(b.row_lo, max(b.row_hi, b.row_lo)) for b in bands],
                    dtype=np.int64).reshape(-1, 2)
    return np.asarray(kernels.band_noise(local.tile_row, local.sigma_tiles, rows,
                                         NOISE_TILE_PX, local.width))


def blinded_bands(values: npt.NDArray[np.generic], saturated: BoolArray | None,
                  local: NoiseMap, bands: tuple[Band, ...], snr_min: float
                  ) -> BoolArray | None:
    """(K, W) True where line k's band holds, in column c, a saturated pixel below its
    tile's threshold: full scale in the OFF sub-frames too (sunlit, blinded), it carries
    no laser light and would hide the line; None when there is none. One compiled pass
    over the band rows (:func:`atris_node.pipeline.peaks_kernels.blinded`), left out when
    nothing is saturated. ``saturated`` as :func:`saturation_mask` gives it."""
    if saturated is None:
        return None
    out = np.zeros((len(bands), local.width), dtype=np.bool_)
    rows = np.array([(b.row_lo, b.row_hi) for b in bands], dtype=np.int64).reshape(-1, 2)
    found = kernels.blinded(kernels.map_values(values), saturated, rows,
                            local.threshold_tiles(snr_min), local.tile_row, NOISE_TILE_PX, out)
    return out if found else None


def one_sided(values: npt.NDArray[Any], saturated: BoolArray | None, peaks: IntArray,
              local: NoiseMap, settings: ExtractorSettings) -> BoolArray:
    """(M, W) True for the maxima ``peaks`` (rows, -1 padding) that stand above one side
    of their column only (a step's edge, no stripe: flicker beating with the code leaves a
    residual of the lit scene whose steps reach the threshold). One compiled pass
    (:func:`atris_node.pipeline.peaks_kernels.one_sided`). Such a maximum is no sample and
    no line's stripe: :func:`extract_lines` counts it among its column's doubtful peaks
    (the column is not free) and, unplaced, as foreign light in the bands. ``saturated``
    as :func:`saturation_mask` gives it (None: nothing saturated)."""
    far = int(np.ceil(3.0 * settings.stripe_sigma_px)) + EDGE_REACH_PX
    return np.asarray(kernels.one_sided(
        kernels.map_values(values), np.ascontiguousarray(peaks, dtype=np.int64),
        _NO_MASK if saturated is None else saturated, saturated is not None, local.tile_row,
        local.sigma_tiles, NOISE_TILE_PX, EDGE_NEAR_PX, far, EDGE_RATIO, EDGE_SIGMAS))


def _peak_snr(values: npt.NDArray[Any], local: NoiseMap, rows: IntArray) -> FloatArray:
    """(., W) SNR of the map at the given rows of each column (0 where a row is -1): the
    value over its tile's background, in its tile's σ. One compiled pass
    (:func:`atris_node.pipeline.peaks_kernels.peak_snr`); tests/test_kernels.py holds it to
    the numpy form."""
    return np.asarray(kernels.peak_snr(kernels.map_values(values),
                                       np.asarray(rows, dtype=np.int64), local.tile_row,
                                       local.background_tiles, local.sigma_tiles,
                                       NOISE_TILE_PX))


def _weak(values: npt.NDArray[Any], local: NoiseMap, rows: IntArray, peaks: IntArray,
          snr_min: float) -> BoolArray:
    """(., W) True at the ``rows`` (., W) of each column whose peak is weak: an SNR under
    WEAK_SNR·``snr_min`` against its tile (:func:`_peak_snr`) or, where that SNR is
    FLANK_RATIO or more times its SNR against its own flanks
    (:func:`atris_node.pipeline.peaks_kernels.flank_snr`; asked only below
    FLANK_SNR_CAP·``snr_min``), against its flanks. A tile's σ
    comes from its quiet part: where a dark region an 8-bit camera leaves at 0 DN meets a
    noisier one, noise maxima on the edge stood at tile SNR 10-16 and completed a ground
    comb read one line down, which then anchored it in every column
    (ground_comb_read_one_line_down_noise_anchored_drawn: 1.7-1.9 m where nothing
    stands). True also where a row is -1 (the caller masks them)."""
    tile = _peak_snr(values, local, rows)
    flank = np.asarray(kernels.flank_snr(kernels.map_values(values),
                                         np.asarray(rows, dtype=np.int64),
                                         np.asarray(peaks, dtype=np.int64), tile,
                                         WEAK_SNR * snr_min, FLANK_SNR_CAP * snr_min,
                                         FLANK_NEAR_PX, FLANK_FAR_PX, FLANK_FLOOR_DN))
    own = (flank < tile) & (tile >= FLANK_RATIO * flank)
    return np.where(own, flank, tile) < WEAK_SNR * snr_min


def _unsampled(identified: IntArray, samples: LineSamples) -> IntArray:
    """(W,) identified peaks per column (``identified`` (W,)) that gave no sample."""
    got = per_column(samples.col_px, identified.size)
    return np.maximum(identified - got, 0).astype(np.int64)


def _present_per_column(rows: IntArray) -> IntArray:
    """(W,) int64 how many of the (K, W) ``rows`` hold a peak (>= 0) in each column, as
    ``(rows >= 0).sum(axis=0)``: added as bytes while K fits one (faster)."""
    present = rows >= 0
    if rows.shape[0] > np.iinfo(np.uint8).max:
        return present.sum(axis=0).astype(np.int64)
    return np.add.reduce(present.view(np.uint8), axis=0, dtype=np.uint8).astype(np.int64)


def per_column(col_px: FloatArray, width: int) -> IntArray:
    """(W,) how many of the given column positions (px) fall in each image column."""
    return np.bincount(col_px.astype(np.int64), minlength=width)[:width].astype(np.int64)


def seen_lines(samples: LineSamples, lines: int, width: int) -> BoolArray:
    """(K, W) True where line k has a sample in column c."""
    seen = np.zeros((lines, width), dtype=np.bool_)
    seen[samples.line, samples.col_px.astype(np.int64)] = True
    return seen


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
