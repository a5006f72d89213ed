"""Scene files: TOML in, validated frozen dataclasses out. The format is in docs/scenes.md.

``load_scene("indoor_lab")`` reads ``launch/scenes/indoor_lab.toml``; any other argument
containing a path separator or ending in ``.toml`` is read as a path. The ``launch/``
folder sits at the repository root, next to the ``atris_node`` package: it is found from
the package's parent directory (an editable install or a source checkout), then from the
current directory, then from ``$ATRIS_SCENES`` (a folder of scene files, for installs that
do not carry ``launch/``).

Geometry is given in the vehicle frame (x forward, y left, z up, metres, ground at z = 0);
angles in degrees in the file, radians in the dataclasses. Projector lines are renumbered
top of the image first (ascending ``f·cot α``), the order calibration uses.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from atris_node.calibration import CameraModel
from atris_node.errors import ConfigError
from atris_node.mounting import Mounting
from atris_node.sim import schema as s
from atris_node.sim.miscalibration import Miscalibration, parse_miscalibration
from atris_node.sim.raycast import Box, Cylinder, Plane, Ramp, Shape, Sphere

F = s.Field
SCENES_ENV = "ATRIS_SCENES"


@dataclass(frozen=True)
class CameraSpec:
    """Sensor and lens. Units: px, Hz, µs, e⁻, DN/e⁻, µm; ``psf_sigma_px`` is lens blur."""

    width_px: int
    height_px: int
    focal_px: float
    cx_px: float
    cy_px: float
    rate_hz: float
    exposure_us: float
    bits: int
    full_well_e: float
    read_noise_e: float
    gain_dn_per_e: float
    distortion: tuple[float, ...] = ()
    pixel_pitch_um: float = 6.0
    f_number: float = 2.0
    quantum_efficiency: float = 0.3
    psf_sigma_px: float = 0.5

    @property
    def model(self) -> CameraModel:
        """The pinhole model with distortion, as calibration holds it."""
        return CameraModel(self.width_px, self.height_px, self.focal_px, self.cx_px,
                           self.cy_px, self.distortion)


@dataclass(frozen=True)
class LinePattern:
    """A DOE of parallel lines: K angles α_k (rad), baseline (m), power (W, all lines),
    angular line width (FWHM, mrad), fan (full angle, rad), wavelength (nm).

    ``filter_factor`` (0..1) is the fraction of ambient light the camera's narrow-band
    filter passes; it matters only for the unit's own projector (the camera's filter).
    """

    alpha_rad: tuple[float, ...]
    power_w: float
    baseline_m: float = 0.0
    line_width_mrad: float = 1.0
    fan_rad: float = math.radians(70.0)
    wavelength_nm: float = 650.0
    filter_factor: float = 1.0

    @property
    def line_sigma_rad(self) -> float:
        """Gaussian σ of the sheet's angular thickness, radians."""
        return self.line_width_mrad * 1e-3 / (2.0 * math.sqrt(2.0 * math.log(2.0)))


@dataclass(frozen=True)
class Window:
    """A rectangular aperture sunlight must pass: centre and two half-side vectors (m)."""

    center_m: tuple[float, float, float]
    half_a_m: tuple[float, float, float]
    half_b_m: tuple[float, float, float]


@dataclass(frozen=True)
class Sun:
    """Direct sun: illuminance on a surface facing it (lux), direction, optional window."""

    lux: float
    azimuth_rad: float
    elevation_rad: float
    window: Window | None = None

    @property
    def direction(self) -> np.ndarray:
        """Unit vector (3,) from the scene towards the sun, vehicle frame."""
        ce = math.cos(self.elevation_rad)
        return np.array([ce * math.cos(self.azimuth_rad), ce * math.sin(self.azimuth_rad),
                         math.sin(self.elevation_rad)])


@dataclass(frozen=True)
class Lamp:
    """Artificial light: illuminance (lux) with flicker (Hz) of relative depth 0..1."""

    lux: float
    flicker_hz: float = 0.0
    flicker_depth: float = 0.0


@dataclass(frozen=True)
class Ambient:
    """Sky (diffuse, lux on a horizontal surface), sun and lamps, each optional: ``lamp``
    (the file's ``lamp``) and ``lamps`` (the file's ``lamps`` list) together."""

    sky_lux: float = 0.0
    sun: Sun | None = None
    lamp: Lamp | None = None
    lamps: tuple[Lamp, ...] = ()

    @property
    def all_lamps(self) -> tuple[Lamp, ...]:
        """Every lamp of the scene: ``lamp`` first, then ``lamps``."""
        return ((self.lamp,) if self.lamp is not None else ()) + self.lamps

    @property
    def lamp_lux(self) -> float:
        """Mean illuminance of all lamps together, lux."""
        return sum(lamp.lux for lamp in self.all_lamps)


@dataclass(frozen=True)
class InterfererSpec:
    """Another unit's projector: pose (its camera frame), pattern and strobe timing.

    ``strobe`` is ``"cw"`` (always on) or ``"code"``: Walsh row ``code_row`` of length
    ``code_length`` at ``chip_rate_hz``, sub-frame j starting at
    ``(j + phase_sub_frames) / chip_rate_hz`` and lit for ``exposure_us`` when its chip is 1.
    """

    name: str
    pose: Mounting
    pattern: LinePattern
    strobe: str = "cw"
    code_length: int = 16
    code_row: int = 2
    chip_rate_hz: float = 240.0
    phase_sub_frames: float = 0.0
    exposure_us: float = 1000.0


@dataclass(frozen=True)
class Scene:
    """A validated scene. ``mountings`` holds one pose per unit (index = ``unit``)."""

    name: str
    camera: CameraSpec
    projector: LinePattern
    mountings: tuple[Mounting, ...]
    ambient: Ambient
    shapes: tuple[Shape, ...]
    interferers: tuple[InterfererSpec, ...] = ()
    noise: bool = True
    seed: int = 1
    code_length: int = 16
    code_row: int = 2
    description: str = ""
    path: Path | None = field(default=None, compare=False)
    z_max_m: float | None = None
    miscalibration: Miscalibration = field(default_factory=Miscalibration)


_POSE = {"x_m": F(float, 0.0), "y_m": F(float, 0.0), "z_m": F(float, 0.5),
         "roll_deg": F(float, 0.0), "pitch_deg": F(float, 0.0, s.within(-89.9, 89.9)),
         "yaw_deg": F(float, 0.0, s.within(-360.0, 360.0))}
_CAMERA = {
    "width_px": F(int, s.REQUIRED, s.within(8, 8192)),
    "height_px": F(int, s.REQUIRED, s.within(8, 8192)),
    "focal_px": F(float, s.REQUIRED, s.positive), "cx_px": F(float, None),
    "cy_px": F(float, None), "rate_hz": F(float, s.REQUIRED, s.within(1.0, 10000.0)),
    "exposure_us": F(float, s.REQUIRED, s.positive), "bits": F(int, 10, s.within(8, 16)),
    "full_well_e": F(float, 10000.0, s.positive),
    "read_noise_e": F(float, 3.0, s.non_negative),
    "gain_dn_per_e": F(float, None, s.positive), "distortion": F("floats", ()),
    "pixel_pitch_um": F(float, 6.0, s.positive), "f_number": F(float, 2.0, s.positive),
    "quantum_efficiency": F(float, 0.3, s.within(0.001, 1.0)),
    "psf_sigma_px": F(float, 0.5, s.within(0.0, 10.0)),
}
_PATTERN = {
    "alpha_deg": F("floats", s.REQUIRED, s.within(0.1, 179.9)),
    "power_w": F(float, s.REQUIRED, s.non_negative),
    "baseline_m": F(float, 0.0, s.within(-10.0, 10.0)),
    "line_width_mrad": F(float, 1.0, s.positive),
    "fan_deg": F(float, 70.0, s.within(0.1, 179.0)),
    "wavelength_nm": F(float, 650.0, s.within(300.0, 2000.0)),
}
_PROJECTOR = {**_PATTERN, "baseline_m": F(float, s.REQUIRED, s.positive),
              "filter_factor": F(float, 1.0, s.within(0.0, 1.0))}
_SHAPE_COMMON = {"albedo": F(float, 0.5, s.within(0.0, 1.0)), "name": F(str, ""),
                 "velocity_mps": F("vec3", (0.0, 0.0, 0.0)),
                 "acceleration_mps2": F("vec3", (0.0, 0.0, 0.0), s.within(-100.0, 100.0)),
                 "retro_gain": F(float, 0.0, s.within(0.0, 1e5)),
                 "retro_lobe_deg": F(float, 1.0, s.within(0.01, 10.0)),
                 "specular": F(float, 0.0, s.within(0.0, 1.0)),
                 "gloss_deg": F(float, 2.0, s.within(0.1, 30.0))}
_SHAPES: dict[str, tuple[type[Shape], dict[str, s.Field]]] = {
    "plane": (Plane, {"point_m": F("vec3"), "normal": F("vec3")}),
    "box": (Box, {"center_m": F("vec3"), "size_m": F("vec3"), "yaw_deg": F(float, 0.0)}),
    "cylinder": (Cylinder, {"center_m": F("vec3"), "radius_m": F(float, s.REQUIRED, s.positive),
                            "height_m": F(float, s.REQUIRED, s.positive)}),
    "sphere": (Sphere, {"center_m": F("vec3"), "radius_m": F(float, s.REQUIRED, s.positive)}),
    "ramp": (Ramp, {"start_m": F("vec3"), "length_m": F(float, s.REQUIRED, s.positive),
                    "width_m": F(float, s.REQUIRED, s.positive),
                    "slope_deg": F(float, s.REQUIRED, s.within(0.1, 90.0)),
                    "yaw_deg": F(float, 0.0)}),
}
#: keys given in degrees in the file and held in radians
_DEGREES = ("yaw_deg", "slope_deg", "retro_lobe_deg", "gloss_deg")
_INTERFERER = {
    "name": F(str, "interferer"), "pose": F(dict, s.REQUIRED),
    "strobe": F(str, "cw", s.one_of("cw", "code")), "code_length": F(int, 16, s.within(2, 1024)),
    "code_row": F(int, 2, s.within(1, 1024)),
    "chip_rate_hz": F(float, 240.0, s.within(1.0, 10000.0)),
    "phase_sub_frames": F(float, 0.0, s.within(-1e6, 1e6)),
    "exposure_us": F(float, 1000.0, s.positive), **_PATTERN,
}
_TOP = ("scene", "camera", "projector", "mounting", "ambient", "ground", "code", "noise",
        "interferer", "miscalibration", *_SHAPES)


def _pose(table: Any, where: str) -> Mounting:
    p = s.read_table(table, where, _POSE)
    return Mounting(p["x_m"], p["y_m"], p["z_m"], math.radians(p["roll_deg"]),
                    math.radians(p["pitch_deg"]), math.radians(p["yaw_deg"]))


def _camera(table: Any) -> CameraSpec:
    c = s.read_table(table, "camera", _CAMERA)
    c["cx_px"] = (c["width_px"] - 1) / 2.0 if c["cx_px"] is None else c["cx_px"]
    c["cy_px"] = (c["height_px"] - 1) / 2.0 if c["cy_px"] is None else c["cy_px"]
    if c["gain_dn_per_e"] is None:
        c["gain_dn_per_e"] = ((1 << c["bits"]) - 1) / c["full_well_e"]
    if len(c["distortion"]) > 5:
        raise s.fail("camera.distortion", "must be at most 5 numbers (k1 k2 p1 p2 k3)",
                     list(c["distortion"]))
    if 1e6 / c["rate_hz"] < c["exposure_us"]:
        raise s.fail("camera.exposure_us", f"must fit the sub-frame period "
                     f"{1e6 / c['rate_hz']:.1f} µs", c["exposure_us"])
    return CameraSpec(**c)


def _pattern(p: dict[str, Any], focal_px: float) -> LinePattern:
    alphas = sorted((math.radians(a) for a in p.pop("alpha_deg")),
                    key=lambda a: focal_px / math.tan(a))
    p["fan_rad"] = math.radians(p.pop("fan_deg"))
    return LinePattern(alpha_rad=tuple(alphas), **p)


def _shapes(data: dict[str, Any]) -> tuple[Shape, ...]:
    shapes: list[Shape] = []
    ground = s.read_table(data.get("ground", {}), "ground",
                          {"enabled": F(bool, True), "albedo": F(float, 0.3, s.within(0, 1))})
    if ground["enabled"]:
        shapes.append(Plane(albedo=ground["albedo"], name="ground", obstacle=False))
    for kind, (cls, spec) in _SHAPES.items():
        for i, table in enumerate(s.tables(data.get(kind, []), kind)):
            values = s.read_table(table, f"{kind}[{i}]", {**_SHAPE_COMMON, **spec})
            for key in _DEGREES:
                if key in values:
                    values[key.replace("_deg", "_rad")] = math.radians(values.pop(key))
            shapes.append(cls(**values))
    return tuple(shapes)


def _window(table: Any) -> Window:
    w = s.read_table(table, "ambient.sun.window", {
        "center_m": F("vec3"), "half_a_m": F("vec3"), "half_b_m": F("vec3")})
    return Window(**w)


def _lamp(table: Any, where: str) -> Lamp:
    v = s.read_table(table, where, {
        "lux": F(float, s.REQUIRED, s.non_negative),
        "flicker_hz": F(float, 0.0, s.non_negative),
        "flicker_depth": F(float, 0.0, s.within(0.0, 1.0))})
    return Lamp(**v)


def _lamps(value: Any) -> tuple[Lamp, ...]:
    """``ambient.lamps``: a list of lamp tables (inline tables or ``[[ambient.lamps]]``)."""
    if not isinstance(value, list):
        raise s.fail("ambient.lamps", "must be a list of lamp tables "
                     "({ lux, flicker_hz, flicker_depth })", value)
    return tuple(_lamp(t, f"ambient.lamps[{i}]") for i, t in enumerate(value))


def _ambient(table: Any) -> Ambient:
    a = s.read_table(table, "ambient", {"sky_lux": F(float, 0.0, s.non_negative),
                                        "sun": F(dict, None), "lamp": F(dict, None),
                                        "lamps": F(list, [])})
    sun = lamp = None
    if a["sun"] is not None:
        raw = dict(a["sun"])
        window = _window(raw.pop("window")) if "window" in raw else None
        v = s.read_table(raw, "ambient.sun", {
            "lux": F(float, s.REQUIRED, s.non_negative), "azimuth_deg": F(float, 0.0),
            "elevation_deg": F(float, 45.0, s.within(0.0, 90.0))})
        sun = Sun(v["lux"], math.radians(v["azimuth_deg"]), math.radians(v["elevation_deg"]),
                  window)
    if a["lamp"] is not None:
        lamp = _lamp(a["lamp"], "ambient.lamp")
    return Ambient(a["sky_lux"], sun, lamp, _lamps(a["lamps"]))


def _interferers(data: Any, focal_px: float) -> tuple[InterfererSpec, ...]:
    out = []
    for i, table in enumerate(s.tables(data, "interferer")):
        where = f"interferer[{i}]"
        v = s.read_table(table, where, _INTERFERER)
        pattern = _pattern({k: v.pop(k) for k in _PATTERN}, focal_px)
        pose = _pose(v.pop("pose"), f"{where}.pose")
        if v["strobe"] == "code" and not 1 <= v["code_row"] <= v["code_length"]:
            raise s.fail(f"{where}.code_row", f"must be in 1..{v['code_length']}", v["code_row"])
        out.append(InterfererSpec(pose=pose, pattern=pattern, **v))
    return tuple(out)


def parse_scene(data: dict[str, Any], name: str = "scene", path: Path | None = None) -> Scene:
    """Validate a parsed TOML document into a :class:`Scene`; raises ConfigError."""
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise ConfigError(f"scene {unknown[0]}: unknown table; accepted: {', '.join(_TOP)}")
    meta = s.read_table(data.get("scene", {}), "scene",
                        {"name": F(str, name), "description": F(str, ""),
                         "z_max_m": F(float, None, s.within(0.5, 200.0))})
    camera = _camera(data.get("camera"))
    raw = s.read_table(data.get("projector"), "projector", _PROJECTOR)
    miscalibration = _miscalibration(data.get("miscalibration", {}), raw, camera.focal_px)
    projector = _pattern(raw, camera.focal_px)
    mountings = tuple(_pose(t, f"mounting[{i}]")
                      for i, t in enumerate(s.tables(data.get("mounting", {}), "mounting")))
    code = s.read_table(data.get("code", {}), "code",
                        {"length": F(int, 16, s.within(4, 128)), "row": F(int, 2)})
    noise = s.read_table(data.get("noise", {}), "noise",
                         {"enabled": F(bool, True), "seed": F(int, 1, s.within(0, 2**63))})
    return Scene(name=meta["name"], description=meta["description"], camera=camera,
                 projector=projector, mountings=mountings or (Mounting(),),
                 ambient=_ambient(data.get("ambient", {})), shapes=_shapes(data),
                 interferers=_interferers(data.get("interferer", []), camera.focal_px),
                 noise=noise["enabled"], seed=noise["seed"], code_length=code["length"],
                 code_row=code["row"], path=path, z_max_m=meta["z_max_m"],
                 miscalibration=miscalibration)


def _miscalibration(table: Any, projector: dict[str, Any], focal_px: float) -> Miscalibration:
    """The ``[miscalibration]`` table against the (file-order) projector angles."""
    alpha_deg = tuple(projector["alpha_deg"])
    order = sorted(range(len(alpha_deg)),
                   key=lambda i: focal_px / math.tan(math.radians(alpha_deg[i])))
    return parse_miscalibration(table, alpha_deg, order, projector["baseline_m"])


#: sub-folder of a scene folder holding the stress scenes
STRESS = "stress"


def scene_dirs() -> list[Path]:
    """Folders searched for shipped scene names, in order."""
    package_parent = Path(__file__).resolve().parents[2]
    dirs = [package_parent / "launch" / "scenes", Path.cwd() / "launch" / "scenes"]
    if os.environ.get(SCENES_ENV):
        dirs.append(Path(os.environ[SCENES_ENV]))
    return dirs


def shipped_scenes() -> list[str]:
    """Names of the scenes found in :func:`scene_dirs`."""
    return sorted({p.stem for d in scene_dirs() if d.is_dir() for p in d.glob("*.toml")})


def stress_scenes() -> list[str]:
    """Names of the stress scenes (the ``stress`` folder of :func:`scene_dirs`): hard cases
    stated from the physics (docs/scenes.md), loadable by name like the shipped ones."""
    return sorted({p.stem for d in scene_dirs() if (d / STRESS).is_dir()
                   for p in (d / STRESS).glob("*.toml")})


def resolve_scene(path_or_name: str | Path) -> Path:
    """The file of a scene given as a path or a shipped name; raises ConfigError."""
    text = str(path_or_name)
    if isinstance(path_or_name, Path) or text.endswith(".toml") or os.sep in text:
        path = Path(path_or_name)
        if not path.is_file():
            raise ConfigError(f"scene file {path} does not exist")
        return path
    for folder in scene_dirs():
        for where in (folder, folder / STRESS):
            if (where / f"{text}.toml").is_file():
                return where / f"{text}.toml"
    raise ConfigError(f"no scene named {text!r}; shipped: {', '.join(shipped_scenes())}")


def load_scene(path_or_name: str | Path) -> Scene:
    """Read and validate a scene file (path) or shipped scene (name)."""
    path = resolve_scene(path_or_name)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"scene file {path}: not valid TOML: {exc}") from exc
    return parse_scene(data, name=path.stem, path=path)
