"""Calibration files: a small versioned TOML format, validated on load.

Two kinds share one layout. A *camera* file (written by ``atris calib intrinsics``) holds
the ``[camera]`` table; a *unit* file (written by ``atris calib laser``) holds ``[camera]``
and ``[laser]``. Every key carries its unit in its name (``_px``, ``_m``, ``_rad``) and is
checked for type and range, and the image size is compared with the camera's, so a
corrupt or foreign file stops the node at start instead of giving wrong distances::

    format = "atris-calibration"
    version = 1
    kind = "unit"

    [meta]
    created = "2026-11-22T05:00:00+00:00"
    method = "flat-target"

    [camera]
    width_px = 1280
    height_px = 800
    focal_px = 763.0
    cx_px = 640.0
    cy_px = 400.0
    distortion = [0.0, 0.0, 0.0, 0.0, 0.0]
    rms_px = 0.21

    [laser]
    baseline_m = 0.075
    baseline_sigma_m = 0.0001
    alpha_rad = [1.4, 1.5]
    alpha_sigma_rad = [0.0002, 0.0002]
"""

from __future__ import annotations

import logging
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from atris_node.calibration import Calibration, CameraModel, LaserCalibration
from atris_node.errors import CalibrationError

logger = logging.getLogger(__name__)

FORMAT = "atris-calibration"
VERSION = 1
SUPPORTED_VERSIONS = (1,)

Scalar = str | int | float | bool
MetaValue = Scalar | list[float] | list[list[float]]

#: accepted ranges, inclusive; a value outside is most likely a unit mistake
FOCAL_RANGE_PX = (20.0, 100_000.0)
BASELINE_RANGE_M = (0.002, 5.0)
MAX_DISTORTION_COEFFS = 14

_CAMERA_KEYS = {"width_px", "height_px", "focal_px", "cx_px", "cy_px", "distortion",
                "rms_px", "focal_sigma_px", "cx_sigma_px", "cy_sigma_px"}
_LASER_KEYS = {"baseline_m", "baseline_sigma_m", "alpha_rad", "alpha_sigma_rad",
               "residual_rms_px", "residual_rms_mm", "return_dn_m2", "return_exposure_us",
               "stripe_sigma_px"}


@dataclass(frozen=True)
class IntrinsicsSigma:
    """Standard deviations of the focal length and the principal point, pixels."""

    focal_px: float = 0.0
    cx_px: float = 0.0
    cy_px: float = 0.0


@dataclass(frozen=True)
class CameraFile:
    """What a camera file holds: the model, its RMS reprojection error (px), the standard
    deviations of f, cx, cy (px) and metadata."""

    camera: CameraModel
    rms_px: float
    sigma: IntrinsicsSigma = field(default_factory=IntrinsicsSigma)
    meta: dict[str, MetaValue] = field(default_factory=dict)
    board: dict[str, MetaValue] = field(default_factory=dict)


# ---------------------------------------------------------------- writing


def toml_value(value: object, where: str) -> str:
    """One TOML value: bool, int, finite float, str, or a (nested) list of those."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise CalibrationError(f"{where} must be a finite number, got {value}")
        return repr(value)
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
        return f'"{escaped}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v, where) for v in value) + "]"
    raise CalibrationError(f"{where}: cannot write a {type(value).__name__} to a TOML file")


def toml_table(name: str, table: Mapping[str, object]) -> str:
    lines = [f"[{name}]"] + [f"{k} = {toml_value(v, f'{name}.{k}')}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def _camera_table(camera: CameraModel, rms_px: float,
                  sigma: IntrinsicsSigma) -> dict[str, object]:
    return {"width_px": camera.width_px, "height_px": camera.height_px,
            "focal_px": float(camera.focal_px), "cx_px": float(camera.cx_px),
            "cy_px": float(camera.cy_px), "distortion": [float(d) for d in camera.distortion],
            "rms_px": float(rms_px), "focal_sigma_px": float(sigma.focal_px),
            "cx_sigma_px": float(sigma.cx_px), "cy_sigma_px": float(sigma.cy_px)}


def _laser_table(laser: LaserCalibration, meta: Mapping[str, object]) -> dict[str, object]:
    table: dict[str, object] = {
        "baseline_m": float(laser.baseline_m), "baseline_sigma_m": float(laser.baseline_sigma_m),
        "alpha_rad": [float(a) for a in laser.alpha_rad],
        "alpha_sigma_rad": [float(a) for a in laser.alpha_sigma_rad]}
    if laser.return_dn_m2 > 0.0:
        table["return_dn_m2"] = float(laser.return_dn_m2)
        table["return_exposure_us"] = float(laser.return_exposure_us)
    if laser.stripe_sigma_px > 0.0:
        table["stripe_sigma_px"] = float(laser.stripe_sigma_px)
    for key in ("residual_rms_px", "residual_rms_mm"):
        if key in meta:
            table[key] = float(meta[key])  # type: ignore[arg-type]
    return table


def _write(path: str | Path, kind: str, tables: Mapping[str, Mapping[str, object]]) -> Path:
    header = f'format = "{FORMAT}"\nversion = {VERSION}\nkind = "{kind}"\n'
    text = header + "".join("\n" + toml_table(n, t) for n, t in tables.items() if t)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    logger.info("wrote %s calibration file %s", kind, out)
    return out


def _with_date(meta: Mapping[str, object]) -> dict[str, object]:
    stamped: dict[str, object] = {"created": datetime.now(UTC).isoformat(timespec="seconds")}
    stamped.update({k: v for k, v in meta.items() if not k.startswith("residual_rms_")})
    return stamped


def save_camera_file(path: str | Path, camera: CameraModel, rms_px: float,
                     board: Mapping[str, object], meta: Mapping[str, object], *,
                     sigma: IntrinsicsSigma | None = None) -> Path:
    """Write a camera file (intrinsics with their standard deviations, RMS reprojection
    error in px, board, date)."""
    tables = {"meta": _with_date(meta), "board": dict(board),
              "camera": _camera_table(camera, rms_px, sigma or IntrinsicsSigma())}
    return _write(path, "camera", tables)


def save_calibration(path: str | Path, calibration: Calibration,
                     meta: Mapping[str, object], *, sigma: IntrinsicsSigma | None = None
                     ) -> Path:
    """Write a unit calibration file; ``meta`` may carry ``rms_px`` (intrinsics) and the
    laser fit's ``residual_rms_px`` / ``residual_rms_mm``, stored beside the values;
    ``sigma`` are the intrinsics' standard deviations."""
    rms_px = float(meta.get("rms_px", 0.0))  # type: ignore[arg-type]
    other = {k: v for k, v in meta.items() if k != "rms_px"}
    camera = _camera_table(calibration.camera, rms_px, sigma or IntrinsicsSigma())
    tables = {"meta": _with_date(other), "camera": camera,
              "laser": _laser_table(calibration.laser, meta)}
    return _write(path, "unit", tables)


# ---------------------------------------------------------------- reading


def _read_document(path: str | Path) -> dict[str, object]:
    source = Path(path)
    try:
        doc = tomllib.loads(source.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise CalibrationError(f"calibration file {source} does not exist") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"calibration file {source} is not valid TOML: {exc}") from exc
    if doc.get("format") != FORMAT:
        raise CalibrationError(
            f"{source}: format must be {FORMAT!r}, got {doc.get('format')!r}")
    if doc.get("version") not in SUPPORTED_VERSIONS:
        raise CalibrationError(f"{source}: version {doc.get('version')!r} is not supported; "
                               f"accepted: {SUPPORTED_VERSIONS}")
    return doc


def _table(doc: Mapping[str, object], name: str, keys: set[str], where: Path) -> dict[str, object]:
    table = doc.get(name)
    if not isinstance(table, dict):
        raise CalibrationError(f"{where}: the [{name}] table is missing")
    unknown = sorted(set(table) - keys)
    if unknown:
        raise CalibrationError(f"{where}: unknown keys in [{name}]: {unknown}; "
                               f"accepted: {sorted(keys)}")
    return table


def _number(table: Mapping[str, object], key: str, where: str,
            bounds: tuple[float, float] = (-math.inf, math.inf), *,
            default: float | None = None) -> float:
    low, high = bounds
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CalibrationError(f"{where}.{key} must be a number, got {value!r}")
    if not (math.isfinite(value) and low <= value <= high):
        raise CalibrationError(f"{where}.{key} = {value} is outside the accepted range "
                               f"[{low}, {high}]")
    return float(value)


def _integer(table: Mapping[str, object], key: str, where: str) -> int:
    value = table.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise CalibrationError(f"{where}.{key} must be a positive integer, got {value!r}")
    return value


def _numbers(table: Mapping[str, object], key: str, where: str,
             bounds: tuple[float, float], *, default: list[float] | None = None) -> list[float]:
    values = table.get(key, default)
    if not isinstance(values, list):
        raise CalibrationError(f"{where}.{key} must be a list of numbers, got {values!r}")
    return [_number({key: v}, key, where, bounds) for v in values]


def _parse_sigma(table: Mapping[str, object], where: str) -> IntrinsicsSigma:
    return IntrinsicsSigma(*(_number(table, f"{name}_sigma_px", where, (0.0, 1000.0),
                                     default=0.0) for name in ("focal", "cx", "cy")))


def _parse_camera(table: Mapping[str, object], where: str) -> tuple[CameraModel, float]:
    width, height = _integer(table, "width_px", where), _integer(table, "height_px", where)
    distortion = _numbers(table, "distortion", where, (-1000.0, 1000.0), default=[])
    if len(distortion) > MAX_DISTORTION_COEFFS:
        raise CalibrationError(f"{where}.distortion has {len(distortion)} coefficients; "
                               f"accepted: at most {MAX_DISTORTION_COEFFS}")
    camera = CameraModel(
        width_px=width, height_px=height,
        focal_px=_number(table, "focal_px", where, FOCAL_RANGE_PX),
        cx_px=_number(table, "cx_px", where, (0.0, float(width))),
        cy_px=_number(table, "cy_px", where, (0.0, float(height))),
        distortion=tuple(distortion))
    return camera, _number(table, "rms_px", where, (0.0, 100.0), default=0.0)


def _parse_laser(table: Mapping[str, object], where: str) -> LaserCalibration:
    alpha = _numbers(table, "alpha_rad", where, (1e-9, math.pi - 1e-9))
    sigma = _numbers(table, "alpha_sigma_rad", where, (0.0, 1.0), default=[])
    if not alpha:
        raise CalibrationError(f"{where}.alpha_rad must list at least one line angle")
    if sigma and len(sigma) != len(alpha):
        raise CalibrationError(f"{where}.alpha_sigma_rad has {len(sigma)} entries; "
                               f"accepted: one per line ({len(alpha)})")
    return LaserCalibration(
        baseline_m=_number(table, "baseline_m", where, BASELINE_RANGE_M),
        baseline_sigma_m=_number(table, "baseline_sigma_m", where, (0.0, 1.0), default=0.0),
        alpha_rad=tuple(alpha), alpha_sigma_rad=tuple(sigma),
        return_dn_m2=_number(table, "return_dn_m2", where, (0.0, 1e12), default=0.0),
        return_exposure_us=_number(table, "return_exposure_us", where, (0.0, 1e7),
                                   default=0.0),
        stripe_sigma_px=_number(table, "stripe_sigma_px", where, (0.0, 100.0), default=0.0))


def _check_size(camera: CameraModel, expected_size: tuple[int, int] | None, where: Path) -> None:
    if expected_size is None:
        return
    if (camera.width_px, camera.height_px) != tuple(expected_size):
        raise CalibrationError(
            f"{where} was made for {camera.width_px}x{camera.height_px} images but the "
            f"camera delivers {expected_size[0]}x{expected_size[1]}; recalibrate at this "
            "resolution or set the camera to the calibrated one")


def _meta(doc: Mapping[str, object], name: str) -> dict[str, MetaValue]:
    table = doc.get(name, {})
    return dict(table) if isinstance(table, dict) else {}


def load_calibration(path: str | Path, expected_size: tuple[int, int] | None = None
                     ) -> Calibration:
    """Read and validate a unit calibration file.

    ``expected_size`` is the camera's (width, height) in pixels; a file made for another
    resolution is rejected. Raises :class:`CalibrationError` for anything invalid.
    """
    where = Path(path)
    doc = _read_document(where)
    if doc.get("kind") != "unit":
        raise CalibrationError(f"{where} is a {doc.get('kind')!r} file; a unit calibration "
                               "(kind = \"unit\", with [camera] and [laser]) is needed")
    camera, _ = _parse_camera(_table(doc, "camera", _CAMERA_KEYS, where), f"{where}: camera")
    laser = _parse_laser(_table(doc, "laser", _LASER_KEYS, where), f"{where}: laser")
    _check_size(camera, expected_size, where)
    return Calibration(camera=camera, laser=laser)


def load_camera_file(path: str | Path, expected_size: tuple[int, int] | None = None
                     ) -> CameraFile:
    """Read and validate the ``[camera]`` table of a camera or unit file."""
    where = Path(path)
    doc = _read_document(where)
    if doc.get("kind") not in ("camera", "unit"):
        raise CalibrationError(f"{where}: kind must be 'camera' or 'unit', "
                               f"got {doc.get('kind')!r}")
    table = _table(doc, "camera", _CAMERA_KEYS, where)
    camera, rms_px = _parse_camera(table, f"{where}: camera")
    _check_size(camera, expected_size, where)
    return CameraFile(camera=camera, rms_px=rms_px,
                      sigma=_parse_sigma(table, f"{where}: camera"), meta=_meta(doc, "meta"),
                      board=_meta(doc, "board"))


def save_updated_calibration(source: str | Path, out: str | Path,
                             calibration: Calibration) -> Path:
    """Write ``calibration`` to ``out`` with the meta data, intrinsics σ and laser fit
    residuals of the unit file ``source`` (a later step, such as the radiometric
    calibration, adds its values and keeps what the earlier steps measured)."""
    kept = load_camera_file(source)
    laser_table = _read_document(Path(source)).get("laser", {})
    meta: dict[str, object] = {**kept.meta, "rms_px": kept.rms_px}
    if isinstance(laser_table, dict):
        meta.update({k: laser_table[k] for k in ("residual_rms_px", "residual_rms_mm")
                     if k in laser_table})
    return save_calibration(out, calibration, meta, sigma=kept.sigma)
