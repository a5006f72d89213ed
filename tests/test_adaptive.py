"""Scene assessment and the adaptive N / exposure controllers as pure classes, on
synthetic assessments and maps with known content."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from atris_node import config as cfg
from atris_node.adaptive.assessment import (
    RangeModel,
    SceneAssessment,
    assess,
    laser_level_dn,
    motion_energy,
    peak_level,
)
from atris_node.adaptive.controller import (
    AdaptiveController,
    CodeLengthController,
    CodeLengthSettings,
    ExposureController,
    ExposureSettings,
    controller_from_config,
    withheld,
)
from atris_node.errors import ConfigError
from atris_node.types import DistortionMap, Measurement, SectorDistance, SectorState, SubFrame

SLOTS = 1000
#: f b of the simulated 640x400 camera (f = 381.5 px, b = 0.075 m), px m
FOCAL_BASELINE_PX_M = 28.6
#: the pipeline's calibration floor of the row sigma, px
ROW_FLOOR_PX = 0.05


def scene(n: int = 16, snr: float = 10.0, count: int = 500, **changes: object
          ) -> SceneAssessment:
    """An assessment with ``count`` of SLOTS places at ``snr``, each with a range and the
    fit sigma of a 1.5 px stripe at that SNR (CRLB 1.30 px / SNR)."""
    base = SceneAssessment(n, 1000.0, 0.2, 0.6, 0.0, (snr,), np.full(count, snr, np.float32),
                           SLOTS, 20.0, 10.0, 0.0, 0.0, row_sigma_px=1.30 / snr,
                           row_floor_px=ROW_FLOOR_PX, focal_baseline_px_m=FOCAL_BASELINE_PX_M,
                           valid_samples=count)
    return replace(base, **changes)  # type: ignore[arg-type]


def dmap(values: np.ndarray) -> DistortionMap:
    return DistortionMap(values.astype(np.int16), np.zeros(values.shape, bool), 8, 0, 7,
                         0.0, 0.0)


def controller(n: int = 16, **settings: object) -> CodeLengthController:
    return CodeLengthController(CodeLengthSettings(**{"target_snr": 8.0, "share": 0.2,
                                                      **settings}), n)  # type: ignore[arg-type]


# ------------------------------------------------------------------ assessment
def test_feature_laser_level_from_signal_and_delta() -> None:
    # I_S = l N / 2 + delta with l = 5, N = 16, delta = 4
    assert laser_level_dn(44.0, 4.0, 16) == pytest.approx(5.0)
    assert laser_level_dn(0.0, 4.0, 16) == 0.0
    assert scene(16, laser_dn=5.0, delta_dn=4.0).model_snr == pytest.approx(11.0)


def test_feature_share_counts_places_and_scales_with_gain() -> None:
    a = scene(snr=10.0, count=300)
    assert a.share_above(8.0) == pytest.approx(0.3)
    assert a.share_above(8.0, gain=0.7) == 0.0


def test_feature_motion_energy_of_gray_trails() -> None:
    rng = np.random.default_rng(0)
    still = rng.normal(0, 3, (64, 256))
    still[30:32] += 300.0  # a laser line only adds
    assert motion_energy(dmap(still)) < 0.01
    trail = still.copy()
    trail[10:20] -= 200.0  # a moving edge leaves a negative band
    assert motion_energy(dmap(trail)) > 0.5


def test_feature_peak_level_of_plain_sub_frame() -> None:
    pixels = np.full((40, 100), 511, np.uint16)
    sub = SubFrame(pixels, 0, 0.0, 0.0, 100.0, bits=10)
    assert peak_level(sub) == pytest.approx(511 / 1023)
    assert peak_level(None) == 0.0


# ------------------------------------------------------------------ code length
def test_feature_grows_only_after_grow_frames_below_target() -> None:
    c = controller(16, grow_frames=2)
    poor = scene(16, snr=7.0)
    assert c.observe(poor) is None
    assert c.observe(poor) == 32


def test_feature_growth_capped_at_max_length() -> None:
    c = controller(32, grow_frames=1, max_length=32)
    assert c.observe(scene(32, count=0)) is None


def test_feature_shrinks_to_shortest_predicted_length_after_shrink_frames() -> None:
    c = controller(32, shrink_frames=3)
    # share 0.5 at SNR 40: at N=4 the gain is (4/32)**0.5 = 0.354 -> 14.1 >= 8
    rich = scene(32, snr=40.0, count=500)
    assert [c.observe(rich) for _ in range(3)] == [None, None, 4]


def test_feature_hysteresis_keeps_n_when_margin_is_small() -> None:
    # at N=8 the predicted share is exactly the target share: not enough to shrink
    edge = scene(16, snr=8.5 / 0.7071, count=200)  # 8.5 at N=8: share 0.2 there
    c = controller(16, shrink_frames=1, hysteresis=0.25)
    assert all(c.observe(edge) is None for _ in range(10))
    assert controller(16, shrink_frames=1, hysteresis=0.0).observe(edge) == 8


def test_feature_frames_of_another_n_are_ignored() -> None:
    c = controller(16, grow_frames=1)
    assert c.observe(scene(8, count=0)) is None
    c.follow(8)
    assert c.observe(scene(8, count=0)) == 16


def test_exception_bad_settings() -> None:
    with pytest.raises(ConfigError, match="min_length"):
        CodeLengthSettings(min_length=64, max_length=32)
    with pytest.raises(ConfigError, match="column_share"):
        CodeLengthSettings(share=0.0)
    with pytest.raises(ConfigError, match="peak_target"):
        ExposureSettings(peak_low=0.8, peak_target=0.7)


# ------------------------------------------------------------------ error bound
def test_feature_range_sigma_predicted_from_row_sigma() -> None:
    a = scene(16, snr=40.0)  # fit sigma 1.30 / 40 = 0.0325 px, floor 0.05 px
    expected = 5.0**2 * np.hypot(0.0325, ROW_FLOOR_PX) / FOCAL_BASELINE_PX_M
    assert a.range_sigma_m(5.0) == pytest.approx(expected)
    # half the SNR doubles only the fit's part; the calibration floor stays
    assert a.range_sigma_m(5.0, gain=0.5) == pytest.approx(
        25.0 * np.hypot(0.065, ROW_FLOOR_PX) / FOCAL_BASELINE_PX_M)
    assert scene(valid_samples=0).range_sigma_m(5.0) is None
    assert scene(focal_baseline_px_m=0.0).range_sigma_m(5.0) is None


def test_feature_assessment_keeps_median_row_sigma_of_valid_samples() -> None:
    values = np.zeros((40, 64))
    ranges = RangeModel(np.array([0.1, 0.2, 0.3, np.nan], np.float32), 0.05, 28.6)
    a = assess(dmap(values), np.full(4, 9.0, np.float32), (9.0,), 0.0, None, ranges)
    assert a.row_sigma_px == pytest.approx(0.2) and a.valid_samples == 3
    assert a.row_floor_px == 0.05 and a.focal_baseline_px_m == pytest.approx(28.6)
    empty = assess(dmap(values), np.zeros(0, np.float32), (0.0,), 0.0, None,
                   RangeModel(np.zeros(0, np.float32), 0.05, 28.6))
    assert empty.valid_samples == 0 and empty.range_sigma_m(5.0) is None


def test_feature_never_shrinks_past_the_error_bound() -> None:
    # SNR 40 at N = 16: the share rule alone would go to N = 4 (SNR 20 there); the range
    # sigma at 5 m is predicted 0.059 m at N = 8 and 0.072 m at N = 4
    rich = scene(16, snr=40.0)
    assert controller(16, shrink_frames=1).observe(rich) == 4
    assert controller(16, shrink_frames=1, max_range_sigma_m=0.065).observe(rich) == 8
    tight = controller(16, shrink_frames=1, max_range_sigma_m=0.05)  # 0.052 m at N = 16
    assert all(tight.observe(rich) is None for _ in range(10))


def test_feature_no_shrink_without_a_range_prediction() -> None:
    c = controller(32, shrink_frames=1)
    assert all(c.observe(scene(32, snr=40.0, valid_samples=0)) is None for _ in range(10))


def test_feature_grows_when_measured_range_sigma_exceeds_bound_with_margin() -> None:
    rich = scene(16, snr=40.0)  # 0.052 m at 5 m: share met, but over 0.03 * 1.25
    c = controller(16, grow_frames=2, max_range_sigma_m=0.03)
    assert [c.observe(rich), c.observe(rich)] == [None, 32]
    inside = controller(16, grow_frames=1, max_range_sigma_m=0.045)  # 0.052 < 0.056
    assert inside.observe(rich) is None


def test_exception_bad_error_bound() -> None:
    with pytest.raises(ConfigError, match="max_range_sigma_m"):
        CodeLengthSettings(max_range_sigma_m=0.0)
    with pytest.raises(ConfigError, match="sigma_range_m"):
        CodeLengthSettings(sigma_range_m=float("nan"))
    with pytest.raises(ConfigError, match=r"adaptive\.max_range_sigma_m"):
        cfg.load(environ={}, overrides=["adaptive.max_range_sigma_m=-1"])
    with pytest.raises(ConfigError, match="low_signal_clear_frames"):
        AdaptiveController(controller(16), None, 1.0, clear_frames=0)


# ------------------------------------------------------------------ exposure
def test_feature_exposure_halves_when_saturated_and_scales_to_target() -> None:
    e = ExposureController(ExposureSettings(min_us=10.0, max_us=4000.0))
    assert e.observe(scene(exposure_us=1000.0, saturated_fraction=0.01)) == 500.0
    e.follow(500.0)
    assert e.observe(scene(exposure_us=500.0, peak_level=0.2)) == pytest.approx(1750.0)
    e.follow(1750.0)
    assert e.observe(scene(exposure_us=1750.0, peak_level=0.6)) is None


def test_feature_exposure_clamped_and_other_exposures_ignored() -> None:
    e = ExposureController(ExposureSettings(min_us=10.0, max_us=4000.0), 20.0)
    assert e.observe(scene(exposure_us=20.0, peak_level=1.0)) == pytest.approx(14.0)
    e.follow(10.0)
    assert e.observe(scene(exposure_us=10.0, saturated_fraction=0.5)) is None  # at min
    assert e.observe(scene(exposure_us=20.0, peak_level=0.01)) is None  # an old frame


# ------------------------------------------------------------------ together
def test_feature_low_signal_when_laser_at_delta() -> None:
    c = AdaptiveController(controller(16), None, low_signal_ratio=1.0)
    assert c.on_frame(scene(laser_dn=5.0, delta_dn=6.0)).low_signal
    assert not c.on_frame(scene(laser_dn=20.0, delta_dn=6.0)).low_signal


def test_feature_low_signal_holds_until_clear_frames_in_a_row() -> None:
    c = AdaptiveController(controller(16), None, low_signal_ratio=1.0, clear_frames=3)
    low, good = scene(laser_dn=5.0, delta_dn=6.0), scene(laser_dn=20.0, delta_dn=6.0)
    assert not c.on_frame(good).low_signal  # no LOW_SIGNAL seen yet: nothing held
    verdicts = [c.on_frame(a).low_signal for a in (low, good, good, low, good, good, good)]
    # one or two good frames after a low one are no evidence; the third clears it
    assert verdicts == [True, True, True, True, True, True, False]


def test_feature_exposure_change_defers_n_decision() -> None:
    c = AdaptiveController(controller(16, grow_frames=1), ExposureController(
        ExposureSettings()), 1.0)
    d = c.on_frame(scene(count=0, peak_level=0.1))
    assert d.exposure_us is not None and d.code_length is None


def test_feature_withheld_measurement_has_no_distance() -> None:
    m = Measurement(1, (SectorDistance(0, 0.0, SectorState.VALID, 2.0, 0.9, 20),), 0.0, 7,
                    nearest=SectorDistance(0, 0.0, SectorState.VALID, 2.0, 0.9, 20))
    out = withheld(m)
    assert out.nearest is None
    assert out.sectors[0].state is SectorState.INVALID and out.sectors[0].distance_m == 0.0


def test_feature_off_by_default_and_built_from_config() -> None:
    assert controller_from_config(cfg.defaults(), 240.0) is None
    on = cfg.defaults().with_values({"adaptive.enabled": True, "code.max_length": 16},
                                    "test")
    built = controller_from_config(on, 240.0)
    assert built is not None and built.code.settings.max_length == 16
    assert built.exposure is not None and built.exposure.settings.max_us < 1e6 / 240.0
    assert built.code.settings.max_range_sigma_m == 0.15
    assert built.code.settings.sigma_range_m == 5.0 and built.clear_frames == 2
