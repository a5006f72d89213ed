"""The live table of ``atris launch``: each unit's code and sector distances, and for
simulated units the truth beside them."""

from __future__ import annotations

from typing import Any

from atris_node.bus.can.monitor import BusMonitor, render_table


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:5.2f}"
    return f"{value!s:>5}"[:5]


def _why(view: dict[str, Any], max_age_s: float | None = None) -> str:
    """Data age and fault bits of the unit's last status frame: why sectors are invalid
    (older than ``max_age_s``: published invalid as stale)."""
    age = view.get("data_age_s")  # seconds, or a named value of the DBC (no_data)
    if isinstance(age, (int, float)):
        stale = max_age_s is not None and age > max_age_s
        text = f"  age {age:.2f} s" + (" (stale)" if stale else "")
    else:
        text = "" if age is None else f"  age {age}"
    faults = view.get("faults") or []
    return text + (f"  faults {','.join(faults)}" if faults else "")


def _max_age(unit: Any) -> float | None:
    config = getattr(unit, "config", None)
    try:
        return float(config["publish.max_age_s"]) if config is not None else None
    except (KeyError, TypeError, ValueError):
        return None


def _unit_rows(unit: Any, view: dict[str, Any]) -> list[str]:
    measured = {i: d for i, d, _ in view.get("sectors", [])}
    truth = unit.truth_sector_distances()
    count = max(len(truth or ()), len(measured))
    sectors = " ".join(_cell(measured.get(i, "-")) for i in range(count))
    rows = [f"{unit.label:<8} {view.get('state')!s:<11} "
            f"code {view.get('code_row')}/{view.get('code_length')}  measured: {sectors}"
            f"{_why(view, _max_age(unit))}"]
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
