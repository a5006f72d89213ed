"""The folders are the flow: every module imports only from its own layer or the layers below.

Each module's imports (module level, inside functions and under ``TYPE_CHECKING`` alike) are
read from its source with ``ast`` and checked against the layer table below, which is the
picture in ``docs/architecture.md``. Adding ``from atris_node.node.unit import Unit`` to
``atris_node/pipeline/sectors.py``, ``import atris_node.pipeline.chain`` to
``atris_node/bus/can/frames.py`` or ``from atris_node.node import wiring`` to
``drivers/base.py`` made ``test_every_import_goes_down_the_layers`` fail, naming the
module, the import and the rule; with the line removed it passes again.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("atris_node", "drivers", "calib")

#: module values, frames and errors every layer uses (the ground floor)
GROUND = {"atris_node", "atris_node.types", "atris_node.config", "atris_node.errors",
          "atris_node.codes", "atris_node.jit", "atris_node.calibration",
          "atris_node.mounting", "atris_node.progress"}

#: layer -> the layers its modules may import (their own layer always)
MAY_IMPORT: dict[str, set[str]] = {
    "ground": set(),
    "demod": {"ground"},
    "pipeline": {"ground", "demod"},
    "adaptive": {"ground", "demod"},
    "bus.can": {"ground", "bus.negotiation"},  # the DBC describes the negotiation frames
    "bus.canopen": {"ground", "bus.can"},
    "bus.negotiation": {"ground"},
    "sim": {"ground", "pipeline"},
    "drivers": {"ground", "sim"},
    "calib": {"ground", "demod", "pipeline", "sim", "drivers"},
    "node": {"ground", "demod", "pipeline", "adaptive", "bus.can", "bus.canopen",
             "bus.negotiation", "sim", "drivers", "calib"},
    "testing": {"ground", "drivers"},
    "bench": {"ground", "demod", "pipeline", "adaptive", "bus.can", "bus.canopen",
              "bus.negotiation", "sim", "drivers", "calib", "node", "testing"},
    "cli": {"ground", "demod", "pipeline", "adaptive", "bus.can", "bus.canopen",
            "bus.negotiation", "sim", "drivers", "node", "calib", "bench", "testing"},
}


def layer_of(module: str) -> str:
    """The layer of a dotted module name of this project."""
    if module in GROUND:
        return "ground"
    if module == "atris_node.__main__":
        return "cli"
    parts = module.split(".")
    if parts[0] in ("drivers", "calib"):
        return parts[0]
    if parts[1] == "bus":
        if len(parts) < 3:
            return "ground"  # the bus package's own __init__ holds nothing
        return f"bus.{parts[2]}"
    return parts[1]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def project_imports(path: Path) -> list[tuple[int, str]]:
    """(line, dotted name) of every import of a project module in the file at ``path``;
    ``from package import name`` counts as importing ``package.name`` when that is a
    module of the project, else ``package``."""
    tree = ast.parse(path.read_text("utf-8"), str(path))
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                found.append((node.lineno, sub if is_module(sub) else node.module))
    return [(line, name) for line, name in found if name.split(".")[0] in PACKAGES]


def is_module(dotted: str) -> bool:
    base = ROOT.joinpath(*dotted.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def all_modules() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def violations(path: Path) -> list[str]:
    """The imports of the module at ``path`` that go up or sideways, one message each."""
    source = module_name(path)
    layer = layer_of(source)
    allowed = MAY_IMPORT[layer] | {layer}
    bad = []
    for line, target in project_imports(path):
        if layer_of(target) not in allowed:
            bad.append(f"{path.relative_to(ROOT)}:{line}: {source} ({layer}) imports "
                       f"{target} ({layer_of(target)}); {layer} may import "
                       f"{', '.join(sorted(allowed))}")
    return bad


def test_every_import_goes_down_the_layers() -> None:
    modules = all_modules()
    assert len(modules) > 100  # every package was found
    bad = [message for path in modules for message in violations(path)]
    assert bad == [], "\n".join(bad)


def test_every_module_has_a_layer() -> None:
    layers = {layer_of(module_name(p)) for p in all_modules()}
    assert layers <= set(MAY_IMPORT), layers - set(MAY_IMPORT)
    assert {"pipeline", "bus.can", "bus.canopen", "bus.negotiation", "node",
            "adaptive"} <= layers


@pytest.mark.parametrize(("module", "line"), [
    ("atris_node/pipeline/sectors.py", "from atris_node.node.unit import Unit"),
    ("atris_node/pipeline/chain.py", "from atris_node.bus.can import payloads"),
    ("atris_node/bus/can/frames.py", "import atris_node.pipeline.chain"),
    ("atris_node/bus/negotiation/plan.py", "from atris_node.pipeline import geometry"),
    ("drivers/base.py", "from atris_node.node import wiring"),
    ("atris_node/types.py", "from atris_node.demod import BlockDemodulator"),
    ("atris_node/node/soak.py", "from atris_node.cli.launch import summarize"),
])
def test_an_upward_import_is_caught(tmp_path: Path, module: str, line: str) -> None:
    """The check itself: the same module with one forbidden import added is reported."""
    original = ROOT / module
    copy = tmp_path / "copy.py"
    copy.write_text(original.read_text("utf-8") + f"\n{line}\n", "utf-8")
    assert violations(original) == []
    found = [m for m in _violations_as(copy, original) if line.split()[1] in m]
    assert len(found) == 1, found


def _violations_as(path: Path, stands_for: Path) -> list[str]:
    """:func:`violations` of the file at ``path`` read as if it were ``stands_for``."""
    source = module_name(stands_for)
    allowed = MAY_IMPORT[layer_of(source)] | {layer_of(source)}
    return [f"{source} imports {target}" for _, target in project_imports(path)
            if layer_of(target) not in allowed]
