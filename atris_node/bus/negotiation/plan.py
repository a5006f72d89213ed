"""The code plan units agree on, its code sets, and what a misaligned chip clock leaks.

Units protect each other only when they share the code length N, the chip (sub-frame)
rate and the mode (DESIGN §2): the :class:`Plan` is the thing the negotiation agrees on.
Code sets come from :mod:`atris_node.codes` when it is there; the Table 1 rule is computed
here otherwise, so negotiation never depends on import order.

Example:
    >>> plan = Plan(code_length=16, chip_rate_hz=480.0)
    >>> plan_code_rows(plan)
    (2, 3, 5, 9)
    >>> grow_to_fit(plan, 5, max_code_length=128).code_length
    32
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from atris_node.errors import CodeError, ConfigError

MODES = ("async", "sync")
MIN_CODE_LENGTH = 2
MAX_CODE_LENGTH = 128
#: the PLAN frame carries the chip rate as an unsigned 32-bit count of millihertz
MAX_CHIP_RATE_HZ = (2**32 - 1) / 1000.0


def _check_code_length(code_length: int) -> None:
    if not (MIN_CODE_LENGTH <= code_length <= MAX_CODE_LENGTH
            and code_length & (code_length - 1) == 0):
        raise CodeError(f"code length must be a power of two in [{MIN_CODE_LENGTH}, "
                        f"{MAX_CODE_LENGTH}], got {code_length}")


@dataclass(frozen=True)
class Plan:
    """What all units on one bus must share to be mutually orthogonal.

    Attributes:
        code_length: N, chips (sub-frames) per code period; a power of two, 2..128.
        chip_rate_hz: sub-frames per second; kept to the millihertz the PLAN frame carries.
        mode: ``"async"`` (cyclic orthogonal set, log2 N codes, any clock phase) or
            ``"sync"`` (all N - 1 non-constant Walsh rows; needs sub-frames aligned to SYNC).
    """

    code_length: int
    chip_rate_hz: float
    mode: str = "async"

    def __post_init__(self) -> None:
        _check_code_length(self.code_length)
        if self.mode not in MODES:
            raise ConfigError(f"plan mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        rate = self.chip_rate_hz
        if not (math.isfinite(rate) and 0.0 < rate <= MAX_CHIP_RATE_HZ):
            raise ConfigError(f"plan chip_rate_hz must be in (0, {MAX_CHIP_RATE_HZ}] Hz, "
                              f"got {rate!r}")
        object.__setattr__(self, "chip_rate_hz", round(rate * 1000.0) / 1000.0)

    @property
    def chip_rate_mhz(self) -> int:
        """Chip rate in millihertz, as the PLAN frame carries it."""
        return round(self.chip_rate_hz * 1000.0)

    @property
    def output_rate_hz(self) -> float:
        """Distortion maps per second with block demodulation: chip rate / N."""
        return self.chip_rate_hz / self.code_length

    @property
    def cycle_s(self) -> float:
        """Duration of one code period (N chips), seconds."""
        return self.code_length / self.chip_rate_hz


def _table1_rows(code_length: int, mode: str) -> tuple[int, ...]:
    """Paper Table 1 (one row per highest set bit j, lowest first) or rows 2..N for sync."""
    if mode == "sync":
        return tuple(range(2, code_length + 1))
    return tuple((1 << j) + 1 for j in range(code_length.bit_length() - 1))


@functools.cache
def code_rows(code_length: int, mode: str) -> tuple[int, ...]:
    """1-based Walsh rows a unit may claim for ``code_length`` and ``mode``, lowest first."""
    _check_code_length(code_length)
    try:
        from atris_node.codes import code_set
    except ImportError:
        return _table1_rows(code_length, mode)
    return tuple(int(row) for row in code_set(code_length, mode))


def plan_code_rows(plan: Plan) -> tuple[int, ...]:
    """The code rows of ``plan``, lowest first."""
    return code_rows(plan.code_length, plan.mode)


def capacity(plan: Plan) -> int:
    """How many units ``plan`` can give a code to."""
    return len(plan_code_rows(plan))


def grow_to_fit(plan: Plan, units: int, max_code_length: int) -> Plan:
    """The plan with the shortest N >= ``plan.code_length`` that fits ``units`` units.

    Returns the longest allowed N when none fits (the extra units then send cannot-claim).
    """
    code_length = plan.code_length
    while capacity(Plan(code_length, plan.chip_rate_hz, plan.mode)) < units:
        if code_length * 2 > min(max_code_length, MAX_CODE_LENGTH):
            break
        code_length *= 2
    return Plan(code_length, plan.chip_rate_hz, plan.mode)
