"""Launch files: several units described as data, run as threads or as processes.

A launch file is TOML::

    [launch]
    name = "sim_fleet"
    duration_s = 20.0          # default run time (``--duration`` overrides)
    mode = "threads"           # threads: units share one in-process bus; processes: one
                               # ``atris run`` process per unit on a real bus
    respawn = false            # processes only: restart a unit that exits
    max_respawns = 3

    [bus]                      # shared by all units (python-can terms)
    interface = "virtual"
    channel = "fleet"

    [defaults]                 # parameters every unit starts from (config sections)
    driver = { scene = "fleet" }

    [[unit]]                   # one table per unit; same sections as a config file
    unit = { label = "left", unit_id = 0, name = 0x100 }

Later sources win: unit defaults < ``[defaults]`` < ``[bus]`` < ``[[unit]]`` < environment.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from atris_node import config as cfg
from atris_node.errors import ConfigError

LAUNCH_KEYS = {"name", "duration_s", "mode", "respawn", "max_respawns", "description"}
TOP_KEYS = {"launch", "bus", "defaults", "unit", "world"}


@dataclass(frozen=True)
class LaunchSpec:
    """A parsed, validated launch file."""

    name: str
    path: Path
    duration_s: float
    mode: str
    respawn: bool
    max_respawns: int
    units: tuple[cfg.Config, ...]
    world: dict[str, Any] = field(default_factory=dict)
    description: str = ""


def _read(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except OSError as exc:
        raise ConfigError(f"cannot read launch file {path}: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"launch file {path} is not valid TOML: {exc}") from exc


def _check_keys(table: dict[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; "
                          f"accepted: {', '.join(sorted(allowed))}")


def _check_tables(data: dict[str, Any], where: str) -> None:
    for name in ("launch", "bus", "defaults", "world"):
        if not isinstance(data.get(name, {}), dict):
            raise ConfigError(f"{where}: [{name}] must be a table, got {data[name]!r}")
    units = data.get("unit", [])
    if not isinstance(units, list) or not units or not all(isinstance(u, dict) for u in units):
        raise ConfigError(f"{where}: needs at least one [[unit]] table")


def _number(table: dict[str, Any], key: str, kind: type, default: Any, where: str) -> Any:
    value = table.get(key, default)
    accepted = int if kind is int else int | float
    if isinstance(value, bool) or not isinstance(value, accepted) or not math.isfinite(value):
        raise ConfigError(f"{where} [launch] {key}: must be a finite {kind.__name__}, "
                          f"got {value!r}")
    return kind(value)


def _unit_config(defaults: dict[str, Any], bus: dict[str, Any], unit: dict[str, Any],
                 where: str) -> cfg.Config:
    merged = cfg.defaults()
    merged = merged.with_values(cfg.flatten(defaults), f"{where} [defaults]")
    merged = merged.with_values(cfg.flatten({"bus": bus}), f"{where} [bus]")
    merged = merged.with_values(cfg.flatten(unit), f"{where} [[unit]]")
    env = cfg.from_environment(os.environ)
    return merged.with_values(env, "environment", from_text=True) if env else merged


def _check_units(units: list[cfg.Config], where: str) -> None:
    ids = [u["unit.unit_id"] for u in units]
    if len(set(ids)) != len(ids):
        raise ConfigError(f"{where}: two units share a unit_id ({ids}); each needs its own "
                          "CAN ID block")
    labels = [u["unit.label"] for u in units]
    if len(set(labels)) != len(labels):
        raise ConfigError(f"{where}: unit labels must be unique, got {labels}")


def load_launch(path: str | Path) -> LaunchSpec:
    """Parse and validate a launch file (a path, or the name of a shipped one)."""
    resolved = resolve_launch_path(path)
    data = _read(resolved)
    where = f"launch file {resolved.name}"
    _check_keys(data, TOP_KEYS, where)
    _check_tables(data, where)
    launch = data.get("launch", {})
    _check_keys(launch, LAUNCH_KEYS, f"{where} [launch]")
    units_raw = data["unit"]
    units = [_unit_config(data.get("defaults", {}), data.get("bus", {}), u, where)
             for u in units_raw]
    _check_units(units, where)
    mode = launch.get("mode", "threads")
    if mode not in ("threads", "processes"):
        raise ConfigError(f"{where} [launch] mode: must be threads or processes, got {mode!r}")
    duration = _number(launch, "duration_s", float, 10.0, where)
    if not 0.0 < duration <= 86400.0:
        raise ConfigError(f"{where} [launch] duration_s: must be in (0, 86400], got {duration}")
    return LaunchSpec(
        name=str(launch.get("name", resolved.stem)), path=resolved, duration_s=duration,
        mode=mode, respawn=bool(launch.get("respawn", False)),
        max_respawns=_number(launch, "max_respawns", int, 3, where), units=tuple(units),
        world=dict(data.get("world", {})), description=str(launch.get("description", "")),
    )


def launch_dir() -> Path:
    """The shipped ``launch/`` folder (beside the package in a source checkout)."""
    return Path(__file__).resolve().parents[2] / "launch"


def resolve_launch_path(path: str | Path) -> Path:
    """A path as given, or ``launch/NAME.toml`` for a bare shipped name."""
    candidate = Path(path)
    if candidate.exists():
        return candidate
    shipped = launch_dir() / f"{path}.toml"
    if shipped.exists():
        return shipped
    names = sorted(p.stem for p in launch_dir().glob("*.toml"))
    raise ConfigError(f"launch file {path!r} not found; shipped: {', '.join(names)}")


def describe(spec: LaunchSpec) -> list[str]:
    """Lines that say what ``spec`` would start (``atris launch --print``)."""
    lines = [f"launch {spec.name} ({spec.path.name}): {len(spec.units)} unit(s) as "
             f"{spec.mode}, {spec.duration_s:g} s, respawn={spec.respawn}"]
    for unit in spec.units:
        changed = [f"{k}={v!r}" for k, v, s in unit.describe() if s != "default"]
        lines.append(f"  unit {unit['unit.label']}: " + ", ".join(changed))
    return lines
