"""Small data classes that travel along the one-way data flow.

Every stage carries the sequence numbers and timestamps of the sub-frames it came from,
so a published frame can say how old its data is.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class SubFrame:
    """One camera sub-frame, as every camera backend yields it.

    Attributes:
        pixels: (H, W) uint8 (bits <= 8) or uint16 (bits 9..16) raw intensities, in DN.
        sequence: camera sequence number; consecutive sub-frames differ by 1, a gap means
            dropped sub-frames.
        device_time_s: exposure mid-time on the device clock, seconds.
        host_time_s: arrival time on the host's ``time.monotonic()`` clock, seconds.
        exposure_us: exposure time, microseconds.
        bits: significant bits per pixel (8..16); full scale is ``2**bits - 1``.
        chip: the chip (0 = projector off, 1 = on) the projector was commanded to strobe
            for this sub-frame, or None when the backend does not know it.
    """

    pixels: npt.NDArray[np.uint8] | npt.NDArray[np.uint16]
    sequence: int
    device_time_s: float
    host_time_s: float
    exposure_us: float
    bits: int = 8
    chip: int | None = None

    @property
    def full_scale(self) -> int:
        """Largest raw value a pixel can take, in DN."""
        return (1 << self.bits) - 1


@dataclass(frozen=True)
class WindowFrames:
    """The raw sub-frames a map was summed from, oldest first, with their signs (±1).

    References to the drivers' own arrays, not copies: kept only for the life of the map,
    so the pipeline can read the time course of a few pixels (its peaks).
    """

    pixels: tuple[npt.NDArray[np.generic], ...]  # (H, W) uint8 or uint16 each, DN
    signs: tuple[int, ...]
    #: the last OFF sub-frame before the window, as (its sequence minus the window's
    #: first, < 0; its pixels), when the demodulator saw it without a gap since
    before: tuple[int, npt.NDArray[np.generic]] | None = None
    #: for a window whose pixels stay in another process (the map process asks the unit):
    #: the frames' values at flat pixel indices, (n, P) float64 DN, the OFF frame before
    #: the window first; ``pixels`` and the pixels of ``before`` are then left empty
    gather: Callable[[npt.NDArray[np.int64]], npt.NDArray[np.float64]] | None = None


@dataclass(frozen=True)
class DistortionMap:
    """The demodulated image: sum over one code period of ``v_i * F_i``.

    Attributes:
        values: (H, W) int16 or int32 signed sums, in DN. A laser pixel holds about
            ``l * N / 2``; background about 0.
        saturated: (H, W) bool, True where any sub-frame of the window was at full scale.
        code_length: N, the number of sub-frames summed.
        first_sequence / last_sequence: sequence numbers of the window's first and last
            sub-frame.
        first_time_s / last_time_s: host timestamps of the first and last sub-frame.
        phase: lag in sub-frames between the intended chip and the strobe actually seen.
        dropped: sub-frames lost since the previous map.
        processing_gain / snr: measured per paper Eq. 5-6 (0.0 when not measured).
        window: the window's raw sub-frames (None for a map read back from a recording).
        exposure_us: the exposure of the window's sub-frames, µs (a window restarts when it
            changes); 0.0 when not known.
    """

    values: npt.NDArray[np.int16] | npt.NDArray[np.int32]
    saturated: npt.NDArray[np.bool_]
    code_length: int
    first_sequence: int
    last_sequence: int
    first_time_s: float
    last_time_s: float
    phase: int = 0
    dropped: int = 0
    processing_gain: float = 0.0
    snr: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)
    window: WindowFrames | None = None
    exposure_us: float = 0.0


class SectorState(enum.IntEnum):
    """What a sector distance means. Only VALID carries a usable distance."""

    VALID = 0
    NO_RETURN = 1  # measured, and nothing within range: free up to z_max
    INVALID = 2  # not measured, stale, too few points, or from a faulted pipeline


@dataclass(frozen=True)
class SectorDistance:
    """The obstacle distance of one angular sector, in the vehicle frame.

    ``distance_m`` and ``sigma_m`` (its 1-σ uncertainty) are meaningful only when
    ``state`` is VALID; they are 0.0 otherwise (never NaN or inf). ``confidence`` is 0..1.
    """

    index: int
    bearing_rad: float
    state: SectorState
    distance_m: float = 0.0
    confidence: float = 0.0
    point_count: int = 0
    sigma_m: float = 0.0


@dataclass(frozen=True)
class Measurement:
    """One output of the pipeline, ready to publish.

    ``newest_time_s`` is the host ``time.monotonic()`` timestamp of the newest sub-frame
    the measurement used; the publisher computes the data age from it. Fields that are
    not known are None (never NaN).
    """

    counter: int
    sectors: tuple[SectorDistance, ...]
    newest_time_s: float
    newest_sequence: int
    nearest: SectorDistance | None = None
    closing_speed_mps: float | None = None
    time_to_collision_s: float | None = None


class UnitState(enum.IntEnum):
    """The state a unit reports in its status frame."""

    INIT = 0
    NEGOTIATING = 1  # claiming a code; laser off
    RUNNING = 2  # strobing its claimed code and measuring
    NO_CODE = 3  # could not claim a code; laser off
    FAULT = 4  # camera or projector fault; laser off
    STOPPED = 5


class FaultBits(enum.IntFlag):
    """Fault bits of the status frame."""

    NONE = 0
    CAMERA_LOST = 0x01
    LASER_FAULT = 0x02
    BUS_ERROR = 0x04
    DEADLINE_MISS = 0x08
    PLAN_CONFLICT = 0x10
    FOREIGN_CODE = 0x20  # sustained interference on our own code
    LOW_SIGNAL = 0x40  # laser energy at the level of the uncompensated remainder delta
    CALIBRATION = 0x80


@dataclass(frozen=True)
class UnitStatus:
    """The content of the cycle status frame. Fractions are 0..1."""

    state: UnitState
    code_row: int  # 1-based Walsh row as in the paper, 0 when none
    code_length: int
    chip_rate_hz: float
    measurement_counter: int
    faults: FaultBits = FaultBits.NONE
    ambient_level: float = 0.0  # mean raw level of the sub-frames, fraction of full scale
    saturated_fraction: float = 0.0
    foreign_code_energy: float = 0.0  # energy of other codes, fraction of own line energy
    dropped_sub_frames: int = 0
    data_age_s: float = 0.0
