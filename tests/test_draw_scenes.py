"""scripts/draw_scenes.py, the random-scene generator the never-wrong rounds draw their
batches with (docs/scenes.md): every scene it writes loads, and a seed gives the same
file every time (a batch can be drawn again from its seeds)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

from atris_node.sim import load_scene

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "draw_scenes.py"


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("draw_scenes", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_drawn_scenes_load_and_a_seed_draws_the_same_file(tmp_path: Path) -> None:
    draw = _script()
    assert draw.main([str(tmp_path / "a"), "24000", "6"]) == 0
    assert draw.main([str(tmp_path / "b"), "24003", "2"]) == 0
    first = sorted((tmp_path / "a").glob("*.toml"))
    assert [p.name for p in first] == [f"s{s}.toml" for s in range(24000, 24006)]
    for path in first:
        scene = load_scene(path)
        assert scene.projector.alpha_rad
    for name in ("s24003.toml", "s24004.toml"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_bad_arguments_say_how_to_call_it(capsys) -> None:
    assert _script().main(["only-one"]) == 2
    assert "draw_scenes.py OUT_DIR FIRST_SEED COUNT" in capsys.readouterr().err
