"""Draw random, physically plausible scenes to look for wrong sector verdicts.

Usage: ``python scripts/draw_scenes.py OUT_DIR FIRST_SEED COUNT``

Writes ``OUT_DIR/s{seed}.toml`` for seed = FIRST_SEED .. FIRST_SEED + COUNT - 1. Scene
``seed`` is drawn with ``numpy.random.default_rng(seed)``; a draw that
``atris_node.sim.load_scene`` rejects is drawn again with ``default_rng([seed, k])``,
k = 1, 2, ... (the header names the sub-seed), so every file is reproducible.

A scene: a 640x400 camera (sometimes 640x480 or 1280x800) at f 300-600 px (doubled at
1280x800), 1-6 sheets meeting the ground 1-10 m ahead (sometimes a pair 0.2-0.6 deg
apart, sometimes one far or above the horizon), the unit 0.25-1.2 m up pitched 3 deg up
to 8 deg down; dark, lamp-lit (100/120/300 Hz flicker, a sunlit window) or outdoor light;
a wall behind or none, and 0-6 crates, cars, kerbs, spheres (some hanging), poles,
people, plates and ramps 0.5-12 m ahead, some retro-reflective or glossy, one moving in
about 15 % of scenes; in half the scenes a z_max (mostly short of the farthest sheet's
ground reach, so that sectors can be free), sometimes a calibration error or a foreign
unit.
"""

from __future__ import annotations

import json
import math
import sys
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from atris_node.errors import ConfigError
from atris_node.sim import load_scene

Table = dict[str, Any]
#: (kind of shape, its table, footprint radius in m)
Drawn = tuple[str, Table, float]
#: how many sub-seeds are tried before giving up on a seed
ATTEMPTS = 20
#: bench maps a moving object must stay clear of the unit for (4 maps and a spare)
MAPS_MOVING = 5


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def chance(rng: np.random.Generator, p: float) -> bool:
    return bool(rng.random() < p)


def pick(rng: np.random.Generator, options: list[Any], weights: list[float] | None = None
         ) -> Any:
    p = None if weights is None else np.asarray(weights) / sum(weights)
    return options[int(rng.choice(len(options), p=p))]


def draw_camera(rng: np.random.Generator, outdoor: bool) -> Table:
    width, height, scale = pick(rng, [(640, 400, 1), (640, 480, 1), (1280, 800, 2)],
                                [0.87, 0.07, 0.06])
    rate = pick(rng, [240.0, 200.0, 300.0, 480.0, 120.0], [0.5, 0.15, 0.15, 0.1, 0.1])
    period = 1e6 / rate
    exposure = (log_uniform(rng, 50.0, 0.8 * period) if outdoor
                else uniform(rng, 0.15, 0.95) * period)
    camera = {"width_px": width, "height_px": height,
              "focal_px": uniform(rng, 300.0, 600.0) * scale, "rate_hz": rate,
              "exposure_us": exposure, "bits": pick(rng, [10, 8], [0.7, 0.3]),
              "full_well_e": uniform(rng, 6000.0, 14000.0),
              "read_noise_e": uniform(rng, 2.0, 6.0),
              "psf_sigma_px": uniform(rng, 0.35, 1.0)}
    if chance(rng, 0.2):
        camera["f_number"] = pick(rng, [1.6, 2.8, 4.0])
    if chance(rng, 0.2):
        camera["cx_px"] = (width - 1) / 2 + uniform(rng, -8.0, 8.0)
        camera["cy_px"] = (height - 1) / 2 + uniform(rng, -8.0, 8.0)
    if chance(rng, 0.1):
        camera["distortion"] = [uniform(rng, -0.08, 0.05), uniform(rng, -0.02, 0.02)]
    return camera


def draw_mounting(rng: np.random.Generator) -> Table:
    """Height and pitch (positive tilts down, as the scene format has it), small roll."""
    roll = float(np.clip(rng.normal(0.0, 0.7), -2.0, 2.0)) if chance(rng, 0.5) else 0.0
    pitch = uniform(rng, -3.0, 8.0) if chance(rng, 0.4) else uniform(rng, -1.0, 3.5)
    return {"z_m": uniform(rng, 0.25, 1.2), "pitch_deg": pitch, "roll_deg": roll}


def sheet_alpha(reach_m: float, height_m: float, baseline_m: float, pitch_deg: float
                ) -> float:
    """The sheet angle α (deg) meeting the ground ``reach_m`` ahead (straight ahead): the
    projector is b above the camera, the sheet dips 90° − α + pitch below the horizon."""
    p = math.radians(pitch_deg)
    rise = height_m + baseline_m * math.cos(p)
    run = reach_m - baseline_m * math.sin(p)
    return 90.0 + pitch_deg - math.degrees(math.atan2(rise, run))


def ground_reach(alpha_deg: float, height_m: float, baseline_m: float, pitch_deg: float
                 ) -> float:
    """Where the sheet α meets the ground straight ahead, m (inf over the horizon): the
    inverse of :func:`sheet_alpha`."""
    p, dip = math.radians(pitch_deg), math.radians(90.0 + pitch_deg - alpha_deg)
    if dip <= 0.0:
        return math.inf
    return (height_m + baseline_m * math.cos(p)) / math.tan(dip) + baseline_m * math.sin(p)


def nearest_ground_seen(camera: Table, mounting: Table) -> float:
    """The nearest ground point straight ahead inside 90 % of the lower half-image, m."""
    half = math.degrees(math.atan(camera["height_px"] / 2 / camera["focal_px"]))
    dip = min(mounting["pitch_deg"] + 0.9 * half, 85.0)
    return mounting["z_m"] / math.tan(math.radians(dip)) if dip > 0 else math.inf


def draw_reaches(rng: np.random.Generator, count: int, nearest: float) -> list[float]:
    """Where ``count`` sheets meet the ground, m: evenly or randomly spread in 1-10 m."""
    lo = min(max(1.0, 1.1 * nearest), 8.0)
    near = uniform(rng, lo, max(lo, 3.0))
    if count == 1:
        return [uniform(rng, lo, 10.0)]
    far = uniform(rng, min(max(1.4 * near, 3.5), 9.5), 10.0)
    if chance(rng, 0.5):
        return list(np.geomspace(near, far, count))
    return sorted([near, far, *rng.uniform(near, far, count - 2)])


def draw_alphas(rng: np.random.Generator, camera: Table, mounting: Table, baseline: float
                ) -> list[float]:
    count = int(pick(rng, [1, 2, 3, 4, 5], [0.08, 0.22, 0.25, 0.25, 0.2]))
    h, pitch = mounting["z_m"], mounting["pitch_deg"]
    reaches = draw_reaches(rng, count, nearest_ground_seen(camera, mounting))
    alphas = [sheet_alpha(r, h, baseline, pitch) for r in reaches]
    if chance(rng, 0.25):  # two sheets nearly parallel
        alphas.append(pick(rng, alphas) + pick(rng, [-1, 1]) * uniform(rng, 0.2, 0.6))
    if len(alphas) < 6 and chance(rng, 0.15):  # one sheet far or over the horizon
        alphas.append(sheet_alpha(uniform(rng, 12.0, 40.0), h, baseline, pitch)
                      if chance(rng, 0.5) else 90.0 + pitch + uniform(rng, 0.1, 3.0))
    return [float(a) for a in rng.permutation(alphas)]


def draw_projector(rng: np.random.Generator, camera: Table, mounting: Table,
                   outdoor: bool) -> Table:
    baseline = uniform(rng, 0.08, 0.3)
    return {"baseline_m": baseline, "alpha_deg": draw_alphas(rng, camera, mounting, baseline),
            "power_w": log_uniform(rng, 0.3 if outdoor else 0.08, 1.0),
            "line_width_mrad": uniform(rng, 1.0, 2.5), "fan_deg": uniform(rng, 40.0, 90.0),
            "wavelength_nm": pick(rng, [650.0, 850.0, 940.0], [0.8, 0.1, 0.1]),
            "filter_factor": (log_uniform(rng, 0.02, 0.15) if outdoor
                              else pick(rng, [1.0, log_uniform(rng, 0.03, 0.5)]))}


def draw_code(rng: np.random.Generator) -> Table:
    length = int(pick(rng, [8, 16, 32], [0.25, 0.5, 0.25]))
    return {"length": length, "row": int(rng.integers(2, length + 1))}


def draw_lamp(rng: np.random.Generator) -> Table:
    flicker = pick(rng, [0.0, 100.0, 120.0, 300.0], [0.25, 0.35, 0.3, 0.1])
    return {"lux": log_uniform(rng, 50.0, 2000.0), "flicker_hz": flicker,
            "flicker_depth": uniform(rng, 0.01, 0.7) if flicker else 0.0}


def draw_window_sun(rng: np.random.Generator) -> Table:
    side = pick(rng, [-1.0, 1.0])
    window = {"center_m": [uniform(rng, 1.0, 4.0), side * uniform(rng, 1.5, 3.5),
                           uniform(rng, 1.0, 2.0)],
              "half_a_m": [uniform(rng, 0.3, 1.0), 0.0, 0.0],
              "half_b_m": [0.0, 0.0, uniform(rng, 0.3, 0.7)]}
    return {"lux": log_uniform(rng, 10000.0, 40000.0),
            "azimuth_deg": side * uniform(rng, 60.0, 150.0),
            "elevation_deg": uniform(rng, 15.0, 50.0), "window": window}


def draw_ambient(rng: np.random.Generator, kind: str) -> Table:
    if kind == "dark":
        return {"sky_lux": uniform(rng, 0.0, 5.0)}
    if kind == "indoor":
        ambient: Table = {"sky_lux": uniform(rng, 0.0, 20.0),
                          "lamps": [draw_lamp(rng) for _ in range(pick(rng, [1, 2, 3],
                                                                       [0.7, 0.2, 0.1]))]}
        if chance(rng, 0.2):
            ambient["sun"] = draw_window_sun(rng)
        return ambient
    ambient = {"sky_lux": log_uniform(rng, 1000.0, 20000.0)}
    if chance(rng, 0.75):
        ambient["sun"] = {"lux": log_uniform(rng, 5000.0, 100000.0),
                          "azimuth_deg": uniform(rng, -180.0, 180.0),
                          "elevation_deg": uniform(rng, 5.0, 70.0)}
    return ambient


def draw_finish(rng: np.random.Generator) -> Table:
    finish: Table = {"albedo": log_uniform(rng, 0.03, 0.9)}
    u = rng.random()
    if u < 0.08:
        finish |= {"retro_gain": log_uniform(rng, 30.0, 1000.0),
                   "retro_lobe_deg": uniform(rng, 0.2, 3.0)}
    elif u < 0.18:
        finish |= {"specular": uniform(rng, 0.5, 0.98), "gloss_deg": uniform(rng, 1.0, 10.0)}
    return finish


def box(x: float, y: float, size: list[float], yaw: float, lift: float = 0.0) -> Table:
    return {"center_m": [x, y, lift + size[2] / 2], "size_m": size, "yaw_deg": yaw}


def draw_object(rng: np.random.Generator, kind: str, x: float, y: float) -> Drawn:
    """One object of ``kind`` centred over (x, y): its shape kind, table and footprint."""
    heading = math.degrees(math.atan2(y, x))
    u = partial(uniform, rng)
    if kind == "crate":
        size = [u(0.2, 1.0), u(0.2, 1.0), u(0.15, 1.2)]
        return "box", box(x, y, size, u(-90, 90)), math.hypot(*size[:2]) / 2
    if kind == "car":
        size = [u(3.6, 4.8), u(1.6, 1.9), u(1.3, 1.6)]
        yaw = pick(rng, [0.0, 90.0, u(-90, 90)])
        return "box", box(x, y, size, yaw), math.hypot(*size[:2]) / 2
    if kind == "kerb":
        size = [u(0.3, 2.5), u(0.5, 4.0), u(0.05, 0.45)]
        return "box", box(x, y, size, heading + u(-40, 40)), math.hypot(*size[:2]) / 2
    if kind == "plate":
        size = [u(0.5, 1.5), u(0.01, 0.04), u(0.3, 1.2)]
        return "box", box(x, y, size, heading + u(-15, 15)), size[0] / 2
    if kind == "sphere":
        radius = u(0.08, 0.5)
        lift = u(0.15, 1.3) if chance(rng, 0.5) else 0.0
        return "sphere", {"center_m": [x, y, radius + lift], "radius_m": radius}, radius
    if kind in ("pole", "person"):
        radius, height = ((u(0.015, 0.1), u(0.6, 3.0)) if kind == "pole"
                          else (u(0.18, 0.3), u(1.5, 1.95)))
        return "cylinder", {"center_m": [x, y, 0.0], "radius_m": radius,
                            "height_m": height}, radius
    length = u(1.0, 4.0)
    return "ramp", {"start_m": [x, y, 0.0], "length_m": length, "width_m": u(1.0, 4.0),
                    "slope_deg": u(3.0, 25.0), "yaw_deg": heading + u(-30, 30)}, length


def draw_backdrop(rng: np.random.Generator) -> tuple[list[tuple[str, Table]], float, float]:
    """A wall behind the scene or none: its shapes, its distance and turn (deg); inf if
    none. A wall may carry a retro-reflective or glossy sign."""
    style = pick(rng, ["none", "plane", "box"], [0.45, 0.3, 0.25])
    if style == "none":
        return [], math.inf, 0.0
    dist, turn = uniform(rng, 2.0, 12.0), uniform(rng, -35.0, 35.0)
    c, s = math.cos(math.radians(turn)), math.sin(math.radians(turn))
    if style == "plane":
        wall: Table = {"point_m": [dist * c, dist * s, 0.0], "normal": [-c, -s, 0.0]}
        shapes = [("plane", {"name": "wall", **wall, **draw_finish(rng)})]
    else:
        size = [uniform(rng, 0.1, 0.3), uniform(rng, 3.0, 12.0), uniform(rng, 1.0, 3.0)]
        wall = box((dist + size[0] / 2) * c, (dist + size[0] / 2) * s, size, turn)
        shapes = [("box", {"name": "wall", **wall, **draw_finish(rng)})]
    if chance(rng, 0.2):
        shapes.append(("box", draw_sign(rng, dist, turn)))
    return shapes, dist, turn


def draw_sign(rng: np.random.Generator, dist: float, turn: float) -> Table:
    """A thin panel on a wall's face, retro-reflective or glossy."""
    bearing = turn + uniform(rng, -20.0, 20.0)
    reach = dist / math.cos(math.radians(bearing - turn)) - 0.02
    x, y = reach * math.cos(math.radians(bearing)), reach * math.sin(math.radians(bearing))
    size = [0.02, uniform(rng, 0.3, 1.2), uniform(rng, 0.2, 0.8)]
    finish = ({"retro_gain": log_uniform(rng, 100.0, 1000.0),
               "retro_lobe_deg": uniform(rng, 0.2, 2.0)} if chance(rng, 0.6)
              else {"specular": uniform(rng, 0.8, 0.98), "gloss_deg": uniform(rng, 1.0, 5.0)})
    return {"name": "sign", **box(x, y, size, turn, uniform(rng, 0.1, 1.5)),
            "albedo": log_uniform(rng, 0.03, 0.9), **finish}


OBJECT_KINDS = ["crate", "car", "kerb", "sphere", "pole", "person", "plate", "ramp"]
OBJECT_WEIGHTS = [0.24, 0.1, 0.1, 0.15, 0.16, 0.1, 0.06, 0.09]


def draw_objects(rng: np.random.Generator, wall_m: float, turn: float) -> list[Drawn]:
    """0-6 objects 0.5-12 m ahead, mostly within the 70° sectors, nearer than the wall
    and not overlapping one another (footprint circles)."""
    out: list[Drawn] = []
    for _ in range(int(pick(rng, list(range(7)), [0.08, 0.2, 0.22, 0.2, 0.14, 0.1, 0.06]))):
        for _try in range(20):
            bearing = uniform(rng, -35.0, 35.0) if chance(rng, 0.85) else uniform(rng, -45, 45)
            limit = min(12.0, wall_m / math.cos(math.radians(bearing - turn)))
            reach = 0.5 + (limit - 0.5) * float(rng.random()) ** 1.5
            x, y = reach * math.cos(math.radians(bearing)), reach * math.sin(
                math.radians(bearing))
            what = pick(rng, OBJECT_KINDS, OBJECT_WEIGHTS)
            kind, table, radius = draw_object(rng, what, x, y)
            clear = all(math.dist((x, y), centre(t)) > radius + r for _, t, r in out)
            if reach - radius >= 0.4 and reach + radius < limit - 0.1 and clear:
                name = f"{what}{len(out)}"
                out.append((kind, {"name": name, **table, **draw_finish(rng)}, radius))
                break
    return out


def centre(table: Table) -> tuple[float, float]:
    x, y, _ = table.get("center_m", table.get("start_m"))
    return x, y


def add_motion(rng: np.random.Generator, table: Table, duration_s: float) -> None:
    """Make an object approach (along -x) or cross (along ±y) at 0.5-8 m/s, staying at
    least 0.8 m ahead of the unit over ``duration_s``."""
    key = "center_m"
    x, y, z = table[key]
    speed = min(uniform(rng, 0.5, 8.0), 6.0 / duration_s)
    if chance(rng, 0.5):
        accel = -uniform(rng, 2.0, 20.0) if chance(rng, 0.3) else 0.0
        travel = speed * duration_s - 0.5 * accel * duration_s**2
        table[key] = [max(x, 0.8 + travel + 0.5), y, z]
        table["velocity_mps"] = [-speed, 0.0, 0.0]
        if accel:
            table["acceleration_mps2"] = [accel, 0.0, 0.0]
    else:
        side = pick(rng, [-1.0, 1.0])
        table[key] = [x, y - side * speed * duration_s / 2, z]
        table["velocity_mps"] = [0.0, side * speed, 0.0]


def draw_z_max(rng: np.random.Generator, projector: Table, mounting: Table) -> float:
    """The range searched, m: mostly short of where the farthest sheet meets the ground
    (else no sector can be free, every ground-only sector is INVALID), else 3-12 m."""
    farthest = max(ground_reach(a, mounting["z_m"], projector["baseline_m"],
                                mounting["pitch_deg"]) for a in projector["alpha_deg"])
    if math.isfinite(farthest) and chance(rng, 0.7):
        return max(1.0, uniform(rng, 0.6, 0.95) * farthest)
    return uniform(rng, 3.0, 12.0)


def draw_miscalibration(rng: np.random.Generator, baseline: float) -> Table:
    """One or two small calibration errors, of the size a good calibration leaves."""
    options: list[tuple[str, Any]] = [
        ("baseline_scale", 1.0 + uniform(rng, -0.01, 0.01)),
        ("alpha_offset_deg", uniform(rng, -0.29, 0.29) * baseline),
        ("mounting_pitch_offset_deg", uniform(rng, -0.3, 0.3)),
        ("mounting_z_offset_m", uniform(rng, -0.02, 0.02)),
        ("focal_offset_px", uniform(rng, -3.0, 3.0)),
        ("cy_offset_px", uniform(rng, -2.0, 2.0))]
    chosen = rng.choice(len(options), size=int(rng.integers(1, 3)), replace=False)
    return dict(options[int(i)] for i in chosen)


def draw_interferer(rng: np.random.Generator) -> Table:
    """Another unit facing this one or beside it, continuous or strobing a code."""
    if chance(rng, 0.5):
        pose = {"x_m": uniform(rng, 2.0, 7.0), "y_m": uniform(rng, -2.0, 2.0),
                "z_m": uniform(rng, 0.4, 1.0), "yaw_deg": 180.0 + uniform(rng, -30.0, 30.0)}
    else:
        pose = {"x_m": uniform(rng, -0.5, 0.5), "y_m": uniform(rng, -1.5, 1.5),
                "z_m": uniform(rng, 0.3, 1.0), "yaw_deg": uniform(rng, -30.0, 30.0)}
    pose["pitch_deg"] = uniform(rng, -1.0, 5.0)
    table: Table = {"name": "other_unit", "pose": pose,
                    "alpha_deg": sorted(uniform(rng, 76.0, 95.0) for _ in range(4)),
                    "power_w": log_uniform(rng, 0.1, 1.0),
                    "baseline_m": uniform(rng, 0.05, 0.2)}
    if chance(rng, 0.7):
        length = int(pick(rng, [8, 16, 32]))
        table |= {"strobe": "code", "code_length": length,
                  "code_row": int(rng.integers(2, length + 1)),
                  "chip_rate_hz": uniform(rng, 200.0, 340.0),
                  "phase_sub_frames": uniform(rng, 0.0, 4.0),
                  "exposure_us": uniform(rng, 300.0, 2000.0)}
    return table


def draw_scene(rng: np.random.Generator) -> tuple[Table, str]:
    """A scene document (table name -> table or list of tables) and a one-line summary."""
    light = pick(rng, ["dark", "indoor", "outdoor"], [0.2, 0.45, 0.35])
    camera = draw_camera(rng, light == "outdoor")
    mounting = draw_mounting(rng)
    projector = draw_projector(rng, camera, mounting, light == "outdoor")
    code = draw_code(rng)
    doc: Table = {"scene": {}, "camera": camera, "projector": projector, "code": code,
                  "mounting": mounting, "ambient": draw_ambient(rng, light),
                  "ground": {"enabled": chance(rng, 0.92),
                             "albedo": uniform(rng, 0.05, 0.8)}}
    if chance(rng, 0.5):
        doc["scene"]["z_max_m"] = draw_z_max(rng, projector, mounting)
    if chance(rng, 0.12):
        doc["miscalibration"] = draw_miscalibration(rng, projector["baseline_m"])
    backdrop, wall_m, turn = draw_backdrop(rng)
    objects = draw_objects(rng, wall_m, turn)
    movable = [t for k, t, _ in objects if k != "ramp"]
    moving = ""
    if movable and chance(rng, 0.15):
        mover = pick(rng, movable)
        add_motion(rng, mover, MAPS_MOVING * code["length"] / camera["rate_hz"])
        moving = f", {mover['name']} moving"
    for kind, table in backdrop + [(k, t) for k, t, _ in objects]:
        doc.setdefault(kind, []).append(table)
    if chance(rng, 0.06):
        doc["interferer"] = [draw_interferer(rng)]
    doc["noise"] = {"enabled": True, "seed": int(rng.integers(1, 2**31))}
    names = ", ".join(t["name"] for _, t in backdrop + [(k, t) for k, t, _ in objects])
    summary = (f"{light}, sheets {len(projector['alpha_deg'])}, "
               f"{names or 'nothing but the ground'}{moving}")
    return doc, summary


def toml_value(value: Any) -> str:
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return repr(round(float(value), 4))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"


def toml_text(doc: Table, header: list[str]) -> str:
    lines = [f"# {line}" for line in header]
    for name, body in doc.items():
        for table in body if isinstance(body, list) else [body]:
            lines.append(f"\n[[{name}]]" if isinstance(body, list) else f"\n[{name}]")
            lines += [f"{k} = {toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def write_scene(out_dir: Path, seed: int) -> Path:
    """Draw scene ``seed`` until it loads; write it and return its path."""
    path = out_dir / f"s{seed}.toml"
    for sub in range(ATTEMPTS):
        rng = np.random.default_rng(seed if sub == 0 else [seed, sub])
        doc, summary = draw_scene(rng)
        how = f"numpy.random.default_rng({seed if sub == 0 else [seed, sub]})"
        doc["scene"] = {"description": f"drawn s{seed}: {summary}", **doc["scene"]}
        header = [f"Drawn at random by scripts/draw_scenes.py, seed {seed} (sub-seed {sub}:",
                  f"{how}). {summary}."]
        path.write_text(toml_text(doc, header), encoding="utf-8")
        try:
            load_scene(path)
        except ConfigError as exc:
            print(f"s{seed} sub-seed {sub} rejected: {exc}", file=sys.stderr)
            continue
        return path
    raise RuntimeError(f"seed {seed}: no loadable scene in {ATTEMPTS} draws")


def main(argv: list[str]) -> int:
    if len(argv) != 3:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    out_dir, first, count = Path(argv[0]), int(argv[1]), int(argv[2])
    out_dir.mkdir(parents=True, exist_ok=True)
    for seed in range(first, first + count):
        print(write_scene(out_dir, seed))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
