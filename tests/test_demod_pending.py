"""Maps built when taken (``push_pending``): the same maps as ``push`` gives at once.

Promises:
- every map taken from a pending map, late and after further sub-frames were pushed, has
  the values, saturation mask, gain, SNR, ambient level, saturated fraction, phase,
  dropped count, exposure and window of the map ``push`` returns for that window, to the
  bit: over a few hundred sub-frames of two simulated scenes with a gap, saturated
  sub-frames and an exposure change, sliding and block, lag known and locked;
- a map's gain and SNR are those :func:`measure_gain` gives for its values, and its
  ambient level that of the strips of its own sub-frames.
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Iterator

import numpy as np
import pytest

from atris_node.codes import walsh_chips
from atris_node.demod import (
    BlockDemodulator,
    PendingMap,
    SlidingDemodulator,
    measure_gain,
    strip_level,
)
from atris_node.sim import Simulator, load_scene
from atris_node.types import DistortionMap, SubFrame

Demod = type[BlockDemodulator] | type[SlidingDemodulator]
SUB_FRAMES = 320


def sub_frames(scene_name: str, count: int) -> tuple[np.ndarray, int, list[SubFrame]]:
    """``count`` sub-frames of a scene, three of them dropped (a gap), some with a
    saturated patch, the exposure halved from sub-frame 260 on."""
    scene = load_scene(scene_name)
    chips = walsh_chips(scene.code_length, scene.code_row)
    sim = Simulator(scene, chips=chips, seed=1)
    subs = []
    for sequence in range(count):
        if sequence in (150, 151, 152):
            continue
        sub = sim.render(sequence)
        if 200 <= sequence < 230 and sequence % 3 == 0:
            pixels = sub.pixels.copy()
            pixels[100:140, 50:300] = sub.full_scale
            sub = dataclasses.replace(sub, pixels=pixels)
        if sequence >= 260:
            sub = dataclasses.replace(sub, exposure_us=sub.exposure_us * 0.5)
        subs.append(sub)
    return chips, scene.camera.bits, subs


def assert_same_map(a: DistortionMap, b: DistortionMap) -> None:
    assert np.array_equal(a.values, b.values) and a.values.dtype == b.values.dtype
    assert np.array_equal(a.saturated, b.saturated)
    for name in ("code_length", "first_sequence", "last_sequence", "first_time_s",
                 "last_time_s", "phase", "dropped", "processing_gain", "snr", "extra",
                 "exposure_us"):
        assert getattr(a, name) == getattr(b, name), name
    assert (a.window is None) == (b.window is None)
    if a.window is not None and b.window is not None:
        assert a.window.signs == b.window.signs
        assert all(x is y for x, y in zip(a.window.pixels, b.window.pixels, strict=True))
        assert (a.window.before is None) == (b.window.before is None)
        if a.window.before is not None and b.window.before is not None:
            assert a.window.before[0] == b.window.before[0]
            assert a.window.before[1] is b.window.before[1]


def taken_late(demod: SlidingDemodulator | BlockDemodulator,
               subs: list[SubFrame]) -> Iterator[DistortionMap]:
    """Push every sub-frame, keep every fifth pending map and take it three sub-frames
    later (as the map thread does); the others are dropped untaken."""
    held: collections.deque[PendingMap] = collections.deque()
    for i, sub in enumerate(subs):
        pending = demod.push_pending(sub)
        if pending is not None and i % 5 == 0:
            held.append(pending)
        while held and held[0].last_sequence <= sub.sequence - 3:
            yield held.popleft().take()
    yield from (p.take() for p in held)


@pytest.mark.parametrize("kind", [SlidingDemodulator, BlockDemodulator])
@pytest.mark.parametrize("lag", [0, None])
@pytest.mark.parametrize("scene_name", ["parking_pedestrian", "indoor_lab"])
def test_maps_taken_late_are_those_pushed_at_once(kind: Demod, lag: int | None,
                                                  scene_name: str) -> None:
    chips, bits, subs = sub_frames(scene_name, SUB_FRAMES)
    demod = kind(chips, bits=bits, lag=lag)
    eager = [m for m in (demod.push(s) for s in subs) if m is not None]
    late = list(taken_late(kind(chips, bits=bits, lag=lag), subs))
    by_last = {m.last_sequence: m for m in eager}
    assert len(late) >= len(eager) // 6
    for m in late:  # all taken only now: a reused buffer would show here
        assert_same_map(m, by_last[m.last_sequence])
    assert any(m.extra["saturated_fraction"] > 0 for m in eager)
    assert any(m.dropped == 3 for m in eager)


@pytest.mark.parametrize("lag", [0, None])
def test_measures_of_a_map_are_those_of_its_values(lag: int | None) -> None:
    chips, bits, subs = sub_frames("parking_pedestrian", 120)
    demod = SlidingDemodulator(chips, bits=bits, lag=lag)
    maps = [m for m in (demod.push(s) for s in subs) if m is not None]
    assert maps
    for m in maps:
        gain, snr, signal, residual = measure_gain(m.values, m.code_length)
        assert (m.processing_gain, m.snr) == (gain, snr)
        assert (m.extra["signal_dn"], m.extra["residual_dn"]) == (signal, residual)
        assert m.window is not None
        levels = {strip_level(p) / subs[0].full_scale for p in m.window.pixels}
        if lag is None:  # locked: the mean of the window's own levels
            assert m.extra["ambient_level"] == pytest.approx(
                np.mean([strip_level(p) for p in m.window.pixels]) / subs[0].full_scale)
        else:  # known lag: one of its sub-frames, refreshed once per N
            assert m.extra["ambient_level"] in levels
