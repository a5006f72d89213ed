"""The live table of ``atris launch`` says why a unit's sectors are invalid."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import pytest

from atris_node.node.fleetview import _unit_rows


def _unit() -> SimpleNamespace:
    return SimpleNamespace(label="left", truth_sector_distances=lambda: [None, 6.29])


def test_rows_show_the_data_age_and_the_fault_bits() -> None:
    view = {"state": "RUNNING", "code_row": 3, "code_length": 16, "data_age_s": 1.23,
            "faults": ["DeadlineMiss", "LowSignal"], "sectors": [[0, "invalid", 0], [1, 6.25, 0]]}
    measured, truth = _unit_rows(_unit(), view)
    assert "inval  6.25" in measured
    assert measured.endswith("age 1.23 s  faults DeadlineMiss,LowSignal")
    assert truth.split("truth:")[1].split() == ["free", "6.29"]


def test_rows_without_a_status_frame_yet_show_no_age() -> None:
    measured, _ = _unit_rows(_unit(), {})
    assert "age" not in measured and "faults" not in measured


def test_a_named_data_age_is_shown_as_named() -> None:
    measured, _ = _unit_rows(_unit(), {"data_age_s": "no_data", "faults": []})
    assert measured.endswith("age no_data")


def test_an_age_beyond_max_age_is_marked_stale() -> None:
    unit = _unit()
    unit.config = {"publish.max_age_s": 1.0}
    measured, _ = _unit_rows(unit, {"data_age_s": 1.12})
    assert measured.endswith("age 1.12 s (stale)")
    measured, _ = _unit_rows(unit, {"data_age_s": 0.4})
    assert measured.endswith("age 0.40 s")


def test_a_table_that_cannot_be_drawn_is_logged_and_the_fleet_runs_on(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture,
        capsys: pytest.CaptureFixture[str]) -> None:
    from atris_node.cli import launch as launch_cli

    def broken(runner: object, monitor: object) -> str:
        raise ValueError("bad frame content")

    monkeypatch.setattr(launch_cli, "fleet_table", broken)
    with caplog.at_level(logging.ERROR):
        launch_cli._show(SimpleNamespace(), SimpleNamespace(), live=False)  # type: ignore[arg-type]
    assert "could not be drawn" in caplog.text and capsys.readouterr().out == ""
