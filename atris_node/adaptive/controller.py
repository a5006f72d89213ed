"""Scene-adaptive operation (issue 11): code length N and exposure from per-frame
assessments. Pure classes fed with :class:`~atris_node.adaptive.assessment.SceneAssessment`;
no I/O. The node applies their decisions (``Negotiator.request_plan``,
``Camera.set_exposure_us``); see docs/adaptive.md.

Code length. The SNR of a line sample grows with N as ``(N' / N) ** (1 - gamma)``: the
paper's Eq. 6 (``SNR = l N / (2 delta) + 1``, delta constant) is ``gamma = 0``; when the
remainder delta is shot and read noise summed over N sub-frames, ``gamma = 0.5``. The
controller wants ``share`` of the line-column places with an SNR of at least ``target``:

- below the share for ``grow_frames`` frames in a row: double N (up to ``max_length``);
- the share predicted at a shorter N reaches ``share * (1 + hysteresis)`` for
  ``shrink_frames`` frames in a row: the shortest such N (down to ``min_length``).

Error bound. N never shrinks to a length whose predicted range sigma at the range that
matters, ``sigma_z(N') = z_ref^2 hypot(sigma_fit / g, sigma_cal) / (f b)`` with
``g = (N' / N) ** (1 - gamma)`` (see :meth:`SceneAssessment.range_sigma_m`), exceeds
``max_range_sigma_m``; a frame without a valid sample predicts nothing and shrinks
nothing. A measured ``sigma_z(N)`` above ``max_range_sigma_m * (1 + hysteresis)`` counts
as a frame below target (N grows).

Frames of another N or exposure than the newest decision are ignored, so a decision is
only ever taken on maps of the plan in force.

Exposure. The brightest ambient (``peak_level``) is kept in ``[peak_low, peak_high]`` by
scaling the exposure to ``peak_target``; any saturated pixel counts as too bright. The
exposure stays in ``[min_us, max_us]``.

Low signal. When the laser level per sub-frame ``l`` falls to ``low_signal_ratio * delta``
(the paper's strong-sunlight limit) the decision says ``low_signal``: the unit reports
``FaultBits.LOW_SIGNAL`` and publishes no distance from that frame, nor from the frames
after it until ``clear_frames`` frames in a row were above the limit (one lucky frame in
strong sun is no evidence).

Interference analysis only where someone strobes: :func:`used_chips` keeps the own row
and the plan's rows claimed on the bus or known in the scene.

Example:
    >>> c = CodeLengthController(CodeLengthSettings(target_snr=8.0, share=0.2), 16)
    >>> c.code_length
    16
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from atris_node.adaptive.assessment import SceneAssessment
from atris_node.config import Config
from atris_node.errors import check_setting
from atris_node.types import Measurement, SectorState

logger = logging.getLogger(__name__)

Chips = Sequence[int] | npt.NDArray[np.integer]


def _check(ok: bool, name: str, value: object, accepted: str) -> None:
    check_setting(ok, f"adaptive.{name}", value, accepted)


def _power_of_two(value: int) -> bool:
    return value >= 2 and value & (value - 1) == 0


@dataclass(frozen=True)
class CodeLengthSettings:
    """Target line SNR on a share (0..1) of line-column places; N limits (powers of
    two); persistence in output frames; hysteresis (fraction) and noise exponent gamma;
    the error bound: the largest range sigma (m) predicted at ``sigma_range_m`` (m)."""

    target_snr: float = 8.0
    share: float = 0.2
    min_length: int = 4
    max_length: int = 32
    grow_frames: int = 2
    shrink_frames: int = 4
    hysteresis: float = 0.25
    noise_exponent: float = 0.5
    max_range_sigma_m: float = 0.15
    sigma_range_m: float = 5.0

    def __post_init__(self) -> None:
        _check(self.target_snr > 1.0, "snr_target", self.target_snr, "> 1")
        _check(0.0 < self.share <= 1.0, "column_share", self.share, "in (0, 1]")
        for name in ("min_length", "max_length"):
            _check(_power_of_two(getattr(self, name)), name, getattr(self, name),
                   "a power of two >= 2")
        _check(self.min_length <= self.max_length, "min_length", self.min_length,
               f"at most max_length ({self.max_length})")
        for name in ("grow_frames", "shrink_frames"):
            _check(getattr(self, name) >= 1, name, getattr(self, name), "an integer >= 1")
        _check(self.hysteresis >= 0.0, "hysteresis", self.hysteresis, ">= 0")
        _check(0.0 <= self.noise_exponent < 1.0, "noise_exponent", self.noise_exponent,
               "in [0, 1)")
        for name in ("max_range_sigma_m", "sigma_range_m"):
            value = getattr(self, name)
            _check(math.isfinite(value) and value > 0.0, name, value, "a finite number > 0 (m)")

    def lengths(self) -> tuple[int, ...]:
        """The allowed code lengths, shortest first."""
        out, n = [], self.min_length
        while n <= self.max_length:
            out.append(n)
            n *= 2
        return tuple(out)


class CodeLengthController:
    """Chooses N from assessments, with hysteresis (see the module docstring)."""

    def __init__(self, settings: CodeLengthSettings, code_length: int) -> None:
        self.settings = settings
        self.code_length = code_length
        self._low = self._high = 0
        self._shrink_to: int | None = None

    def gain(self, code_length: int) -> float:
        """SNR factor from the current N to ``code_length``."""
        ratio = code_length / self.code_length
        return float(ratio ** (1.0 - self.settings.noise_exponent))

    def follow(self, code_length: int) -> None:
        """The plan in force is ``code_length`` (ours or the bus's): restart the counts."""
        if code_length != self.code_length:
            self.code_length = code_length
            self._low = self._high = 0

    def observe(self, a: SceneAssessment) -> int | None:
        """A new N to ask the bus for, or None (keep). Frames of another N are ignored."""
        if a.code_length != self.code_length:
            return None
        s = self.settings
        if a.share_above(s.target_snr) < s.share or self._over_bound(a):
            self._high = 0
            self._low += 1
            return self._grow() if self._low >= s.grow_frames else None
        self._low = 0
        return self._maybe_shrink(a)

    def predicted_sigma_m(self, a: SceneAssessment, code_length: int) -> float | None:
        """Range sigma (m) at ``sigma_range_m`` predicted at ``code_length`` from ``a``."""
        return a.range_sigma_m(self.settings.sigma_range_m, self.gain(code_length))

    def within_bound(self, a: SceneAssessment, code_length: int) -> bool:
        """True when ``a`` predicts a range sigma within the bound at ``code_length``
        (False without a prediction: no valid sample)."""
        sigma = self.predicted_sigma_m(a, code_length)
        return sigma is not None and sigma <= self.settings.max_range_sigma_m

    def _over_bound(self, a: SceneAssessment) -> bool:
        """The range sigma measured at the current N exceeds the bound by the margin."""
        sigma = self.predicted_sigma_m(a, self.code_length)
        limit = self.settings.max_range_sigma_m * (1.0 + self.settings.hysteresis)
        return sigma is not None and sigma > limit

    def _grow(self) -> int | None:
        longer = min(self.code_length * 2, self.settings.max_length)
        self._low = 0
        return longer if longer > self.code_length else None

    def _maybe_shrink(self, a: SceneAssessment) -> int | None:
        s = self.settings
        wanted = s.share * (1.0 + s.hysteresis)
        shorter = [n for n in s.lengths() if n < self.code_length
                   and a.share_above(s.target_snr, self.gain(n)) >= wanted
                   and self.within_bound(a, n)]
        if not shorter or shorter[0] != self._shrink_to:
            self._shrink_to, self._high = (shorter[0] if shorter else None), 0
        if self._shrink_to is None:
            return None
        self._high += 1
        return self._shrink_to if self._high >= s.shrink_frames else None


@dataclass(frozen=True)
class ExposureSettings:
    """Exposure band of the brightest ambient (fractions of full scale) and limits (µs)."""

    peak_target: float = 0.7
    peak_low: float = 0.4
    peak_high: float = 0.9
    min_us: float = 10.0
    max_us: float = 4000.0
    max_saturated: float = 0.0005

    def __post_init__(self) -> None:
        _check(0.0 < self.peak_low < self.peak_target < self.peak_high <= 1.0, "peak_target",
               (self.peak_low, self.peak_target, self.peak_high),
               "0 < peak_low < peak_target < peak_high <= 1")
        _check(0.0 < self.min_us <= self.max_us and math.isfinite(self.max_us), "min_us",
               (self.min_us, self.max_us), "0 < exposure_min_us <= exposure_max_us")


class ExposureController:
    """Keeps the brightest ambient inside the band; one step per assessment."""

    def __init__(self, settings: ExposureSettings, exposure_us: float | None = None) -> None:
        self.settings = settings
        self.exposure_us = exposure_us  # None: taken from the first assessment

    def follow(self, exposure_us: float) -> None:
        """The exposure in force (after a change took effect)."""
        self.exposure_us = exposure_us

    def observe(self, a: SceneAssessment) -> float | None:
        """A new exposure (µs), or None to keep it. Frames of another exposure are ignored."""
        s = self.settings
        if self.exposure_us is None:
            self.exposure_us = a.exposure_us
        if not math.isclose(a.exposure_us, self.exposure_us, rel_tol=1e-6):
            return None
        if a.saturated_fraction > s.max_saturated:
            scale = 0.5  # clipped: the true peak is unknown, halve
        elif a.peak_level > s.peak_high or a.peak_level < s.peak_low:
            scale = s.peak_target / max(a.peak_level, 0.01)
        else:
            return None
        return self._clamped(self.exposure_us * scale)

    def _clamped(self, exposure_us: float) -> float | None:
        s = self.settings
        new = min(max(exposure_us, s.min_us), s.max_us)
        old = self.exposure_us or 0.0
        return None if math.isclose(new, old, rel_tol=0.02) else new


@dataclass(frozen=True)
class Decision:
    """What one assessment asks for: a new N and/or exposure (None = keep), and whether
    the unit is in LOW_SIGNAL (no distances from this frame): the laser is at the level of
    the remainder delta now, or was within the last ``clear_frames`` frames."""

    code_length: int | None
    exposure_us: float | None
    low_signal: bool


class AdaptiveController:
    """Code length, exposure and the low-signal verdict from per-frame assessments."""

    def __init__(self, code: CodeLengthController, exposure: ExposureController | None,
                 low_signal_ratio: float = 1.0, clear_frames: int = 1) -> None:
        _check(clear_frames >= 1, "low_signal_clear_frames", clear_frames, "an integer >= 1")
        self.code = code
        self.exposure = exposure
        self.low_signal_ratio = low_signal_ratio
        self.clear_frames = clear_frames
        self._above = clear_frames  # frames above the limit since the last low one
        self.last: SceneAssessment | None = None

    def low_signal(self, a: SceneAssessment) -> bool:
        """True when ``l <= low_signal_ratio * delta`` (no laser found counts as 0)."""
        return a.laser_dn <= self.low_signal_ratio * a.delta_dn

    def _withhold(self, a: SceneAssessment) -> bool:
        """LOW_SIGNAL now, or fewer than ``clear_frames`` frames above it since."""
        if self.low_signal(a):
            self._above = 0
        else:
            self._above = min(self._above + 1, self.clear_frames)
        return self._above < self.clear_frames

    def on_frame(self, a: SceneAssessment, plan_length: int | None = None) -> Decision:
        """Feed one assessment; ``plan_length`` is the N of the plan in force (the bus may
        have changed it). Exposure first: a new exposure restarts the window, so no N
        decision is taken on the same frame. The caller applies the decision at once."""
        self.last = a
        logger.debug("scene: %s", a.log_fields())
        if plan_length is not None:
            self.code.follow(plan_length)
        exposure = self.exposure.observe(a) if self.exposure is not None else None
        if exposure is not None and self.exposure is not None:
            self.exposure.follow(exposure)
            logger.info("exposure %.1f -> %.1f us (peak %.3f, saturated %.4f)",
                        a.exposure_us, exposure, a.peak_level, a.saturated_fraction)
        code_length = None if exposure is not None else self.code.observe(a)
        if code_length is not None:
            sigma = self.code.predicted_sigma_m(a, code_length)
            logger.info("code length %d -> %d asked for (range sigma at %.1f m predicted "
                        "%s m; %s)", a.code_length, code_length, self.code.settings.sigma_range_m,
                        "-" if sigma is None else f"{sigma:.3f}", a.log_fields())
        return Decision(code_length, exposure, self._withhold(a))


def withheld(measurement: Measurement) -> Measurement:
    """``measurement`` with every sector INVALID and no nearest / closing speed / TTC:
    what a low-signal frame publishes instead of poor distances."""
    sectors = tuple(replace(s, state=SectorState.INVALID, distance_m=0.0, confidence=0.0)
                    for s in measurement.sectors)
    return replace(measurement, sectors=sectors, nearest=None, closing_speed_mps=None,
                   time_to_collision_s=None)


def controller_from_config(config: Config, rate_hz: float) -> AdaptiveController | None:
    """The controller of the ``adaptive.*`` parameters, or None when adaptation is off.
    ``rate_hz`` (sub-frames/s, 0 = unknown) caps the exposure at 95 % of a period."""
    if not config["adaptive.enabled"]:
        return None
    code = CodeLengthSettings(
        config["adaptive.snr_target"], config["adaptive.column_share"],
        config["adaptive.min_length"], min(config["adaptive.max_length"],
                                           config["code.max_length"]),
        config["adaptive.grow_frames"], config["adaptive.shrink_frames"],
        config["adaptive.hysteresis"], config["adaptive.noise_exponent"],
        config["adaptive.max_range_sigma_m"], config["adaptive.sigma_range_m"])
    period_us = 0.95e6 / rate_hz if rate_hz > 0 else math.inf
    exposure = ExposureController(ExposureSettings(
        min_us=config["adaptive.exposure_min_us"],
        max_us=min(config["adaptive.exposure_max_us"], period_us)))
    return AdaptiveController(CodeLengthController(code, int(config["code.length"])),
                              exposure if config["adaptive.exposure"] else None,
                              config["adaptive.low_signal_ratio"],
                              config["adaptive.low_signal_clear_frames"])


def rows_in_use(plan_rows: Iterable[int], own_row: int, peer_rows: Iterable[int | None],
                scene_rows: Iterable[int] = ()) -> tuple[int, ...]:
    """The plan's rows worth an interference analysis: the own row and those claimed on
    the bus (peers) or known to strobe in the scene (interferers), 1-based, sorted."""
    used = {r for r in (*peer_rows, *scene_rows) if r is not None}
    return tuple(sorted({own_row} | (set(plan_rows) & used)))


def used_chips(chips_by_row: Mapping[int, Chips], own_row: int,
               peer_rows: Iterable[int | None], scene_rows: Iterable[int] = ()
               ) -> dict[int, Chips]:
    """``chips_by_row`` reduced to :func:`rows_in_use`: what an
    :class:`~atris_node.pipeline.interference.InterferenceMeter` needs to be given. Codes nobody
    strobes carry only noise, so leaving them out changes no reported energy."""
    keep = rows_in_use(chips_by_row, own_row, peer_rows, scene_rows)
    return {r: chips_by_row[r] for r in keep}
