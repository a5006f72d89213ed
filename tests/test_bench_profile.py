"""`atris bench profile`: the fields of a row and the cases of the sweep (no timings)."""

from __future__ import annotations

from atris_node.bench import profile


def test_smoke_row_carries_stages_and_top_functions() -> None:
    row = profile.measure(profile.Case(320, 200, code_length=4, lines=4, sectors=4), 3,
                          top=True)
    assert set(row["pipeline"]) == {"lines", "triangulate", "sectors", "rest", "total", "cpu"}
    assert all(v >= 0.0 for v in row["pipeline"].values())
    assert row["demod_block_ms"] > 0 and row["demod_sliding_ms"] > 0
    assert row["per_map_block_ms"] >= row["pipeline"]["cpu"]
    assert 0 < len(row["top"]) <= profile.TOP


def test_sweep_varies_one_axis_at_a_time() -> None:
    cases = profile.sweep_cases()
    assert {axis for axis, _, _ in cases} == {"resolution", "code_length", "lines", "sectors"}
    base = profile.Case(1280, 800)
    for axis, value, case in cases:
        if axis != "resolution":
            assert getattr(case, axis) == value
            assert profile.replace(case, **{axis: getattr(base, axis)}) == base


def test_scene_has_the_asked_number_of_lines() -> None:
    scene = profile.scene_for(profile.Case(640, 400, bits=10, lines=3))
    assert len(scene.projector.alpha_rad) == 3
    assert (scene.camera.width_px, scene.camera.bits) == (640, 10)
