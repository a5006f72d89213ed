"""``atris bench adaptive``: the JSON rows and their fields (tiny runs)."""

from __future__ import annotations

import json

import pytest

from atris_node.cli import main

FIELDS = {"scene", "code_length", "output_hz", "ms_per_frame", "range_rmse_m",
          "fixed32_output_hz", "fixed32_range_rmse_m"}


def test_smoke_bench_adaptive_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "adaptive", "--json", "--scenes", "indoor_lab", "--settle", "16",
                 "--measure", "80"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == 1 and set(rows[0]) >= FIELDS
    r = rows[0]
    assert r["scene"] == "indoor_lab" and 0 < r["fixed32_output_hz"] <= 240 / 32 + 1e-9
    assert r["output_hz"] > 0 and r["code_length"] in (4, 8, 16, 32)
