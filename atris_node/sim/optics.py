"""Radiometry: from light sources to electrons per second in each pixel.

Laws used (all surfaces Lambertian, radiance ``L = albedo · E / π``):

- Camera: image irradiance ``π L / (4 N²)`` (f-number N, cos⁴ fall-off neglected), so a
  pixel of pitch p collects ``L · π p² QE λ / (4 N² h c)`` electrons per second.
- Laser sheet (own projector and interferers): a diffractive element fans the beam from a
  near-point source over ``fan`` radians along the line and a Gaussian of σ across it, so
  its radiant intensity is ``I = P_k / (fan · σ · √(2π)) · exp(-Δθ² / 2σ²)`` W/sr and the
  irradiance falls with the inverse square of the distance, ``E = I · cos i / r²``. A DOE
  line diverges in both directions, so neither the 1/r of a fixed-thickness sheet nor a
  collimated beam applies beyond a few centimetres from the aperture.
- Pixel footprint: the sheet profile is averaged over the angle ``w`` a pixel spans as seen
  from the source and blurred by the lens PSF: ``σ_eff² = σ² + w²/12 + (σ_psf · w)²``,
  peak scaled by ``σ / σ_eff`` (energy kept). This keeps a sheet thinner than a pixel
  visible and its centre sub-pixel exact.
- Ambient: lux → W/m² with a daylight luminous efficacy of ``LUMINOUS_EFFICACY_LM_PER_W``
  over the sensor's band, times the narrow-band ``filter_factor``, photons at
  ``AMBIENT_WAVELENGTH_NM``. Sun ``E_sun · max(0, n·s)`` where the sun is not shadowed
  (and passes the window, if any); sky and lamp ``E · (1 + n_z) / 2`` (the visible part
  of a uniform upper hemisphere); a pixel that sees no surface sees the sky, ``E_sky / π``.
  Several lamps are diffuse alike, so they add into one lamp irradiance.
- Finishes (point sources only: the own projector and interferers; ambient light sees the
  diffuse part alone). A shape of albedo ρ and ``specular`` s reflects ``ρ (1 − s)``
  diffusely and ``ρ s`` into a Gaussian mirror lobe of σ ``gloss``: radiance
  ``E ρ s exp(−γ²/2σ²) / (2π σ²)``, γ the angle between the view direction and the
  mirror image of the incoming ray (the lobe holds ρ s E for small σ; a dark-diffuse
  glossy patch returns little unless seen near its mirror angle). A retro-reflector adds
  ``E g exp(−β²/2σ_r²) / π``, β the angle at the surface between the source and the eye,
  g = ``retro_gain`` (its radiance relative to a white Lambertian surface at β = 0;
  retro-reflective sheeting is of order 100–1000 near 0.2°). With the projector b below
  the camera, β ≈ b / r, so a sign returns far more at long range than near.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from atris_node.mounting import Mounting
from atris_node.sim import optics_kernels
from atris_node.sim.raycast import Shape, occluded
from atris_node.sim.scene import Ambient, CameraSpec, LinePattern, Sun

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

PLANCK_J_S = 6.62607015e-34
LIGHT_M_PER_S = 299792458.0
#: lumens per watt of daylight over the band a silicon sensor sees (about 400-1000 nm)
LUMINOUS_EFFICACY_LM_PER_W = 105.0
#: mean photon wavelength assumed for ambient light, nm
AMBIENT_WAVELENGTH_NM = 600.0
#: largest pixel footprint used for a sheet, rad (at depth edges the gradient is meaningless)
MAX_FOOTPRINT_RAD = 0.02
#: sheets below this fraction of their peak profile are not shadow-tested (treated as dark)
PROFILE_CUTOFF = 1e-4


def electrons_per_radiance(camera: CameraSpec, wavelength_nm: float) -> float:
    """Electrons per second in one pixel per unit scene radiance (W m⁻² sr⁻¹)."""
    pitch_m = camera.pixel_pitch_um * 1e-6
    photon_j = PLANCK_J_S * LIGHT_M_PER_S / (wavelength_nm * 1e-9)
    return math.pi * pitch_m**2 * camera.quantum_efficiency / (
        4.0 * camera.f_number**2 * photon_j)


def sheet_peak_intensity(pattern: LinePattern) -> float:
    """Radiant intensity (W/sr) at the centre of one line's sheet: its share of the
    power over the fan and the Gaussian across it, ``P_k / (fan · σ · √(2π))``."""
    return pattern.power_w / len(pattern.alpha_rad) / (
        pattern.fan_rad * pattern.line_sigma_rad * math.sqrt(2.0 * math.pi))


def line_return_dn_m2(camera: CameraSpec, pattern: LinePattern) -> float:
    """The radiometric calibration of a line (:class:`atris_node.calibration.LaserCalibration`
    ``return_dn_m2``): the peak DN per on sub-frame of a line centred on a pixel row of a
    white Lambertian surface facing the unit 1 m away, times m², at the camera's exposure.
    By the laws above: the sheet's peak irradiance at 1 m, scaled by its pixel footprint
    (a pixel spans 1/f rad of a facing surface seen from the source), its radiance
    ``E / π``, the electrons a pixel collects in one exposure and the sensor gain; no full
    scale (a calibration target is not saturated)."""
    sigma = pattern.line_sigma_rad
    footprint = 1.0 / camera.focal_px
    var = sigma**2 + footprint**2 * (1.0 / 12.0 + camera.psf_sigma_px**2)
    peak_w_m2 = sheet_peak_intensity(pattern) * sigma / math.sqrt(var)
    electrons = (peak_w_m2 / math.pi * electrons_per_radiance(camera, pattern.wavelength_nm)
                 * camera.exposure_us * 1e-6)
    return electrons * camera.gain_dn_per_e


def stripe_sigma_px(camera: CameraSpec, pattern: LinePattern) -> float:
    """The stripes' width (:class:`atris_node.calibration.LaserCalibration`
    ``stripe_sigma_px``): the sheet's σ across the rows of a facing surface, the pixel's
    box (variance 1/12 px²) and the lens's PSF, added in variance (px)."""
    return math.sqrt((pattern.line_sigma_rad * camera.focal_px) ** 2 + 1.0 / 12.0
                     + camera.psf_sigma_px**2)


def lux_to_w_m2(lux: float, filter_factor: float) -> float:
    """In-band irradiance (W/m²) of ``lux`` passed by a filter of ``filter_factor``."""
    return lux / LUMINOUS_EFFICACY_LM_PER_W * filter_factor


def hemisphere_factor(normals: FloatArray) -> FloatArray:
    """``(1 + n_z) / 2``: how much of a uniform upper hemisphere a surface sees."""
    return 0.5 * (1.0 + normals[..., 2])


def _through_window(sun: Sun, points: FloatArray) -> tuple[BoolArray, FloatArray]:
    """Which points the sun reaches through the window, and the distance to it (m)."""
    if sun.window is None:
        return np.ones(points.shape[0], bool), np.full(points.shape[0], np.inf)
    w = sun.window
    a, b, c = (np.asarray(v) for v in (w.half_a_m, w.half_b_m, w.center_m))
    normal = np.cross(a, b)
    s = sun.direction
    denom = float(s @ normal)
    if abs(denom) < 1e-12:
        return np.zeros(points.shape[0], bool), np.full(points.shape[0], np.inf)
    t = ((c - points) @ normal) / denom
    rel = points + np.outer(t, s) - c
    inside = (np.abs(rel @ a) <= a @ a) & (np.abs(rel @ b) <= b @ b) & (t > 0)
    return inside, t


def sun_irradiance(sun: Sun, shapes: Sequence[Shape], points: FloatArray,
                   normals: FloatArray, filter_factor: float,
                   time_s: float = 0.0) -> FloatArray:
    """Direct-sun irradiance (n,) W/m² at surface points (n, 3) with normals (n, 3)."""
    s = sun.direction
    cos_i = np.clip(normals @ s, 0.0, None)
    lit, distance = _through_window(sun, points)
    candidates = np.flatnonzero(lit & (cos_i > 0))
    if candidates.size:
        shadow = occluded(shapes, points[candidates], s, distance[candidates], time_s)
        lit[candidates[shadow]] = False
    return np.where(lit, cos_i, 0.0) * lux_to_w_m2(sun.lux, filter_factor)


def diffuse_irradiance(ambient: Ambient, normals: FloatArray,
                       filter_factor: float) -> tuple[FloatArray, FloatArray]:
    """Sky and lamp irradiance (n,) W/m² each (the lamp part is the one that flickers)."""
    hemi = hemisphere_factor(normals)
    return (hemi * lux_to_w_m2(ambient.sky_lux, filter_factor),
            hemi * lux_to_w_m2(ambient.lamp_lux, filter_factor))


def footprint_rad(theta: FloatArray) -> FloatArray:
    """Angle (H, W) a pixel spans in the sheet coordinate ``theta`` (H, W), radians.

    The smaller one-sided difference per axis is used, so a depth edge does not widen
    the pixels on either side of it. Pixels without a surface hold NaN in ``theta``.
    """
    def one_axis(axis: int) -> FloatArray:
        d = np.abs(np.diff(theta, axis=axis))
        d = np.where(np.isfinite(d), d, np.inf)
        pad = [(0, 0), (0, 0)]
        pad[axis] = (1, 0)
        before = np.pad(d, pad, constant_values=np.inf)
        pad[axis] = (0, 1)
        after = np.pad(d, pad, constant_values=np.inf)
        return np.minimum(before, after)
    w = np.hypot(np.minimum(one_axis(0), MAX_FOOTPRINT_RAD),
                 np.minimum(one_axis(1), MAX_FOOTPRINT_RAD))
    return np.minimum(w, MAX_FOOTPRINT_RAD)


def sheet_angles(pose: Mounting, pattern: LinePattern,
                 points: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Source-frame angles of world points (..., 3): θ (plane family angle), φ (along the
    fan), distance r (m) and unit world directions (..., 3) from the source (compiled:
    :mod:`atris_node.sim.optics_kernels`)."""
    p = np.asarray(points, dtype=np.float64)
    flat = p.reshape(-1, 3)
    theta, phi, r = (np.empty(flat.shape[0]) for _ in range(3))
    dirs = np.empty(flat.shape)
    optics_kernels.source_angles(flat, pose.translation, pose.rotation,
                                 float(pattern.baseline_m), theta, phi, r, dirs)
    shape = p.shape[:-1]
    return theta.reshape(shape), phi.reshape(shape), r.reshape(shape), dirs.reshape(p.shape)


def sheet_profile(theta: FloatArray, pattern: LinePattern,
                  footprint: FloatArray, psf_sigma_px: float) -> FloatArray:
    """Σ_k of the pixel-averaged Gaussian profile of every line, peak 1 for a thin pixel."""
    sigma = pattern.line_sigma_rad
    var = sigma**2 + footprint**2 * (1.0 / 12.0 + psf_sigma_px**2)
    total = np.zeros_like(theta)
    for alpha in pattern.alpha_rad:
        total += np.exp(-((theta - alpha) ** 2) / (2.0 * var))
    return np.nan_to_num(total * (sigma / np.sqrt(var)))


def sheet_irradiance(pose: Mounting, pattern: LinePattern, shapes: Sequence[Shape], *,
                     points: FloatArray, normals: FloatArray, hit: BoolArray,
                     psf_sigma_px: float, time_s: float = 0.0) -> FloatArray:
    """Irradiance (H, W) W/m² of a line pattern at surface points (H, W, 3), with shadows.

    ``hit`` (H, W) marks pixels that see a surface; others get 0 and are not computed.
    Pixels below ``PROFILE_CUTOFF`` of the line profile get 0 without a shadow test.
    """
    seen = np.flatnonzero(hit)
    theta_s, phi, r, dirs = sheet_angles(pose, pattern, points.reshape(-1, 3)[seen])
    theta = np.full(hit.shape, np.nan)
    theta.reshape(-1)[seen] = theta_s
    footprint = footprint_rad(theta).reshape(-1)[seen]
    profile = sheet_profile(theta_s, pattern, footprint, psf_sigma_px)
    in_fan = (np.abs(phi) <= pattern.fan_rad / 2.0) & (theta_s > 0.0)
    cos_i = np.clip(-np.einsum("...i,...i->...", normals.reshape(-1, 3)[seen], dirs), 0.0, None)
    peak = sheet_peak_intensity(pattern)
    irr = np.where(in_fan, peak * profile * cos_i / np.maximum(r, 1e-3) ** 2, 0.0)
    lit = np.flatnonzero((irr > 0.0) & (profile > PROFILE_CUTOFF))
    if lit.size:
        shadow = occluded(shapes, points.reshape(-1, 3)[seen[lit]], -dirs[lit], r[lit], time_s)
        lit = lit[~shadow]
    flat = np.zeros(hit.size)
    flat[seen[lit]] = irr[lit]
    return flat.reshape(hit.shape)


def _angle(a: FloatArray, b: FloatArray) -> FloatArray:
    """Angle (rad) between unit vectors a and b (..., 3)."""
    return np.arccos(np.clip(np.einsum("...i,...i->...", a, b), -1.0, 1.0))


def finish_factor(finish: dict[str, FloatArray], normals: FloatArray, from_source: FloatArray,
                  to_eye: FloatArray) -> FloatArray:
    """Radiance per irradiance (sr⁻¹) the finish adds to the diffuse ``ρ (1 − s) / π``
    (see "Finishes" above). ``finish`` holds per-pixel ``retro_gain``, ``retro_lobe_rad``,
    ``mirror`` (ρ s) and ``gloss_rad``; ``from_source`` the unit directions of the light,
    ``to_eye`` the unit directions from the surface to the camera, all (..., 3)."""
    beta = _angle(-from_source, to_eye)
    lobe = finish["retro_lobe_rad"]
    retro = finish["retro_gain"] / math.pi * np.exp(-0.5 * (beta / lobe) ** 2)
    cos_in = np.einsum("...i,...i->...", from_source, normals)
    mirrored = from_source - 2.0 * cos_in[..., None] * normals
    gamma, gloss = _angle(mirrored, to_eye), finish["gloss_rad"]
    glossy = finish["mirror"] * np.exp(-0.5 * (gamma / gloss) ** 2) / (2.0 * math.pi * gloss**2)
    return retro + glossy
