"""Typed, validated parameters and where each value came from.

Parameters are declared once, before use, with a type, a default, a check and a help text
(as rclpy declares node parameters). Sources are layered, later ones win:

    defaults < TOML file < ATRIS_* environment < command line (``--set key=value``)

Values are converted by their declared type, never inferred from text: a ``str``
parameter given as ``"0483"`` stays ``"0483"``. An unknown key is rejected by name.
Nothing is read implicitly from ``$HOME``.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from atris_node.errors import ConfigError

ENV_PREFIX = "ATRIS_"
#: where a unit measures its maps (``pipeline.worker``; docs/node.md "The map thread")
WORKERS = ("thread", "process", "inline")
Check = Callable[[Any], str | None]


def in_range(lo: float, hi: float) -> Check:
    """A check that accepts numbers in ``[lo, hi]``."""
    return lambda v: None if lo <= v <= hi else f"must be in [{lo}, {hi}]"


def one_of(*choices: str) -> Check:
    """A check that accepts one of ``choices``."""
    return lambda v: None if v in choices else f"must be one of {', '.join(choices)}"


def power_of_two(lo: int, hi: int) -> Check:
    """A check for powers of two in ``[lo, hi]`` (code lengths)."""
    return lambda v: None if lo <= v <= hi and v & (v - 1) == 0 else (
        f"must be a power of two in [{lo}, {hi}]")


def _no_check(_: Any) -> None:
    return None


@dataclass(frozen=True)
class Param:
    """One declared parameter: dotted ``key``, Python ``kind``, default, check and help."""

    key: str
    kind: type
    default: Any
    help: str
    check: Check = _no_check


P = Param
#: every parameter of a unit. Units: _m metres, _s seconds, _hz hertz, _us microseconds.
PARAMS: tuple[Param, ...] = (
    P("unit.name", int, 0, "64-bit NAME for code negotiation; 0 = derived from unit_id",
      in_range(0, 2**64 - 1)),
    P("unit.name_file", str, "", "file that keeps a random NAME across restarts (empty = "
      "none)"),
    P("unit.unit_id", int, 0, "CAN ID block bus.base_id + 4 * unit_id", in_range(0, 15)),
    P("unit.label", str, "front", "human-readable unit name"),
    P("driver.name", str, "sim", "camera/projector backend", one_of("sim", "depthai", "replay")),
    P("driver.scene", str, "indoor_lab", "simulator scene: shipped name or TOML path"),
    P("driver.path", str, "", "recording directory for the replay backend"),
    P("driver.loop", bool, False, "replay: start again at the end of the recording"),
    P("driver.seed", int, 1, "simulator noise seed", in_range(0, 2**32 - 1)),
    P("driver.unit", int, 0, "simulator: which of the scene's unit mountings this unit uses",
      in_range(0, 15)),
    P("driver.rate_hz", float, 0.0, "simulator sub-frame rate, Hz; 0 = the scene's",
      in_range(0.0, 10000.0)),
    P("driver.lag_sub_frames", int, 0, "strobe lag the backend adds (sim)", in_range(0, 8)),
    P("driver.realtime", bool, False, "pace the simulator at the sub-frame rate"),
    P("driver.projector_state_file", str, "", "publish the projector's watchdog lease here "
      "(empty = off)"),
    P("driver.projector_lease_s", float, 0.05, "watchdog: the laser goes dark this long after "
      "the last strobe command, s", in_range(0.001, 1.0)),
    P("driver.strobe_margin_s", float, 0.05, "the projector goes dark when no strobe came "
      "for one sub-frame period plus this margin, s", in_range(0.001, 1.0)),
    P("code.length", int, 16, "code length N (sub-frames per period)", power_of_two(4, 128)),
    P("code.max_length", int, 128, "longest N this unit accepts or grows the plan to",
      power_of_two(4, 128)),
    P("code.mode", str, "async", "cyclic orthogonal set: async (log2 N) or sync (N-1)",
      one_of("async", "sync")),
    P("code.demod", str, "block", "block (rate/N) or sliding (rate) demodulation",
      one_of("block", "sliding")),
    P("pipeline.peak_method", str, "gaussian", "sub-pixel peak method",
      one_of("cog", "parabolic", "gaussian", "blais_rioux", "steger")),
    P("pipeline.snr_min", float, 6.0, "minimum peak SNR", in_range(1.0, 1e6)),
    P("pipeline.z_min_m", float, 0.3, "nearest range searched, m", in_range(0.05, 100.0)),
    P("pipeline.z_max_m", float, 10.0, "farthest range searched, m", in_range(0.1, 200.0)),
    P("pipeline.roi_bands", bool, True, "search each line only inside its row band"),
    P("pipeline.roi_narrowing", bool, False, "search each line only near its recent rows "
      "(identical results; a pixel elsewhere above threshold forces a full search)"),
    P("pipeline.identity", str, "aligned", "line identity: greedy matchings, or also the "
      "cheapest alignment per column (fewer shifted lines, ~0.3 ms more at 640x400)",
      one_of("greedy", "aligned")),
    P("pipeline.roi_full_every", int, 16, "maps between whole-band searches while "
      "narrowing", in_range(1, 10000)),
    P("pipeline.sector_count", int, 8, "number of sectors", in_range(1, 16)),
    P("pipeline.fov_deg", float, 70.0, "horizontal field of view of the sectors, deg",
      in_range(1.0, 360.0)),
    P("pipeline.min_points", int, 5, "points a sector needs to be valid", in_range(1, 10000)),
    P("pipeline.invalid_on_interference", bool, False, "foreign light anywhere makes every "
      "sector invalid (false: only the affected columns are left out)"),
    P("pipeline.min_reflectance", float, 0.002, "apparent reflectance (albedo x cos "
      "incidence) under which a return is too faint for the range its line gives, and is a "
      "doubt, not a point (0 = off; needs the calibration's return_dn_m2)", in_range(0.0, 0.5)),
    P("pipeline.tied_reflectance", float, 0.007, "the same for a return whose line "
      "continuity chose over farther rivals the physics could not rule out (at most "
      "min_reflectance: no stricter check)", in_range(0.0, 0.5)),
    P("interference.every_windows", int, 8, "measure other codes' energy on one window of N "
      "sub-frames out of this many (0 = never; hopping needs it)", in_range(0, 10000)),
    P("pipeline.worker", str, "thread", "where maps are measured: thread (a map thread "
      "beside the camera loop; a map that finds it busy replaces the waiting one), process "
      "(the pipeline pass in a child process, fed through shared memory) or inline (in the "
      "loop, serially)", one_of(*WORKERS)),
    P("pipeline.objects", bool, False, "cluster points into objects (open3d DBSCAN)"),
    P("bus.interface", str, "virtual", "python-can interface"),
    P("bus.channel", str, "atris", "python-can channel"),
    P("bus.bitrate", int, 500000, "bit rate, bit/s", in_range(10000, 8000000)),
    P("bus.fd", bool, False, "CAN FD frames"),
    P("bus.base_id", int, 0x680, "first unit frame ID (16 units x 4 IDs, so 0..0x7C0); "
      "outside the CANopen predefined connection set unless bus.allow_canopen_ids",
      in_range(0, 0x7C0)),
    P("bus.allow_canopen_ids", bool, False, "allow a bus.base_id inside the CANopen "
      "predefined connection set (a bus without CANopen devices)"),
    P("bus.protocol", str, "atris", "atris frames (DBC) or canopen", one_of("atris", "canopen")),
    P("bus.node_id", int, 0x20, "CANopen node id", in_range(1, 127)),
    P("publish.period_s", float, 0.05, "cycle period, s", in_range(0.01, 1.0)),
    P("publish.max_age_s", float, 0.25, "older data is sent as invalid, s", in_range(0.01, 5.0)),
    P("negotiation.window_s", float, 0.25, "contest window before strobing, s",
      in_range(0.05, 5.0)),
    P("negotiation.reannounce_s", float, 1.0, "periodic re-announce, s", in_range(0.1, 60.0)),
    P("negotiation.silence_timeout_s", float, 3.0, "a silent owner frees its code after, s",
      in_range(0.2, 600.0)),
    P("mounting.source", str, "driver", "mounting pose: from the driver (simulator scene) or "
      "from the mounting.* parameters", one_of("driver", "config")),
    P("mounting.x_m", float, 0.0, "camera position forward of the reference, m",
      in_range(-50.0, 50.0)),
    P("mounting.y_m", float, 0.0, "camera position left of the reference, m",
      in_range(-50.0, 50.0)),
    P("mounting.z_m", float, 0.5, "camera height above the ground, m", in_range(-5.0, 10.0)),
    P("mounting.roll_deg", float, 0.0, "camera roll, deg", in_range(-180.0, 180.0)),
    P("mounting.pitch_deg", float, 0.0, "camera pitch, positive nose down, deg",
      in_range(-89.0, 89.0)),
    P("mounting.yaw_deg", float, 0.0, "camera yaw, positive to the left, deg",
      in_range(-180.0, 180.0)),
    P("calibration.file", str, "", "calibration file; empty = the simulator's truth"),
    P("adaptive.enabled", bool, False, "adapt code length and exposure to the scene"),
    P("adaptive.snr_target", float, 8.0, "line SNR wanted ...", in_range(1.5, 1e4)),
    P("adaptive.column_share", float, 0.2, "... on this share of line-column places",
      in_range(0.01, 1.0)),
    P("adaptive.min_length", int, 4, "shortest N adaptation asks for", power_of_two(4, 128)),
    P("adaptive.max_length", int, 32, "longest N adaptation asks for (and code.max_length)",
      power_of_two(4, 128)),
    P("adaptive.grow_frames", int, 2, "output frames below target before N doubles",
      in_range(1, 1000)),
    P("adaptive.shrink_frames", int, 4, "output frames with margin before N shrinks",
      in_range(1, 1000)),
    P("adaptive.hysteresis", float, 0.25, "extra share needed to shorten N (fraction)",
      in_range(0.0, 10.0)),
    P("adaptive.noise_exponent", float, 0.5, "delta grows as N**this (0 = paper Eq. 6)",
      in_range(0.0, 0.95)),
    P("adaptive.exposure", bool, True, "adapt the exposure (when adaptive.enabled)"),
    P("adaptive.exposure_min_us", float, 10.0, "shortest exposure, us", in_range(1.0, 1e5)),
    P("adaptive.exposure_max_us", float, 4000.0, "longest exposure, us (and 95 % of a "
      "sub-frame period)", in_range(1.0, 1e5)),
    P("adaptive.low_signal_ratio", float, 1.0, "LOW_SIGNAL when laser l <= this * delta",
      in_range(0.0, 100.0)),
    P("adaptive.low_signal_clear_frames", int, 2, "after LOW_SIGNAL, frames above the limit "
      "in a row before distances are published again", in_range(1, 1000)),
    P("adaptive.max_range_sigma_m", float, 0.15, "N never shrinks to a length whose "
      "predicted range sigma at adaptive.sigma_range_m exceeds this, m", in_range(0.001, 10.0)),
    P("adaptive.sigma_range_m", float, 5.0, "the range that matters for "
      "adaptive.max_range_sigma_m, m", in_range(0.1, 200.0)),
)
PARAM_BY_KEY: dict[str, Param] = {p.key: p for p in PARAMS}
#: keys no longer accepted, and what to set instead
REPLACED = {"pipeline.thread": "pipeline.worker (thread, process or inline; "
                               "pipeline.thread = false is pipeline.worker = \"inline\")"}


def _parse_bool(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise ValueError("expected true/false, yes/no, on/off or 1/0")


def convert(param: Param, value: Any, source: str, from_text: bool = False) -> Any:
    """Convert ``value`` to ``param.kind`` and check it; raise ConfigError naming the key.

    Text is parsed by the declared type only when ``from_text`` (environment, command
    line); a TOML value must already have the right type.
    """
    try:
        typed = _convert_kind(param.kind, value, from_text)
    except (TypeError, ValueError) as exc:
        raise ConfigError(
            f"{source}: {param.key}: expected {param.kind.__name__}, got {value!r} ({exc})"
        ) from exc
    problem = param.check(typed)
    if problem:
        raise ConfigError(f"{source}: {param.key}: {problem}, got {typed!r}")
    return typed


def _convert_kind(kind: type, value: Any, from_text: bool) -> Any:
    if from_text and isinstance(value, str) and kind is not str:
        if kind is bool:
            return _parse_bool(value)
        return int(value, 0) if kind is int else float(value)
    if kind is bool and not isinstance(value, bool):
        raise TypeError("not a boolean")
    if kind is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise TypeError("not an integer")
    if kind is float and (isinstance(value, bool) or not isinstance(value, int | float)):
        raise TypeError("not a number")
    if kind is str and not isinstance(value, str):
        raise TypeError("not a string")
    return kind(value)


def flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Flatten nested TOML tables into dotted keys."""
    flat: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, dotted + "."))
        else:
            flat[dotted] = value
    return flat


@dataclass(frozen=True)
class Config:
    """Effective parameter values and, per key, the source that set it."""

    values: Mapping[str, Any]
    sources: Mapping[str, str]

    def __getitem__(self, key: str) -> Any:
        if key not in self.values:
            raise ConfigError(f"unknown parameter {key!r}")
        return self.values[key]

    def section(self, name: str) -> dict[str, Any]:
        """The values of one section, without the section prefix."""
        prefix = name + "."
        return {k[len(prefix):]: v for k, v in self.values.items() if k.startswith(prefix)}

    def with_values(self, updates: Mapping[str, Any], source: str,
                    from_text: bool = False) -> Config:
        """A new Config with ``updates`` applied (checked) as coming from ``source``."""
        values, sources = dict(self.values), dict(self.sources)
        for key, value in updates.items():
            if key in REPLACED:
                raise ConfigError(f"{source}: {key} was replaced by {REPLACED[key]}")
            if key not in PARAM_BY_KEY:
                raise ConfigError(f"{source}: unknown parameter {key!r}; accepted: "
                                  f"{', '.join(sorted(PARAM_BY_KEY))}")
            values[key] = convert(PARAM_BY_KEY[key], value, source, from_text)
            sources[key] = source
        _check_cross(values, source)
        return Config(values, sources)

    def describe(self) -> list[tuple[str, Any, str]]:
        """(key, value, source) for every parameter, in declaration order."""
        return [(p.key, self.values[p.key], self.sources[p.key]) for p in PARAMS]


def _check_cross(values: Mapping[str, Any], source: str) -> None:
    if values["pipeline.z_min_m"] >= values["pipeline.z_max_m"]:
        raise ConfigError(f"{source}: pipeline.z_min_m ({values['pipeline.z_min_m']}) must be "
                          f"below pipeline.z_max_m ({values['pipeline.z_max_m']})")


def defaults() -> Config:
    """The declared defaults."""
    return Config({p.key: p.default for p in PARAMS}, {p.key: "default" for p in PARAMS})


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file into dotted keys; a missing or broken file is a ConfigError."""
    try:
        with open(path, "rb") as handle:
            return flatten(tomllib.load(handle))
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {path} is not valid TOML: {exc}") from exc


def from_environment(environ: Mapping[str, str]) -> dict[str, str]:
    """``ATRIS_CODE__LENGTH=32`` -> ``{"code.length": "32"}`` (``__`` separates sections)."""
    found = {}
    for name, value in environ.items():
        if name.startswith(ENV_PREFIX) and "__" in name:
            key = name[len(ENV_PREFIX):].lower().replace("__", ".")
            found[key] = value
    return found


def parse_assignments(items: Iterable[str]) -> dict[str, str]:
    """``["code.length=32"]`` -> ``{"code.length": "32"}``."""
    parsed = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects key=value, got {item!r}")
        parsed[key.strip()] = value.strip()
    return parsed


def load(
    file: str | Path | None = None,
    environ: Mapping[str, str] | None = None,
    overrides: Iterable[str] = (),
    table: Mapping[str, Any] | None = None,
) -> Config:
    """Build the effective configuration from all sources, later ones winning.

    ``table`` is an already-parsed mapping (a launch file's unit table) that sits between
    the file and the environment.
    """
    config = defaults()
    if file:
        config = config.with_values(read_toml(file), f"file {file}")
    if table:
        config = config.with_values(flatten(table), "launch file")
    env = from_environment(os.environ if environ is None else environ)
    if env:
        config = config.with_values(env, "environment", from_text=True)
    sets = parse_assignments(overrides)
    if sets:
        config = config.with_values(sets, "command line", from_text=True)
    return config
