"""The simulator: a scene in, :class:`atris_node.types.SubFrame` objects out.

Sub-frame ``sequence`` is exposed from ``t0 = sequence / rate_hz`` for ``exposure_us``;
its device (and host) time is the exposure mid-time on this simulated clock. Its mean
electrons are a weighted sum of per-pixel rates computed once for the static scene:

    e = (steady + chip · laser + flicker(t0, t1) · lamp + Σ_j on_j(t0, t1) · interferer_j)
        · exposure

where ``on_j`` is the fraction of the window interferer j was lit (integrated, so a
different chip rate or a fractional phase acts as on a real sensor). Shapes with a velocity
are re-cast per sub-frame only inside their image bounding box, and they shadow the laser
on the static scene; they do not shadow sun or interferers (documented simplification).

Work a scene does not need is skipped: with no flicker, interferer or motion the mean image
of each chip is prepared once (noise-free pixels are cached outright); ``calls`` counts
each stage so tests can see what ran. Noise of sub-frame ``sequence`` comes from its own
generator seeded by ``(seed, unit, sequence)``, so a fixed seed gives bit-identical
sub-frames in any order.

Truth and belief: the renderer and the truth use the scene's true pose
(``true_mounting``) and projector; ``mounting`` and :meth:`Simulator.calibration` are what
the unit's pipeline gets, the truth off by the scene's ``[miscalibration]`` (equal to the
truth without one). This is the one place the error is applied: ``atris sim``, the benches
and the node's simulated camera all build their pipeline from these two.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from atris_node.calibration import Calibration, LaserCalibration
from atris_node.codes import walsh_chips
from atris_node.errors import ConfigError
from atris_node.mounting import Mounting
from atris_node.pipeline.geometry import distort_pixels
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim import layers
from atris_node.sim.optics import line_return_dn_m2, sheet_angles, stripe_sigma_px
from atris_node.sim.raycast import Shape, occluded
from atris_node.sim.scene import LinePattern, Scene
from atris_node.sim.sensor import Pixels, Sensor
from atris_node.sim.strobe import Strobe, always_on, code_strobe, lamps_factor
from atris_node.sim.truth import Truth, compute_truth
from atris_node.types import SubFrame

logger = logging.getLogger(__name__)
Float32Array = npt.NDArray[np.float32]
#: pixels added around a moving shape's projected bounding box
BOX_MARGIN_PX = 3


@dataclass(frozen=True)
class Source:
    """An interfering line projector: pose (its camera frame), pattern, strobe."""

    pose: Mounting
    pattern: LinePattern
    strobe: Strobe
    name: str = ""


@dataclass
class _Static:
    """Rates of the static scene (e⁻/s, float32 (H, W)) and laser-lit pixels."""

    surface: layers.Surface
    steady: Float32Array
    lamp: Float32Array
    laser: Float32Array
    interferers: list[Float32Array] = field(default_factory=list)
    lit: npt.NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, np.intp))
    #: shadow rays of the lit pixels towards the own projector: points (n, 3), unit
    #: directions (n, 3), distances (n,) m; made at the first moving sub-frame
    lit_rays: tuple[npt.NDArray[np.float64], ...] | None = None


def _source_of(spec: object) -> Source:
    from atris_node.sim.scene import InterfererSpec

    assert isinstance(spec, InterfererSpec)
    if spec.strobe == "cw":
        return Source(spec.pose, spec.pattern, always_on, spec.name)
    chips = [int(c) for c in walsh_chips(spec.code_length, spec.code_row)]
    strobe = code_strobe(chips, spec.chip_rate_hz, spec.phase_sub_frames,
                         spec.exposure_us * 1e-6)
    return Source(spec.pose, spec.pattern, strobe, spec.name)


class Simulator:
    """Renders sub-frames and ground truth of ``scene`` for unit ``unit``'s mounting.

    ``chips`` is the own code used when :meth:`render` gets no chip (default: the
    scene's ``[code]``); ``seed`` overrides the scene's noise seed.
    """

    def __init__(self, scene: Scene, chips: npt.ArrayLike | None = None,
                 seed: int | None = None, unit: int = 0) -> None:
        if not 0 <= unit < len(scene.mountings):
            raise ConfigError(f"unit {unit} has no mounting in scene {scene.name!r}; "
                              f"accepted: 0..{len(scene.mountings) - 1}")
        self.scene, self.camera, self.unit = scene, scene.camera, unit
        self.true_mounting = scene.mountings[unit]
        #: the pose the unit's pipeline gets (the truth off by the scene's miscalibration)
        self.mounting = scene.miscalibration.mounting(self.true_mounting)
        default = walsh_chips(scene.code_length, scene.code_row)
        self.chips = np.asarray(default if chips is None else chips, dtype=np.uint8)
        self.seed = scene.seed if seed is None else int(seed)
        self.noise = scene.noise
        self.rate_hz = scene.camera.rate_hz
        self.exposure_us = scene.camera.exposure_us
        self.sensor = Sensor(scene.camera)
        self.calls: collections.Counter[str] = collections.Counter()
        self.sources = [_source_of(spec) for spec in scene.interferers]
        self.static_shapes = tuple(s for s in scene.shapes if not s.moving)
        self.moving_shapes = tuple(s for s in scene.shapes if s.moving)
        self._dirs_cam, self._dirs = layers.camera_rays(scene.camera, self.true_mounting)
        self._static: _Static | None = None
        self._lock = threading.Lock()
        self._prepared: dict[int, tuple[object, ...]] = {}
        self.set_exposure_us(scene.camera.exposure_us)  # checks it fits the sub-frame rate

    # ------------------------------------------------------------------ set-up
    @property
    def flickers(self) -> bool:
        """True when the scene has a lamp with flicker."""
        return any(lamp.lux > 0 and lamp.flicker_hz > 0 and lamp.flicker_depth > 0
                   for lamp in self.scene.ambient.all_lamps)

    def _lamp_factor(self, t0: float, t1: float) -> np.float32:
        """Mean lamp output over the window relative to the lamps' mean (flicker)."""
        self.calls["flicker"] += 1
        return np.float32(lamps_factor(self.scene.ambient.all_lamps, t0, t1))

    @property
    def dynamic(self) -> bool:
        """True when sub-frames differ by more than chip and noise."""
        return self.flickers or bool(self.sources) or bool(self.moving_shapes)

    def _sheet(self, static: _Static, pose: Mounting, pattern: LinePattern) -> Float32Array:
        return layers.sheet_rates(self.camera, pose, pattern, static.surface,
                                  self.static_shapes, eye_m=self.true_mounting.translation)

    def _static_layer(self) -> _Static:
        """The static scene's rates, rendered once (thread-safe: another thread may be
        attaching interferers while this one renders)."""
        static = self._static
        if static is None:
            with self._lock:
                if self._static is None:
                    self._static = self._render_static()
                static = self._static
        return static

    def _render_static(self) -> _Static:
        self.calls["static_render"] += 1
        surface = layers.see(self.static_shapes, self.true_mounting.translation, self._dirs)
        steady, lamp = layers.ambient_rates(self.scene, surface, self.static_shapes)
        if not self.flickers:
            steady += lamp
        laser = layers.sheet_rates(self.camera, self.true_mounting, self.scene.projector,
                                   surface, self.static_shapes)
        static = _Static(surface, steady, lamp, laser,
                         lit=np.flatnonzero(laser.reshape(-1) > 0))
        static.interferers = [self._sheet(static, s.pose, s.pattern) for s in self.sources]
        return static

    def add_interferer(self, pose: Mounting, pattern: LinePattern, strobe: Strobe,
                       name: str = "") -> None:
        """Attach a strobing line projector at ``pose`` (its camera frame, vehicle frame
        coordinates); ``strobe(t0_s, t1_s)`` is the fraction of the window it was ON.

        Safe while another thread renders: the rates are appended before the source, so
        a render pairs sources with rates by index and never sees a source without them.
        """
        source = Source(pose, pattern, strobe, name)
        with self._lock:
            if self._static is not None:
                self._static.interferers.append(self._sheet(self._static, pose, pattern))
            self.sources.append(source)
            self._prepared.clear()

    def set_exposure_us(self, exposure_us: float) -> None:
        """Change the exposure (µs, > 0, at most one sub-frame period)."""
        period_us = 1e6 / self.rate_hz
        if not (math.isfinite(exposure_us) and 0 < exposure_us <= period_us):
            raise ConfigError(f"exposure_us must be in (0, {period_us:.1f}], got {exposure_us}")
        self.exposure_us = float(exposure_us)
        self._prepared.clear()

    # ------------------------------------------------------------------ render
    def window(self, sequence: int) -> tuple[float, float]:
        """Exposure window ``(t0_s, t1_s)`` of sub-frame ``sequence`` on the simulated clock."""
        t0 = sequence / self.rate_hz
        return t0, t0 + self.exposure_us * 1e-6

    def rng(self, sequence: int) -> np.random.Generator:
        """The noise generator of sub-frame ``sequence`` (independent of render order)."""
        key = np.random.SeedSequence([self.seed, self.unit, sequence % (1 << 63)])
        return np.random.Generator(np.random.SFC64(key))

    def render(self, sequence: int, chip: int | None = None) -> SubFrame:
        """Sub-frame ``sequence`` with the own projector emitting ``chip`` (0 or 1; None =
        ``chips[sequence % N]``). Pixels are a fresh array each call."""
        if chip is None:
            chip = int(self.chips[sequence % self.chips.size])
        if chip not in (0, 1):
            raise ValueError(f"chip must be 0 or 1, got {chip!r}")
        t0, t1 = self.window(sequence)
        if self.dynamic:
            pixels = self._finish(self._electrons(chip, t0, t1), sequence)
        else:
            pixels = self._static_pixels(chip, sequence)
        mid = 0.5 * (t0 + t1)
        return SubFrame(pixels, sequence, mid, mid, self.exposure_us, self.camera.bits, chip)

    def _mean_electrons(self, chip: int) -> Float32Array:
        static = self._static_layer()
        exposure_s = np.float32(self.exposure_us * 1e-6)
        return (static.steady + static.laser * chip) * exposure_s

    def _static_pixels(self, chip: int, sequence: int) -> Pixels:
        if chip not in self._prepared:
            mean = self._mean_electrons(chip)
            self._prepared[chip] = (self.sensor.prepare(mean) if self.noise
                                    else (self.sensor.quantise(mean),))
        prepared = self._prepared[chip]
        if not self.noise:
            pixels = prepared[0]
            assert isinstance(pixels, np.ndarray)
            return pixels.copy()
        self.calls["noise"] += 1
        return self.sensor.noisy(self.rng(sequence), *prepared)  # type: ignore[arg-type]

    def _finish(self, electrons: Float32Array, sequence: int) -> Pixels:
        if not self.noise:
            return self.sensor.quantise(electrons)
        self.calls["noise"] += 1
        return self.sensor.noisy_electrons(self.rng(sequence), electrons)

    def _electrons(self, chip: int, t0: float, t1: float) -> Float32Array:
        static = self._static_layer()
        exposure_s = np.float32(self.exposure_us * 1e-6)
        e = static.steady.copy()
        if self.flickers:
            e += static.lamp * self._lamp_factor(t0, t1)
        if chip:
            e += self._laser(0.5 * (t0 + t1)) if self.moving_shapes else static.laser
        for source, rates in zip(list(self.sources), static.interferers, strict=False):
            self.calls["interferer"] += 1
            on = source.strobe(t0, t1)
            if on > 0.0:
                e += rates * np.float32(on)
        e *= exposure_s
        if self.moving_shapes:
            self._paint_moving(e, chip, t0, t1)
        return e

    # ------------------------------------------------------------------ motion
    def _laser(self, time_s: float) -> Float32Array:
        """Own-laser rates with the shadows the moving shapes cast at ``time_s``."""
        static = self._static_layer()
        if static.lit_rays is None:
            points = static.surface.points.reshape(-1, 3)[static.lit]
            _, _, r, dirs = sheet_angles(self.true_mounting, self.scene.projector, points)
            static.lit_rays = (points, -dirs, r)
        points, towards, r = static.lit_rays
        shadow = occluded(self.moving_shapes, points, towards, r, time_s)
        laser = static.laser.copy()
        laser.reshape(-1)[static.lit[shadow]] = 0.0
        return laser

    def _box(self, shape: Shape, time_s: float) -> tuple[int, int, int, int] | None:
        """Observed pixel box (r0, r1, c0, c1) that may show ``shape``; None if off-image.

        The shape's axis-aligned bounds are projected corner by corner (the image of a
        box in front of the camera is the hull of its corners), the rectangle's edges
        pushed through the lens distortion, widened by BOX_MARGIN_PX.
        """
        cam, h, w = self.camera, self.camera.height_px, self.camera.width_px
        bounds = shape.bounds(time_s)
        if bounds is None:
            return 0, h, 0, w
        lo, hi = bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        local = self.true_mounting.vehicle_to_camera(corners)
        if local[:, 2].min() <= 0.05:
            return 0, h, 0, w
        u = cam.focal_px * local[:, 1] / local[:, 2]
        v = cam.focal_px * local[:, 0] / local[:, 2]
        edge = np.linspace(0.0, 1.0, 9)
        us = np.concatenate([u.min() + np.ptp(u) * edge, np.full(9, u.min()),
                             np.full(9, u.max()), u.min() + np.ptp(u) * edge])
        vs = np.concatenate([np.full(9, v.min()), v.min() + np.ptp(v) * edge,
                             v.min() + np.ptp(v) * edge, np.full(9, v.max())])
        rows, cols = distort_pixels(us + cam.cy_px, vs + cam.cx_px, cam.model)
        r0 = max(int(np.floor(rows.min())) - BOX_MARGIN_PX, 0)
        r1 = min(int(np.ceil(rows.max())) + BOX_MARGIN_PX + 1, h)
        c0 = max(int(np.floor(cols.min())) - BOX_MARGIN_PX, 0)
        c1 = min(int(np.ceil(cols.max())) + BOX_MARGIN_PX + 1, w)
        return (r0, r1, c0, c1) if r1 > r0 and c1 > c0 else None

    def _paint_moving(self, e: Float32Array, chip: int, t0: float, t1: float) -> None:
        """Replace, inside each moving shape's box, the pixels it covers at mid-exposure."""
        self.calls["motion"] += 1
        time_s = 0.5 * (t0 + t1)
        for shape in self.moving_shapes:
            box = self._box(shape, time_s)
            if box is not None:
                self._paint_box(e, box, chip, t0, t1)

    def _paint_box(self, e: Float32Array, box: tuple[int, int, int, int], chip: int,
                   t0: float, t1: float) -> None:
        r0, r1, c0, c1 = box
        time_s = 0.5 * (t0 + t1)
        static = self._static_layer()
        moving = layers.see(self.moving_shapes, self.true_mounting.translation,
                            self._dirs[r0:r1, c0:c1], time_s)
        near = moving.t < static.surface.t[r0:r1, c0:c1]
        if not near.any():
            return
        # only the pixels where the moving shape is in front are lit and written; their
        # neighbours on the static scene count as "no surface" for the stripe footprint
        part = replace(moving, hit=near)
        shapes = self.scene.shapes
        steady, lamp = layers.ambient_rates(self.scene, part, shapes, time_s=time_s)
        rates = steady if self.flickers else steady + lamp
        if self.flickers:
            rates += lamp * self._lamp_factor(t0, t1)
        if chip:
            rates += layers.sheet_rates(self.camera, self.true_mounting, self.scene.projector,
                                        part, shapes, time_s=time_s)
        eye = self.true_mounting.translation
        for source in self.sources:
            on = source.strobe(t0, t1)
            if on > 0.0:
                rates += layers.sheet_rates(self.camera, source.pose, source.pattern, part,
                                            shapes, time_s=time_s, eye_m=eye) * np.float32(on)
        window = e[r0:r1, c0:c1]
        window[near] = rates[near] * np.float32(self.exposure_us * 1e-6)

    # ------------------------------------------------------------------ truth
    def truth(self, sequence: int, layout: SectorLayout) -> Truth:
        """Ground truth at the exposure mid-time of sub-frame ``sequence``."""
        t0, t1 = self.window(sequence)
        return compute_truth(self.scene, self.true_mounting, self._dirs_cam, self._dirs,
                             sequence=sequence, time_s=0.5 * (t0 + t1), layout=layout)

    def true_calibration(self) -> Calibration:
        """The true camera model and light planes of this unit."""
        laser = self.scene.projector
        return Calibration(self.camera.model, LaserCalibration(
            laser.baseline_m, laser.alpha_rad,
            return_dn_m2=line_return_dn_m2(self.camera, laser),
            return_exposure_us=self.camera.exposure_us,
            stripe_sigma_px=stripe_sigma_px(self.camera, laser)))

    def calibration(self) -> Calibration:
        """The calibration the unit's pipeline gets: the truth off by the scene's
        ``[miscalibration]`` (the truth itself without one)."""
        return self.scene.miscalibration.calibration(self.true_calibration())

