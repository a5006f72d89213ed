"""A peak's time course over the window: own strobed light, or ambient light that changed.

Synthetic windows of 64 columns × 40 rows: a dark scene with sensor noise, one own stripe
on row 10 (lit on the ON sub-frames only, still or moving) and, on row 30, ambient light
that changes during the window (an edge that moves: a step, or a linear ramp). The
demodulated sum of both is a strong peak; only the own stripe may stay.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from atris_node.codes import bipolar, walsh_chips
from atris_node.pipeline.noise import noise_map
from atris_node.pipeline.temporal import not_own_light, off_projection, trend_weights
from atris_node.types import WindowFrames

HEIGHT, WIDTH = 40, 64
STRIPE_ROW, EDGE_ROW = 10, 30
ALTERNATING = 2  # Walsh row 2 of H_16 (Sylvester order): 1 0 1 0 ...


def window(signs: np.ndarray, ambient: np.ndarray, stripe: np.ndarray,
           seed: int = 0) -> tuple[WindowFrames, np.ndarray]:
    """Sub-frames (uint16) with ``ambient[i]`` on EDGE_ROW and ``stripe[i]`` added to
    STRIPE_ROW on sub-frame i, both per column; and the demodulated sum."""
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(signs.size):
        frame = 100.0 + rng.normal(0.0, 3.0, (HEIGHT, WIDTH))
        frame[EDGE_ROW] += ambient[i]
        frame[STRIPE_ROW] += stripe[i]
        frames.append(np.clip(np.rint(frame), 0, 1023).astype(np.uint16))
    values = sum(int(s) * f.astype(np.int32) for s, f in zip(signs, frames, strict=True))
    return WindowFrames(tuple(frames), tuple(int(s) for s in signs)), np.asarray(values)


def rejected(signs: np.ndarray, ambient: np.ndarray, stripe: np.ndarray) -> tuple[bool, bool]:
    """Whether the stripe peak and the edge peak are set aside (every column agrees)."""
    frames, values = window(signs, ambient, stripe)
    peaks = np.full((2, WIDTH), -1, dtype=np.int64)
    peaks[0], peaks[1] = STRIPE_ROW, EDGE_ROW
    out = not_own_light(peaks, values, frames, noise_map(values, [(0, HEIGHT)]))
    assert out[0].all() or not out[0].any(), "columns disagree on the stripe"
    assert out[1].all() or not out[1].any(), "columns disagree on the edge"
    return bool(out[0, 0]), bool(out[1, 0])


def alternating() -> np.ndarray:
    return bipolar(walsh_chips(16, ALTERNATING)).astype(np.int64)


def test_feature_the_alternating_code_has_a_trend_margin_the_half_code_none() -> None:
    _, margin, noise = trend_weights(tuple(alternating()))
    assert margin == pytest.approx(1.0 - 15.0 * 16.0 / 1360.0)  # 0.82
    assert noise == pytest.approx(math.sqrt(1.0 - 256.0 / (16 * 1360.0)), rel=1e-9)
    half = tuple([1] * 8 + [-1] * 8)
    assert trend_weights(half)[1] < 0.0  # the trend test cannot tell: not run


def test_feature_a_linear_change_leaves_nothing_after_de_trending() -> None:
    signs = alternating()
    weights, _, _ = trend_weights(tuple(signs))
    ramp = 50.0 + 7.0 * np.arange(16)
    assert abs(float(signs @ ramp)) > 50.0  # the plain sum keeps a residual
    assert float(weights @ ramp) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("course", ["still", "first ON only", "last ON only", "moving in"])
def test_feature_own_light_of_any_course_stays(course: str) -> None:
    """Own light is on ON sub-frames only, whatever it does there: a stripe that is still,
    that crosses the pixel within one sub-frame (fast, near), or that moves in."""
    signs = alternating()
    on = signs > 0
    light = {"still": np.where(on, 300.0, 0.0),
             "first ON only": np.where(np.arange(16) == 0, 900.0, 0.0),
             "last ON only": np.where(np.arange(16) == 14, 900.0, 0.0),
             "moving in": np.where(on, 40.0 * np.arange(16), 0.0)}[course]
    stripe_out, _ = rejected(signs, np.zeros(16), light)
    assert not stripe_out


@pytest.mark.parametrize("change", ["step at sub-frame 5", "step at sub-frame 15", "ramp"])
def test_feature_ambient_light_that_changes_is_set_aside(change: str) -> None:
    """The sky above an approaching car's roof: bright until the edge passes the pixel,
    dark after (a step), or a soft edge passing (a ramp). The plain sum leaves a peak as
    strong as a line; the time course says it is not own light.

    Checked by making ``not_own_light`` return no rejection: all three cases failed."""
    signs = alternating()
    i = np.arange(16)
    ambient = {"step at sub-frame 5": np.where(i < 5, 400.0, 0.0),
               "step at sub-frame 15": np.where(i < 15, 400.0, 0.0),
               "ramp": 30.0 * (15 - i)}[change]
    _, values = window(signs, ambient, np.zeros(16))
    assert values[EDGE_ROW].mean() > 100.0, "no residual peak: proves nothing"
    _, edge_out = rejected(signs, ambient, np.where(signs > 0, 300.0, 0.0))
    assert edge_out


def test_feature_a_step_after_the_first_sub_frame_needs_the_sub_frame_before() -> None:
    """Ambient that drops right after an ON first sub-frame looks, inside the window,
    exactly like own light seen on that sub-frame alone. The last OFF sub-frame before the
    window (still bright: the edge had not passed) tells them apart; without it (the first
    window after a gap) the peak passes as own light.

    Checked by leaving ``before`` out of the OFF sub-frames' fit: the edge was kept."""
    signs = alternating()
    ambient = np.where(np.arange(16) < 1, 400.0, 0.0)
    frames, values = window(signs, ambient, np.where(signs > 0, 300.0, 0.0))
    peaks = np.full((2, WIDTH), -1, dtype=np.int64)
    peaks[0], peaks[1] = STRIPE_ROW, EDGE_ROW
    local = noise_map(values, [(0, HEIGHT)])
    assert not not_own_light(peaks, values, frames, local).any()
    bright = frames.pixels[1].copy()  # an OFF sub-frame, the sky on EDGE_ROW: no edge yet
    bright[EDGE_ROW] = frames.pixels[0][EDGE_ROW]
    with_before = WindowFrames(frames.pixels, frames.signs, (-1, bright))
    out = not_own_light(peaks, values, with_before, local)
    assert out[1].all() and not out[0].any()
    dark = frames.pixels[1].copy()  # own light on sub-frame 0: ambient was dark before
    own = WindowFrames(frames.pixels, frames.signs, (-1, dark))
    assert not not_own_light(peaks, values, own, local).any()


def test_feature_without_the_window_nothing_is_set_aside() -> None:
    signs = alternating()
    _, values = window(signs, np.where(np.arange(16) < 6, 400.0, 0.0), np.zeros(16))
    peaks = np.full((1, WIDTH), EDGE_ROW, dtype=np.int64)
    out = not_own_light(peaks, values, None, noise_map(values, [(0, HEIGHT)]))
    assert not out.any()


def test_feature_a_map_without_peaks_sets_nothing_aside() -> None:
    """A map where no column holds a peak (a blank scene, or every peak removed as
    isolated): an empty answer, not an error (a numpy quantile of nothing raised before)."""
    signs = alternating()
    frames, values = window(signs, np.zeros(16), np.zeros(16))
    local = noise_map(values, [(0, HEIGHT)])
    for peaks in (np.full((3, WIDTH), -1, dtype=np.int64), np.zeros((0, WIDTH), np.int64)):
        assert not not_own_light(peaks, values, frames, local).any()


def test_feature_the_off_projection_needs_three_off_sub_frames() -> None:
    assert off_projection((1, -1, 1, -1))[1] is None
    assert off_projection((1, -1, 1, -1), before=-1)[1] is not None
    off, projection = off_projection((1, -1) * 4)
    assert off.sum() == 4 and projection is not None
    line = 3.0 + 2.0 * np.flatnonzero(off)
    assert np.allclose(projection @ line, 0.0)


def test_feature_the_moving_roof_edge_of_an_approaching_car_makes_no_phantom() -> None:
    """approach_2mps, noise seed 11, first map: the sky edge above the car (3.84 m) moves
    during the window and its residual completed a comb one line off, publishing the car
    at 1.03 m (two sectors VALID). With the time course checked, neither is.

    Checked by making ``not_own_light`` return no rejection: two near phantoms."""
    from atris_node.bench.safety import score_scene

    row = score_scene("approach_2mps", 1, seed=11).row()
    assert row["near_phantom"] == row["far"] == row["false_free"] == 0
