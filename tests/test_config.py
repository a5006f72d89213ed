"""Typed, layered configuration: defaults < file < environment < command line."""

from __future__ import annotations

from pathlib import Path

import pytest

from atris_node import config
from atris_node.cli import main
from atris_node.errors import ConfigError


def test_defaults_are_typed_and_from_default() -> None:
    cfg = config.load(environ={})
    assert cfg["code.length"] == 16 and isinstance(cfg["code.length"], int)
    assert cfg.sources["code.length"] == "default"


def test_later_sources_win_and_are_named(tmp_path: Path) -> None:
    file = tmp_path / "unit.toml"
    file.write_text('[code]\nlength = 32\n[pipeline]\nsnr_min = 9\n[unit]\nlabel = "rear"\n')
    cfg = config.load(file=file, environ={"ATRIS_CODE__LENGTH": "64"},
                      overrides=["pipeline.snr_min=12.5"])
    assert cfg["code.length"] == 64 and cfg.sources["code.length"] == "environment"
    assert cfg["pipeline.snr_min"] == 12.5 and cfg.sources["pipeline.snr_min"] == "command line"
    assert cfg["unit.label"] == "rear" and cfg.sources["unit.label"].startswith("file ")
    assert isinstance(cfg["pipeline.snr_min"], float)


def test_strings_are_not_inferred_from_text() -> None:
    cfg = config.load(environ={"ATRIS_UNIT__LABEL": "0483"})
    assert cfg["unit.label"] == "0483"


def test_unknown_key_rejected_by_name(tmp_path: Path) -> None:
    file = tmp_path / "unit.toml"
    file.write_text("[code]\nlenght = 32\n")
    with pytest.raises(ConfigError, match=r"unknown parameter 'code.lenght'"):
        config.load(file=file, environ={})


@pytest.mark.parametrize(("key", "value", "message"), [
    ("code.length", "12", "power of two"),
    ("code.mode", "fast", "must be one of async, sync"),
    ("pipeline.snr_min", "abc", "expected float"),
    ("driver.realtime", "maybe", "expected bool"),
    ("unit.unit_id", "16", r"must be in \[0, 15\]"),
])
def test_bad_values_name_key_and_accepted_values(key: str, value: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        config.load(environ={}, overrides=[f"{key}={value}"])
    assert key in str(info.value) and "command line" in str(info.value)


def test_toml_types_are_checked(tmp_path: Path) -> None:
    file = tmp_path / "unit.toml"
    file.write_text('[code]\nlength = "16"\n')
    with pytest.raises(ConfigError, match=r"code\.length: expected int"):
        config.load(file=file, environ={})
    file.write_text("[bus]\nfd = 1\n")
    with pytest.raises(ConfigError, match=r"bus\.fd: expected bool"):
        config.load(file=file, environ={})


def test_cross_check_z_range() -> None:
    with pytest.raises(ConfigError, match="z_min_m"):
        config.load(environ={}, overrides=["pipeline.z_min_m=12", "pipeline.z_max_m=10"])


def test_broken_file_is_clear_error(tmp_path: Path) -> None:
    file = tmp_path / "unit.toml"
    file.write_text("[code\nlength=1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        config.load(file=file, environ={})
    with pytest.raises(ConfigError, match="cannot read config file"):
        config.load(file=tmp_path / "missing.toml", environ={})


def test_cli_config_print_shows_value_and_source(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config", "--print", "--set", "code.length=32"]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("code.length"))
    assert "32" in line and "command line" in line


def test_cli_error_is_one_line_and_nonzero(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config", "--set", "code.length=3"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "code.length" in err
