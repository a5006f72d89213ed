"""The live table of ``atris launch``: each unit's code and sector distances, and for
simulated units the truth beside them."""

from __future__ import annotations

from typing import Any

from atris_node.bus.monitor import BusMonitor, render_table


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:5.2f}"
    return f"{value!s:>5}"[:5]


def _unit_rows(unit: Any, view: dict[str, Any]) -> list[str]:
    measured = {i: d for i, d, _ in view.get("sectors", [])}
    truth = unit.truth_sector_distances()
    count = max(len(truth or ()), len(measured))
    sectors = " ".join(_cell(measured.get(i, "-")) for i in range(count))
    rows = [f"{unit.label:<8} {view.get('state')!s:<11} "
            f"code {view.get('code_row')}/{view.get('code_length')}  measured: {sectors}"]
    if truth is not None:
        rows.append(f"{'':<8} {'':<11} {'':<9}     truth: "
                    + " ".join(_cell("free" if t is None else t) for t in truth))
    return rows


def fleet_table(runner: Any, monitor: BusMonitor) -> str:
    """Measured sectors (m, or no_return / invalid) beside the truth, per unit."""
    units = getattr(runner, "units", None)
    snapshot = monitor.snapshot()
    if not units:
        return render_table(snapshot)
    lines = ["unit     state       code      sector distances, m (right to left)"]
    for unit in units:
        view = snapshot["units"].get(str(unit.config["unit.unit_id"]), {})
        lines += _unit_rows(unit, view)
    return "\n".join(lines)
