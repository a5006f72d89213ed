"""What the bus tests feed a unit's publisher and launcher: a status, a measurement of four
sectors, and a two-unit simulated launch file."""

from __future__ import annotations

import time

from atris_node.types import Measurement, SectorDistance, SectorState, UnitState, UnitStatus

_TWO_UNITS = """
[launch]
name = "pair"
mode = "threads"
{duration}
[bus]
interface = "virtual"
channel = "{channel}"

[defaults]
driver = {{ name = "sim", scene = "indoor_lab" }}
code = {{ length = 8 }}
negotiation = {{ window_s = 0.1 }}

[[unit]]
unit = {{ label = "a", unit_id = 0, name = 0x100 }}

[[unit]]
unit = {{ label = "b", unit_id = 1, name = 0x200 }}
driver = {{ seed = 5 }}
"""


def two_units(channel: str, duration_s: float | None = None) -> str:
    """A launch file of two simulated units (threads) on virtual ``channel``."""
    duration = "" if duration_s is None else f"duration_s = {duration_s}\n"
    return _TWO_UNITS.format(channel=channel, duration=duration)


def status(row: int) -> UnitStatus:
    """A RUNNING status on Walsh row ``row`` of N = 16."""
    return UnitStatus(UnitState.RUNNING, code_row=row, code_length=16, chip_rate_hz=480.0,
                      measurement_counter=0)


def measurement(distance_m: float) -> Measurement:
    """Four VALID sectors at ``distance_m`` + 0, 1, 2, 3 m, fresh now."""
    sectors = tuple(SectorDistance(i, 0.0, SectorState.VALID, distance_m + i, 0.5)
                    for i in range(4))
    return Measurement(1, sectors, time.monotonic(), 1, nearest=sectors[0])
