"""A unit whose own code is strobed by a unit of another vehicle moves to a free code
(the negotiation's hopping), and records it in its status."""

from __future__ import annotations

import time
from pathlib import Path

import can
from strobe_audit import AuditedProjector, audited, unpermitted_light

from atris_node import config as cfg
from atris_node.node.launch import launch_dir
from atris_node.node.unit import Unit
from atris_node.types import FaultBits
from drivers import open_backend as open_registry_backend

JAMMER = """
[[interferer]]
name = "other vehicle on our code"
pose = {{ x_m = 0.0, y_m = 0.4, z_m = 0.5 }}
strobe = "code"
code_length = 8
code_row = {row}
chip_rate_hz = 240.0
phase_sub_frames = 3.0
exposure_us = 1000.0
baseline_m = 0.075
alpha_deg = [79.0, 83.0, 87.0, 91.0]
power_w = {power}
line_width_mrad = 1.5
fan_deg = 70.0
"""


def jammed_scene(tmp_path: Path, row: int, power: float) -> Path:
    text = (launch_dir() / "scenes" / "indoor_lab.toml").read_text()
    noise = text.index("[noise]") if "[noise]" in text else len(text)
    path = tmp_path / "jammed.toml"
    path.write_text(text[:noise] + JAMMER.format(row=row, power=power) + text[noise:])
    return path


#: the audited projectors of the last run_unit (hops re-open nothing: one per unit)
PROJECTORS: list[AuditedProjector] = []


def run_unit(scene: Path, channel: str, seconds: float) -> tuple[Unit, int | None]:
    """Run until the first hop (or ``seconds``) and a little after; the row then owned."""
    PROJECTORS.clear()
    config = cfg.load(environ={}, overrides=[
        f"driver.scene={scene}", "code.length=8", "negotiation.window_s=0.1",
        "interference.every_windows=2", f"bus.channel={channel}"])
    with can.Bus(interface="virtual", channel=channel) as bus:
        unit = Unit(config, bus, open_backend=audited(open_registry_backend, PROJECTORS))
        unit.configure()
        unit.activate(threaded=False)
        end = time.monotonic() + seconds
        try:
            while time.monotonic() < end and unit.negotiator.hop_count == 0:
                unit.step()
                unit.check()
            for _ in range(200):
                unit.step()
            row = unit.negotiator.code_row if unit.negotiator.may_strobe else None
        finally:
            unit.shutdown()
    return unit, row


def test_jammed_own_code_makes_the_unit_hop(tmp_path: Path) -> None:
    unit, row = run_unit(jammed_scene(tmp_path, row=2, power=0.6), "hop-jammed", 25.0)
    assert unit.negotiator.hop_count >= 1
    assert row not in (None, 2)
    rows_lit = {row for _, lit, row in unit.stats.history if lit}
    assert 2 in rows_lit and len(rows_lit) >= 2
    assert unpermitted_light(PROJECTORS, unit.negotiator.timeline) == []


def test_orthogonal_foreign_code_does_not_make_the_unit_hop(tmp_path: Path) -> None:
    unit, row = run_unit(jammed_scene(tmp_path, row=5, power=0.6), "hop-orthogonal", 4.0)
    assert unit.negotiator.hop_count == 0
    assert row == 2
    assert not unit.status().faults & FaultBits.FOREIGN_CODE
