"""The raw values of the process objects 0x2100-0x2120, composed from a measurement.

Plain functions of a :class:`~atris_node.types.Measurement` and the configuration
(object 0x2000) in force when a TPDO is sent; the raw codes are those of ``atris.dbc``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

from atris_node.bus.can import payloads
from atris_node.types import Measurement, SectorDistance, SectorState, UnitStatus

MAX_SECTORS = 16
NOT_AVAILABLE_I16, NOT_AVAILABLE_U16 = -32768, 0xFFFF


def rebin(sectors: Sequence[SectorDistance], count: int) -> tuple[SectorDistance, ...]:
    """``sectors`` (indexes 0..n-1 over the field of view) merged into ``count`` wider
    sectors when ``count`` divides n: each keeps the nearest valid distance of its group
    and the lowest confidence; it is INVALID when any of its group is, NO_RETURN when all
    are. Otherwise ``sectors`` unchanged.

    >>> s = [SectorDistance(i, 0.0, SectorState.VALID, 1.0 + i, 0.5) for i in range(4)]
    >>> [m.distance_m for m in rebin(s, 2)]
    [1.0, 3.0]
    """
    n = len(sectors)
    if count >= n or n % count:
        return tuple(sectors)
    ordered = sorted(sectors, key=lambda s: s.index)
    size = n // count
    return tuple(_merge(i, ordered[i * size:(i + 1) * size]) for i in range(count))


def _merge(index: int, group: Sequence[SectorDistance]) -> SectorDistance:
    bearing = sum(s.bearing_rad for s in group) / len(group)
    if any(s.state is SectorState.INVALID for s in group):
        return SectorDistance(index, bearing, SectorState.INVALID)
    valid = [s for s in group if s.state is SectorState.VALID]
    if not valid:
        return SectorDistance(index, bearing, SectorState.NO_RETURN,
                              confidence=min(s.confidence for s in group))
    nearest = min(valid, key=lambda s: s.distance_m)
    return SectorDistance(index, bearing, SectorState.VALID, nearest.distance_m,
                          min(s.confidence for s in valid),
                          sum(s.point_count for s in valid), nearest.sigma_m)


def confident(measurement: Measurement, min_confidence_pct: int) -> Measurement:
    """``measurement`` with VALID sectors below ``min_confidence_pct`` made INVALID (and
    the nearest obstacle dropped when it lies in one of them)."""
    if min_confidence_pct <= 0:
        return measurement
    low = {s.index for s in measurement.sectors
           if s.state is SectorState.VALID and s.confidence * 100.0 < min_confidence_pct}
    if not low:
        return measurement
    sectors = tuple(SectorDistance(s.index, s.bearing_rad, SectorState.INVALID)
                    if s.index in low else s for s in measurement.sectors)
    nearest = measurement.nearest
    if nearest is not None and nearest.index in low:
        nearest = None
    return replace(measurement, sectors=sectors, nearest=nearest)


def status_values(status: UnitStatus, age_s: float | None) -> list[int]:
    """Sub-indexes 1..11 of 0x2120 Status."""
    age_ms = NOT_AVAILABLE_U16 if age_s is None or math.isnan(age_s) else payloads.scaled(
        max(age_s, 0.0), 0.001, 0, NOT_AVAILABLE_U16 - 1)
    return [int(status.state), max(0, min(255, status.code_row)),
            max(0, min(255, status.code_length)),
            payloads.scaled(status.chip_rate_hz, 0.1, 0, 0xFFFF),
            status.measurement_counter % 0x10000, int(status.faults) & 0xFF, age_ms,
            max(0, min(255, status.dropped_sub_frames)),
            payloads.scaled(status.ambient_level * 100.0, 0.5, 0, 200),
            payloads.scaled(status.saturated_fraction * 100.0, 0.5, 0, 200),
            payloads.scaled(status.foreign_code_energy * 100.0, 1.0, 0, 255)]


def sector_values(measurement: Measurement | None, usable: bool,
                  count: int) -> tuple[list[int], list[int]]:
    """Sub-indexes 1..16 of 0x2100 distances and 0x2101 confidences: ``count`` sectors
    (re-binned), the rest invalid."""
    sectors = rebin(measurement.sectors, count) if measurement is not None else ()
    slots = payloads.sector_slots(sectors, count, usable) + [None] * (MAX_SECTORS - count)
    return ([payloads.distance_raw(s) for s in slots], [payloads.confidence_raw(s) for s in slots])


def nearest_values(measurement: Measurement | None, usable: bool,
                   warning_mm: int) -> list[int]:
    """Sub-indexes 1..6 of 0x2110 Nearest (6: Warning, see :func:`warning`)."""
    raw = payloads.nearest_signals(measurement, usable)
    valid = bool(raw["Valid"]) and measurement is not None
    nearest = measurement.nearest if measurement is not None and valid else None
    values = [raw["Distance"], NOT_AVAILABLE_I16, NOT_AVAILABLE_I16, NOT_AVAILABLE_U16,
              int(valid), warning(raw["Distance"], warning_mm)]
    if nearest is not None and measurement is not None:
        values[1] = payloads.bearing_raw(nearest.bearing_rad)
        values[2] = _optional(measurement.closing_speed_mps, 0.01, -32767, 32767,
                              NOT_AVAILABLE_I16)
        ttc = measurement.time_to_collision_s
        values[3] = _optional(ttc if ttc is None or ttc >= 0 else None, 0.01, 0, 0xFFFE,
                              NOT_AVAILABLE_U16)
    return values


def warning(distance_raw: int, warning_mm: int) -> int:
    """1 unless the data show the way clear up to ``warning_mm``: 0 for a valid nearest
    distance beyond it or no return at all, 1 for one within it or invalid data."""
    if distance_raw == payloads.DISTANCE_NO_RETURN:
        return 0
    if distance_raw > payloads.DISTANCE_MAX_RAW:
        return 1
    return int(distance_raw <= warning_mm)


def _optional(value: float | None, scale: float, lo: int, hi: int, missing: int) -> int:
    if value is None or math.isnan(value):
        return missing
    return payloads.scaled(value, scale, lo, hi)
