"""Fuzzing the file and text loaders: config (TOML file, environment, --set), launch files,
scene files and calibration files. Every input gives a valid result or an AtrisError with
a message, never another exception.

Documents are valid shipped files with one to three mutations (a value replaced by one of
another type or out of range, NaN and inf included; a key deleted; an unknown key added),
written back to TOML; plus raw text that is mostly not TOML at all. The number of examples
tried per target is printed at the end of the module (``pytest -s``).
"""

from __future__ import annotations

import copy
import math
import tempfile
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from atris_node import config as cfg
from atris_node.calibration import Calibration, CameraModel, LaserCalibration
from atris_node.node.launch import load_launch
from atris_node.sim.scene import load_scene, parse_scene
from atris_node.testing.fuzz import FuzzTally
from atris_node.testing.tomldoc import dumps
from calib.files import load_calibration, save_calibration

REPO = Path(__file__).resolve().parent.parent
TALLY = FuzzTally()
settle = TALLY.settle
FUZZ = settings(max_examples=300, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
WORK = Path(tempfile.mkdtemp(prefix="atris-fuzz-"))

scalars = st.one_of(
    st.integers(-(2**70), 2**70), st.sampled_from([0, 1, -1, 2**63, 2**64]),
    st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
    st.text(max_size=12), st.sampled_from(["", "sim", "async", "0x10", "nan", "1e999"]))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8)
assignment_text = st.one_of(
    st.text(max_size=30),
    st.builds(lambda k, v: f"{k}={v}",
              st.sampled_from([p.key for p in cfg.PARAMS] + ["nope", "code", ""]),
              st.one_of(st.text(max_size=12), st.integers().map(str),
                        st.floats().map(str), st.sampled_from(["true", "no", "0x1F", "1e3"]))))


@pytest.fixture(scope="module", autouse=True)
def report_counts() -> Iterator[None]:
    yield
    print("\n" + TALLY.report())


def _paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path in a parsed TOML document (into tables and lists)."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(
        doc, list) else ()
    found = []
    for k, v in items:
        found.append((*prefix, k))
        found += _paths(v, (*prefix, k))
    return found


@st.composite
def mutated(draw: st.DrawFn, base: dict[str, Any]) -> dict[str, Any]:
    """``base`` with one to three mutations."""
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        if not paths:
            break
        *parent_path, last = draw(st.sampled_from(paths))
        parent = doc
        for k in parent_path:
            parent = parent[k]
        action = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if action == "delete" and isinstance(parent, dict):
            del parent[last]
        elif action == "add" and isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=8))] = draw(values)
        else:
            parent[last] = draw(values)
    return doc


def write(name: str, text: str) -> Path:
    path = WORK / name
    path.write_text(text, encoding="utf-8")
    return path


def base_doc(path: Path) -> dict[str, Any]:
    with open(path, "rb") as handle:
        return tomllib.load(handle)


def unit_calibration_doc() -> dict[str, Any]:
    calibration = Calibration(CameraModel(640, 400, 381.0, 320.0, 200.0, (0.01, -0.02)),
                              LaserCalibration(0.075, (1.33, 1.38, 1.43), 0.001,
                                               (1e-4, 1e-4, 1e-4)))
    path = save_calibration(WORK / "valid-unit.toml", calibration, {"rms_px": 0.2})
    return base_doc(path)


CONFIG_BASE = {"unit": {"label": "front", "unit_id": 3, "name": 0x10},
               "code": {"length": 16, "mode": "async", "demod": "sliding"},
               "publish": {"period_s": 0.05, "max_age_s": 0.2},
               "driver": {"name": "sim", "scene": "indoor_lab", "rate_hz": 120.0}}
LAUNCH_BASE = base_doc(REPO / "launch" / "sim_soak.toml")
SCENE_BASES = [base_doc(REPO / "launch" / "scenes" / f"{n}.toml")
               for n in ("indoor_lab", "fleet", "window_sun")]
CALIBRATION_BASE = unit_calibration_doc()


def test_the_bases_are_valid() -> None:
    """The unmutated documents load, so a refusal below is the mutation's doing."""
    assert cfg.load(write("c.toml", dumps(CONFIG_BASE)), environ={})["code.length"] == 16
    assert len(load_launch(write("l.toml", dumps(LAUNCH_BASE))).units) == 4
    assert all(parse_scene(copy.deepcopy(b)).camera.width_px > 0 for b in SCENE_BASES)
    assert load_calibration(write("u.toml", dumps(CALIBRATION_BASE))).laser.baseline_m == 0.075


@FUZZ
@given(mutated(CONFIG_BASE))
def test_config_file(doc: dict[str, Any]) -> None:
    path = write("config.toml", dumps(doc))
    config = settle("config.load (TOML file)", lambda: cfg.load(path, environ={}))
    if config is not None:
        for name, value, _ in config.describe():
            assert not isinstance(value, float) or math.isfinite(value), name


@settings(max_examples=500, deadline=None, derandomize=True)
@given(st.dictionaries(st.builds(lambda k: "ATRIS_" + k.upper().replace(".", "__"),
                                 st.sampled_from([p.key for p in cfg.PARAMS] + ["x.y"])),
                       st.text(max_size=16), max_size=4))
def test_config_environment(environ: dict[str, str]) -> None:
    settle("config.load (environment)", lambda: cfg.load(environ=environ))


@settings(max_examples=500, deadline=None, derandomize=True)
@given(st.lists(assignment_text, max_size=4))
def test_config_set_strings(items: list[str]) -> None:
    settle("config.load (--set)", lambda: cfg.load(environ={}, overrides=items))


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.text(max_size=200))
def test_config_file_of_any_text(text: str) -> None:
    path = write("any.toml", text)
    settle("config.load (any text)", lambda: cfg.load(path, environ={}))


@FUZZ
@given(mutated(LAUNCH_BASE))
def test_launch_file(doc: dict[str, Any]) -> None:
    path = write("launch.toml", dumps(doc))
    settle("load_launch", lambda: load_launch(path))


@FUZZ
@given(st.sampled_from(range(len(SCENE_BASES))).flatmap(lambda i: mutated(SCENE_BASES[i])))
def test_scene_document(doc: dict[str, Any]) -> None:
    settle("parse_scene", lambda: parse_scene(doc))


@settings(max_examples=100, deadline=None, derandomize=True)
@given(st.sampled_from(range(len(SCENE_BASES))).flatmap(lambda i: mutated(SCENE_BASES[i])))
def test_scene_file(doc: dict[str, Any]) -> None:
    path = write("scene.toml", dumps(doc))
    settle("load_scene (file)", lambda: load_scene(path))


@FUZZ
@given(mutated(CALIBRATION_BASE))
def test_calibration_file(doc: dict[str, Any]) -> None:
    path = write("calibration.toml", dumps(doc))
    calibration = settle("load_calibration", lambda: load_calibration(path, (640, 400)))
    if calibration is not None:
        assert math.isfinite(calibration.laser.baseline_m)
        assert all(math.isfinite(a) for a in calibration.laser.alpha_rad)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(st.binary(max_size=200))
def test_calibration_file_of_any_bytes(data: bytes) -> None:
    path = WORK / "bytes.toml"
    path.write_bytes(data)
    settle("load_calibration (any bytes)", lambda: load_calibration(path))
