"""``atris codes``: JSON fields, the readable table and errors, through the real entry point."""

from __future__ import annotations

import json

import pytest

from atris_node import codes
from atris_node.cli import main


def _json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, object]:
    assert main(["codes", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)  # type: ignore[no-any-return]


def test_async_json_for_length_8(capsys: pytest.CaptureFixture[str]) -> None:
    doc = _json(capsys, "--length", "8")
    assert doc["length"] == 8 and doc["mode"] == "async" and doc["max_codes"] == 3
    assert doc["codes"] == ["10101010", "11001100", "11110000"]
    assert doc["set_count"] == 8
    assert doc["sets"] == [list(s) for s in codes.async_sets(8)]
    assert [2, 4, 7] in doc["sets"]  # type: ignore[operator]


def test_sync_json_has_no_sets(capsys: pytest.CaptureFixture[str]) -> None:
    doc = _json(capsys, "--length", "4", "--mode", "sync")
    assert doc["max_codes"] == 3 and doc["codes"] == ["1010", "1100", "1001"]
    assert "sets" not in doc and "set_count" not in doc


def test_long_codes_leave_the_sets_out(capsys: pytest.CaptureFixture[str]) -> None:
    doc = _json(capsys, "--length", "128")
    assert doc["set_count"] == 2**21 and "sets" not in doc
    assert len(doc["codes"]) == 7  # type: ignore[arg-type]


def test_table_lists_rows_chips_and_sets(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["codes", "--length", "16"]) == 0
    out = capsys.readouterr().out
    assert "    9  1111111100000000" in out
    assert "64 maximal sets" in out and "5..8, 9..16" in out
    assert "2, 4, 8, 16" in out


@pytest.mark.parametrize("length", ["12", "2"])
def test_bad_length_is_an_error_message(capsys: pytest.CaptureFixture[str], length: str) -> None:
    assert main(["codes", "--length", length]) == 1
    assert "error: code length" in capsys.readouterr().err
