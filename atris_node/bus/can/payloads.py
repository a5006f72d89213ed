"""Raw signal values of the unit frames, built from :mod:`atris_node.types`.

Every function returns raw integers for ``FrameCodec.encode(..., scaling=False)``; the
scales and the reserved raw codes are those of ``atris.dbc``. Inputs that are NaN or
infinite never reach the bus: they become the signal's "invalid"/"not available" code
or its limit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

from atris_node.bus.can.ids import MAX_SECTORS, SECTORS_PER_FRAME
from atris_node.errors import ConfigError
from atris_node.types import (
    FaultBits,
    Measurement,
    SectorDistance,
    SectorState,
    UnitState,
    UnitStatus,
)

DISTANCE_SCALE_M = 0.001
DISTANCE_MAX_RAW = 65532
DISTANCE_NO_SECTOR = 0xFFFD
DISTANCE_NO_RETURN = 0xFFFE
DISTANCE_INVALID = 0xFFFF
DATA_AGE_SCALE_S = 0.01
DATA_AGE_NO_DATA = 255
BEARING_NOT_AVAILABLE = -32768
CLOSING_SPEED_NOT_AVAILABLE = -128
TTC_NOT_AVAILABLE = 255
#: FaultBits member -> status frame signal
FAULT_SIGNALS = {bit: "Fault_" + "".join(w.capitalize() for w in str(bit.name).split("_"))
                 for bit in FaultBits if bit}
#: faults after which the distances of a measurement must not be used
SPOILING_FAULTS = (FaultBits.CAMERA_LOST | FaultBits.LASER_FAULT | FaultBits.PLAN_CONFLICT
                   | FaultBits.CALIBRATION)
RawSignals = dict[str, int]


def data_usable(measurement: Measurement | None, status: UnitStatus, age_s: float | None,
                max_age_s: float) -> bool:
    """True when ``measurement`` (``age_s`` old) may go out as valid distances.

    False without a measurement, when older than ``max_age_s`` or stamped in the future
    (a negative age is a clock error, not fresh data), when the unit is not RUNNING, or
    when a fault in SPOILING_FAULTS is set.
    """
    if measurement is None or age_s is None or not math.isfinite(age_s):
        return False
    if status.state is not UnitState.RUNNING or status.faults & SPOILING_FAULTS:
        return False
    return 0.0 <= age_s <= max_age_s


def alive_status(status: UnitStatus, progress_s: float | None, now: float,
                 deadline_s: float) -> UnitStatus:
    """``status`` as it may go out at ``now`` (seconds, one clock): FAULT with
    DEADLINE_MISS when the measurement loop last reported progress (``progress_s``, None
    before it ever did) more than ``deadline_s`` ago: it died or hangs, so neither its
    state nor its distances can be vouched for."""
    if progress_s is None or now - progress_s <= deadline_s:
        return status
    return replace(status, state=UnitState.FAULT, faults=status.faults | FaultBits.DEADLINE_MISS)


def unchanged(status: UnitStatus) -> UnitStatus:
    """The default check of a status at send time: it goes out as handed over."""
    return status


def scaled(value: float, scale: float, lo: int, hi: int) -> int:
    """``round(value / scale)`` clamped to ``lo..hi``; NaN gives ``lo``."""
    if math.isnan(value):
        return lo
    steps = value / scale
    if math.isinf(steps):  # infinite, or so large that the division overflowed
        return hi if steps > 0 else lo
    return max(lo, min(hi, round(steps)))


def distance_raw(sector: SectorDistance | None) -> int:
    """Raw distance (mm) of a sector, or the no-return / invalid code."""
    if sector is None or sector.state is SectorState.INVALID:
        return DISTANCE_INVALID
    if sector.state is SectorState.NO_RETURN:
        return DISTANCE_NO_RETURN
    if not math.isfinite(sector.distance_m) or sector.distance_m < 0.0:
        return DISTANCE_INVALID
    return scaled(sector.distance_m, DISTANCE_SCALE_M, 0, DISTANCE_MAX_RAW)


def confidence_raw(sector: SectorDistance | None) -> int:
    """Raw confidence, 0.5 % steps (0..200); 0 for invalid sectors."""
    if sector is None or sector.state is SectorState.INVALID:
        return 0
    return scaled(sector.confidence * 100.0, 0.5, 0, 200)


def data_age_raw(age_s: float | None) -> int:
    """Raw data age, 10 ms steps, 254 = 2.54 s or more, 255 = no data."""
    if age_s is None or math.isnan(age_s):
        return DATA_AGE_NO_DATA
    return scaled(max(age_s, 0.0), DATA_AGE_SCALE_S, 0, DATA_AGE_NO_DATA - 1)


def status_signals(status: UnitStatus, faults: FaultBits, age_s: float | None) -> RawSignals:
    """Raw signals of the Status frame; ``faults`` replaces ``status.faults``."""
    signals = {name: int(bool(faults & bit)) for bit, name in FAULT_SIGNALS.items()}
    signals.update(
        State=int(status.state),
        CodeRow=max(0, min(255, status.code_row)),
        CodeLength=max(0, min(255, status.code_length)),
        ChipRate=scaled(status.chip_rate_hz, 0.1, 0, 0xFFFF),
        DataAge=data_age_raw(age_s),
    )
    return signals


def quality_signals(status: UnitStatus, sector_count: int) -> RawSignals:
    """Raw signals of the Quality frame (``sector_count`` 1..16)."""
    return {
        "SectorCount": check_sector_count(sector_count) - 1,
        "MeasurementCounter": status.measurement_counter % 0x10000,
        "AmbientLevel": scaled(status.ambient_level * 100.0, 0.5, 0, 200),
        "SaturatedFraction": scaled(status.saturated_fraction * 100.0, 0.5, 0, 200),
        "ForeignCodeEnergy": scaled(status.foreign_code_energy * 100.0, 1.0, 0, 255),
        "DroppedSubFrames": max(0, min(255, status.dropped_sub_frames)),
    }


def nearest_signals(measurement: Measurement | None, usable: bool) -> RawSignals:
    """Raw signals of the Nearest frame; everything "not available" unless ``usable``."""
    nearest = measurement.nearest if (usable and measurement is not None) else None
    valid = nearest is not None and distance_raw(nearest) <= DISTANCE_MAX_RAW
    if not valid or nearest is None or measurement is None:
        free = usable and measurement is not None
        return {"Valid": 0, "Distance": DISTANCE_NO_RETURN if free else DISTANCE_INVALID,
                "Bearing": BEARING_NOT_AVAILABLE,
                "ClosingSpeed": CLOSING_SPEED_NOT_AVAILABLE, "TimeToCollision": TTC_NOT_AVAILABLE}
    return {"Valid": 1, "Distance": distance_raw(nearest),
            "Bearing": bearing_raw(nearest.bearing_rad),
            "ClosingSpeed": _closing_speed_raw(measurement.closing_speed_mps),
            "TimeToCollision": _ttc_raw(measurement.time_to_collision_s)}


def bearing_raw(bearing_rad: float) -> int:
    """Raw bearing, 0.01 degree steps in -180..180; not available when not finite."""
    if not math.isfinite(bearing_rad):
        return BEARING_NOT_AVAILABLE
    degrees = math.degrees(math.remainder(bearing_rad, math.tau))
    return scaled(degrees, 0.01, -18000, 18000)


def _closing_speed_raw(speed_mps: float | None) -> int:
    if speed_mps is None or math.isnan(speed_mps):
        return CLOSING_SPEED_NOT_AVAILABLE
    return scaled(speed_mps, 0.2, -127, 127)


def _ttc_raw(ttc_s: float | None) -> int:
    if ttc_s is None or math.isnan(ttc_s) or ttc_s < 0.0:
        return TTC_NOT_AVAILABLE
    return scaled(ttc_s, 0.1, 0, TTC_NOT_AVAILABLE - 1)


def check_sector_count(count: int) -> int:
    """Return ``count`` if it is 1..16, else raise ConfigError."""
    if not 1 <= count <= MAX_SECTORS:
        raise ConfigError(f"sector count must be 1..{MAX_SECTORS}, got {count}")
    return count


def sector_slots(sectors: Sequence[SectorDistance], count: int,
                 usable: bool) -> list[SectorDistance | None]:
    """Sector ``i`` at slot ``i`` for ``i < count``; None (invalid) where missing or unusable."""
    slots: list[SectorDistance | None] = [None] * check_sector_count(count)
    for sector in sectors if usable else ():
        if 0 <= sector.index < count:
            slots[sector.index] = sector
    return slots


def sectors_signals(sectors: Sequence[SectorDistance], count: int,
                    usable: bool) -> list[RawSignals]:
    """Raw signals of the Sectors frames: two sectors per frame, first index even."""
    slots = sector_slots(sectors, count, usable)
    frames = []
    for first in range(0, count, SECTORS_PER_FRAME):
        second = first + 1
        frames.append({
            "SectorIndex": first,
            "Distance0": distance_raw(slots[first]), "Confidence0": confidence_raw(slots[first]),
            "Distance1": distance_raw(slots[second]) if second < count else DISTANCE_NO_SECTOR,
            "Confidence1": confidence_raw(slots[second]) if second < count else 0,
        })
    return frames
