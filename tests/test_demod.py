"""Block and sliding demodulation: exact sums, cancellation, overflow, drops, lock, gain."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atris_node import codes
from atris_node.demod import (
    BlockDemodulator,
    Kernels,
    SlidingDemodulator,
    accumulator_dtype,
    measure_gain,
)
from atris_node.errors import CodeError, DemodulationError
from atris_node.types import DistortionMap, SubFrame

DEMODULATORS = (BlockDemodulator, SlidingDemodulator)
Demod = BlockDemodulator | SlidingDemodulator
Pixels = npt.NDArray[np.uint8] | npt.NDArray[np.uint16]


def _sub(pixels: np.ndarray, seq: int, bits: int, exposure_us: float = 100.0) -> SubFrame:
    dtype = np.uint8 if bits == 8 else np.uint16
    return SubFrame(pixels.astype(dtype), seq, seq / 480.0, 1000.0 + seq / 480.0,
                    exposure_us, bits=bits)


def _run(demod: Demod, subs: Iterable[SubFrame]) -> list[DistortionMap]:
    return [m for m in (demod.push(s) for s in subs) if m is not None]


def _window_sum(frames: dict[int, np.ndarray], signs: np.ndarray, lag: int,
                last: int) -> npt.NDArray[np.int64]:
    """Reference: sum of v[(s - lag) % N] F_s over the N sub-frames ending at ``last``."""
    n = signs.size
    return sum(int(signs[(s - lag) % n]) * frames[s].astype(np.int64)
               for s in range(last - n + 1, last + 1))  # type: ignore[return-value]


# --- feature: accumulator dtype and exact sums ----------------------------------------------

DTYPE_TABLE = [
    (128, 8, np.int16), (256, 8, np.int32), (32, 10, np.int16), (64, 10, np.int32),
    (8, 12, np.int16), (16, 12, np.int32), (4, 13, np.int16), (8, 13, np.int32),
    (4, 16, np.int32), (4096, 16, np.int32),
]


def test_accumulator_dtype_follows_the_bound() -> None:
    for n, bits, dtype in DTYPE_TABLE:
        assert accumulator_dtype(n, bits) == np.dtype(dtype), (n, bits)


@pytest.mark.parametrize("cls", DEMODULATORS)
@pytest.mark.parametrize(("bits", "n"), [(8, 128), (10, 32), (12, 8), (13, 4), (16, 256)])
def test_full_scale_extremes_are_exact(cls: type[Demod], bits: int, n: int) -> None:
    """Longest N for the dtype; full scale on ON, OFF or every sub-frame; no overflow."""
    full = (1 << bits) - 1
    row = n // 2 + 1  # ON chips first: partial sums reach N/2 * full scale
    chips = codes.walsh_chips(n, row)
    pattern = np.array([[1, 0, 2], [2, 1, 0]])  # 1: full on ON, 0: full on OFF, 2: always
    frames = {}
    for s in range(3 * n):
        on = chips[s % n] == 1
        frames[s] = np.where(pattern == 2, full, np.where((pattern == 1) == on, full, 0))
    demod = cls(chips, bits)
    maps = _run(demod, (_sub(frames[s], s, bits) for s in range(3 * n)))
    expected = np.where(pattern == 2, 0, np.where(pattern == 1, 1, -1)) * (n // 2) * full
    assert maps and maps[0].values.dtype == accumulator_dtype(n, bits)
    for m in maps:
        np.testing.assert_array_equal(m.values, expected)
        assert m.saturated.all()


@pytest.mark.parametrize("cls", DEMODULATORS)
@pytest.mark.parametrize("bits", [8, 10, 16])
def test_every_map_is_the_window_sum(cls: type[Demod], bits: int) -> None:
    rng = np.random.default_rng(bits)
    n, lag = 8, 3
    chips = codes.walsh_chips(n, 7)
    frames = {s: rng.integers(0, 1 << bits, (5, 7)) for s in range(40, 75)}
    maps = _run(cls(chips, bits, lag=lag), (_sub(f, s, bits) for s, f in frames.items()))
    assert len(maps) == (35 // n if cls is BlockDemodulator else 35 - n + 1)
    for m in maps:
        assert m.last_sequence - m.first_sequence == n - 1 and m.phase == lag
        np.testing.assert_array_equal(
            m.values, _window_sum(frames, codes.bipolar(chips), lag, m.last_sequence))


@pytest.mark.parametrize(("bits", "n"), [(8, 16), (10, 16), (16, 8)])
def test_compiled_slide_is_the_update_on_strided_frames(bits: int, n: int) -> None:
    """The compiled sliding update against numpy, on sub-frames that are column slices of
    wider arrays (a cropped camera image), both signs, chunk maxima and full-scale hooks."""
    rng = np.random.default_rng(bits)
    dtype, full = accumulator_dtype(n, bits), (1 << bits) - 1
    kernels = Kernels(dtype, (70, 33), full, chunk_bytes=33 * dtype.itemsize * 16)
    wide = rng.integers(0, full, (2, 70, 50)).astype(np.uint8 if bits == 8 else np.uint16)
    new, old = wide[0][:, 5:38], wide[1][:, 9:42]
    new[40, 3] = full  # in the third chunk of 16 rows
    prev = rng.integers(-(n // 2) * full, (n // 2) * full, (70, 33)).astype(dtype)
    marked: list[tuple[str, int]] = []
    hooks = (lambda rows, _: marked.append(("in", rows.start)),
             lambda rows, _: marked.append(("out", rows.start)))
    for sign in (1, -1):
        out = np.empty_like(prev)
        peak, hot = kernels.slide(out, prev, new, (old, (0,)), sign, hooks)
        expected = prev.astype(np.int64) + sign * (new.astype(np.int64) - old)
        np.testing.assert_array_equal(out, expected)
        assert peak == full and hot == (2,)
    assert marked == [("in", 32), ("out", 0)] * 2


def test_sliding_maps_are_independent_read_only_arrays() -> None:
    chips = codes.walsh_chips(4, 2)
    frames = [np.full((2, 2), 10 * s) for s in range(8)]
    maps = _run(SlidingDemodulator(chips, 8), (_sub(f, s, 8) for s, f in enumerate(frames)))
    first = maps[0].values.copy()
    assert not maps[0].values.flags.writeable
    np.testing.assert_array_equal(maps[0].values, first)
    assert len({id(m.values) for m in maps}) == len(maps)


# --- feature: cancellation (paper Eq. 3, 4 and 8) -------------------------------------------

def _interferer_level(u: np.ndarray, seq: int, shift: int, fraction: float) -> float:
    """Other unit's laser seen in sub-frame ``seq``: chips as rectangles, shifted in time."""
    n = u.size
    return (1 - fraction) * u[(seq + shift) % n] + fraction * u[(seq + shift + 1) % n]


@st.composite
def _scenes(draw: Callable[..., object]) -> dict[str, object]:
    n = draw(st.sampled_from([4, 8, 16, 32]))
    own, other = draw(st.permutations(draw(st.sampled_from(codes.async_sets(n)))))[:2]
    return {
        "n": n, "own": own, "other": other,
        "lag": draw(st.integers(0, n - 1)),
        "shift": draw(st.integers(0, n - 1)),
        "fraction": draw(st.sampled_from([0.0, 0.25, 0.5, 0.75])),
        "drift": draw(st.integers(-2, 2)),
        "start": draw(st.integers(0, 10_000)),
        "noise": draw(st.sampled_from([0.0, 0.0, 1.0, 3.0])),
        "cls": draw(st.sampled_from(DEMODULATORS)),
        "seed": draw(st.integers(0, 2**32 - 1)),
    }


@given(scene=_scenes())
@settings(max_examples=60, deadline=None)
def test_ambient_drift_and_interferer_cancel(scene: dict) -> None:  # type: ignore[type-arg]
    n, lag, start = scene["n"], scene["lag"], scene["start"]
    own_chips = codes.walsh_chips(n, scene["own"])
    u = codes.walsh_chips(n, scene["other"])
    rng = np.random.default_rng(scene["seed"])
    ambient = rng.integers(300, 500, (6, 8)).astype(np.float64)
    laser = np.zeros((6, 8))
    laser[2] = 50.0
    interferer = np.zeros((6, 8))
    interferer[:, 3] = 40.0  # crosses the own laser row too
    frames, count = {}, 2 * n + 3
    for s in range(start, start + count):
        value = (ambient + scene["drift"] * (s - start)
                 + laser * own_chips[(s - lag) % n]
                 + interferer * _interferer_level(u, s, scene["shift"], scene["fraction"]))
        frames[s] = np.rint(value + rng.normal(0.0, scene["noise"], value.shape))
    demod = scene["cls"](own_chips, 10, lag=lag)
    maps = _run(demod, (_sub(f, s, 10) for s, f in frames.items()))
    v = codes.bipolar(own_chips).astype(np.int64)
    tolerance = 6.0 * scene["noise"] * np.sqrt(n)
    for m in maps:
        window = range(m.last_sequence - n + 1, m.last_sequence + 1)
        delta = scene["drift"] * sum(int(v[(s - lag) % n]) * (s - start) for s in window)
        expected = laser * n / 2 + delta
        np.testing.assert_allclose(m.values, expected, rtol=0, atol=tolerance)


def test_linear_drift_leaves_delta_only_on_single_bit_rows() -> None:
    """Paper's delta for a ramp: zero for rows whose 0-based index has two or more bits."""
    n = 8
    frames = {s: np.full((1, 1), 100 + 3 * s) for s in range(n)}
    residual = {}
    for row in range(2, n + 1):
        m = _run(BlockDemodulator(codes.walsh_chips(n, row), 8),
                 (_sub(f, s, 8) for s, f in frames.items()))[0]
        residual[row] = int(m.values[0, 0])
    assert {r for r, d in residual.items() if d != 0} == {2, 3, 5}
    assert residual[2] == 3 * sum(int(v) * i for i, v in enumerate(codes.bipolar(
        codes.walsh_chips(n, 2))))


# --- feature: saturation --------------------------------------------------------------------

@pytest.mark.parametrize("cls", DEMODULATORS)
def test_full_scale_pixel_is_flagged_for_the_windows_that_hold_it(cls: type[Demod]) -> None:
    n, bits = 4, 10
    frames = {s: np.full((3, 4), 200) for s in range(12)}
    frames[5] = frames[5].copy()
    frames[5][1, 2] = 1023
    maps = _run(cls(codes.walsh_chips(n, 3), bits), (_sub(f, s, bits) for s, f in frames.items()))
    for m in maps:
        holds = m.first_sequence <= 5 <= m.last_sequence
        assert m.saturated[1, 2] == holds
        assert np.count_nonzero(m.saturated) == int(holds)
        assert m.extra["saturated_fraction"] == pytest.approx(holds / 12)
    assert any(m.first_sequence <= 5 <= m.last_sequence for m in maps)


@pytest.mark.parametrize("cls", DEMODULATORS)
def test_saturation_masks_are_exact_across_row_chunks(cls: type[Demod]) -> None:
    """Frames of several cached row chunks; full-scale pixels come and go in different ones."""
    rng = np.random.default_rng(5)
    n, shape = 4, (300, 640)  # 640 int16 columns: 204 (block) or 102 (sliding) rows a chunk
    frames = {s: rng.integers(0, 4000, shape) for s in range(20)}
    for s, (row, col) in {3: (5, 7), 6: (250, 600), 7: (150, 3), 12: (299, 639)}.items():
        frames[s][row, col] = 4095
    maps = _run(cls(codes.walsh_chips(n, 3), 12), (_sub(f, s, 12) for s, f in frames.items()))
    for m in maps:
        window = range(m.first_sequence, m.last_sequence + 1)
        expected = np.any([frames[s] == 4095 for s in window], axis=0)
        np.testing.assert_array_equal(m.saturated, expected)


@pytest.mark.parametrize("lag", [0, None])
def test_ambient_level_is_a_fraction_of_full_scale(lag: int | None) -> None:
    chips = codes.walsh_chips(8, 3)
    subs = []
    for s in range(80):
        frame = np.full((64, 40), 102.0) + 0.01 * s
        frame[30:32] += 60.0 * chips[s % 8]
        subs.append(_sub(np.rint(frame), s, 8))
    maps = _run(SlidingDemodulator(chips, 8, lag=lag), subs)
    assert maps and all(m.extra["ambient_level"] == pytest.approx(0.4 + 0.02 * 0.5, abs=0.02)
                        for m in maps)


# --- feature: sequence numbers, exposure and shape ------------------------------------------

@pytest.mark.parametrize("cls", DEMODULATORS)
def test_dropped_sub_frames_re_prime_and_never_flip_the_sign(cls: type[Demod]) -> None:
    n = 8
    chips = codes.walsh_chips(n, 2)  # a one-frame slip would invert the sign
    frames = {s: np.full((2, 3), 100 + 50 * chips[s % n]) for s in range(60)}
    kept = [s for s in range(60) if s not in (11, 30, 31, 32)]
    demod = cls(chips, 8)
    maps = _run(demod, (_sub(frames[s], s, 8) for s in kept))
    assert maps and all((m.values == 50 * n // 2).all() for m in maps)
    assert all(m.last_sequence - m.first_sequence == n - 1 for m in maps)
    assert demod.dropped_total == 4
    assert sum(m.dropped for m in maps) == 4
    after_gap = [m for m in maps if m.first_sequence > 32]
    assert after_gap[0].first_sequence == 33 and after_gap[0].dropped == 3


@pytest.mark.parametrize("cls", DEMODULATORS)
def test_exposure_change_re_primes_the_window(cls: type[Demod]) -> None:
    n = 4
    demod = cls(codes.walsh_chips(n, 2), 8)
    subs = [_sub(np.full((2, 2), 10), s, 8, exposure_us=100.0 if s < 6 else 50.0)
            for s in range(16)]
    maps = _run(demod, subs)
    assert demod.exposure_changes == 1
    assert all(m.last_sequence < 6 or m.first_sequence >= 6 for m in maps)
    assert min(m.first_sequence for m in maps if m.last_sequence >= 6) == 6
    # each map carries its window's exposure (the pipeline scales the expected return by it)
    assert all(m.exposure_us == (100.0 if m.last_sequence < 6 else 50.0) for m in maps)


@pytest.mark.parametrize("cls", DEMODULATORS)
def test_shape_change_re_primes_the_window(cls: type[Demod]) -> None:
    n = 4
    demod = cls(codes.walsh_chips(n, 2), 8)
    subs = [_sub(np.full((2, 2) if s < 5 else (3, 2), 10), s, 8) for s in range(14)]
    maps = _run(demod, subs)
    assert demod.shape_changes == 1
    assert all(m.values.shape == (3, 2) for m in maps if m.last_sequence >= 5)
    assert min(m.first_sequence for m in maps if m.last_sequence >= 5) == 5


@pytest.mark.parametrize("cls", DEMODULATORS)
def test_reset_forgets_the_window_but_keeps_the_totals(cls: type[Demod]) -> None:
    demod = cls([1, 0, 1, 0], 8)
    _run(demod, [_sub(np.zeros((2, 2)), s, 8) for s in (0, 1, 5, 6)])
    demod.reset()
    maps = _run(demod, [_sub(np.zeros((2, 2)), s, 8) for s in range(100, 104)])
    assert demod.dropped_total == 3
    assert maps[0].first_sequence == 100 and maps[0].dropped == 0


# --- exception ------------------------------------------------------------------------------

@pytest.mark.parametrize(("pixels", "bits", "match"), [
    (np.zeros((2, 2), np.uint16), 8, "8-bit uint16"),
    (np.zeros((2, 2), np.uint8), 10, "10-bit uint8"),
    (np.zeros((2, 2, 3), np.uint8), 8, "2-D"),
    (np.zeros((0, 4), np.uint8), 8, "non-empty"),
    (np.zeros((2, 2), np.float32), 8, "float32"),
])
def test_bad_sub_frames_are_refused(pixels: np.ndarray, bits: int, match: str) -> None:
    demod = BlockDemodulator([1, 0, 1, 0], 8)
    with pytest.raises(DemodulationError, match=match):
        demod.push(SubFrame(pixels, 0, 0.0, 0.0, 100.0, bits=bits))  # type: ignore[arg-type]


@pytest.mark.parametrize("cls", DEMODULATORS)
def test_values_above_full_scale_are_refused_and_re_prime(cls: type[Demod]) -> None:
    demod = cls([1, 0, 1, 0], 10)
    demod.push(_sub(np.full((2, 2), 5), 0, 10))
    with pytest.raises(DemodulationError, match="above the full scale 1023"):
        demod.push(_sub(np.full((2, 2), 1024), 1, 10))
    maps = _run(demod, [_sub(np.full((2, 2), 5), s, 10) for s in range(2, 6)])
    assert maps[0].first_sequence == 2


@pytest.mark.parametrize("value", [1024, 40000, 65535])
def test_values_above_full_scale_are_refused_while_sliding(value: int) -> None:
    """Over range in the last row chunk of a sliding update, also where the pixel's int16
    view (how the accumulator adds it) reads negative: refused, and the window re-primes."""
    n, bits, shape = 4, 10, (300, 640)
    demod = SlidingDemodulator(codes.walsh_chips(n, 3), bits)
    assert _run(demod, [_sub(np.full(shape, 200), s, bits) for s in range(2 * n)])
    bad = np.full(shape, 200)
    bad[-1, -1] = value
    with pytest.raises(DemodulationError, match=f"value {value} above the full scale 1023"):
        demod.push(_sub(bad, 2 * n, bits))
    maps = _run(demod, [_sub(np.full(shape, 200), s, bits) for s in range(2 * n + 1, 4 * n)])
    assert maps[0].first_sequence == 2 * n + 1
    assert all(not m.values.any() and not m.saturated.any() for m in maps)


def test_bad_codes_and_bit_depths_are_refused() -> None:
    with pytest.raises(CodeError, match="not balanced"):
        BlockDemodulator([1, 1, 1, 0], 8)
    with pytest.raises(DemodulationError, match=r"accepted: 8\.\.16"):
        SlidingDemodulator([1, 0], 17)
    with pytest.raises(DemodulationError, match=r"accepted: 8\.\.16"):
        accumulator_dtype(8, 7)


# --- feature: phase lock --------------------------------------------------------------------

def _strobed(chips: np.ndarray, lag_of: Callable[[int], int], seqs: Iterable[int],
             seed: int = 0, other: np.ndarray | None = None) -> Iterable[SubFrame]:
    """10-bit scene: ambient with drift and noise, own lines, an interferer on ``other``."""
    n, rng = chips.size, np.random.default_rng(seed)
    for s in seqs:
        frame = 300.0 + 0.3 * s + rng.normal(0.0, 3.0, (48, 64))
        frame[20:22] += 40.0 * chips[(s - lag_of(s)) % n]
        if other is not None:
            frame[30:33] += 120.0 * other[(s + 3) % n]
        yield _sub(np.rint(frame), s, 10)


@pytest.mark.parametrize("cls", DEMODULATORS)
@pytest.mark.parametrize(("n", "row", "lag"), [(4, 2, 1), (8, 5, 3), (16, 9, 1), (32, 17, 7)])
def test_unknown_lag_is_found_and_reported(cls: type[Demod], n: int, row: int,
                                           lag: int) -> None:
    chips, other = codes.walsh_chips(n, row), codes.walsh_chips(n, 3 if row != 3 else 2)
    demod = cls(chips, 10, lag=None)
    assert not demod.locked and demod.lag is None
    maps = _run(demod, _strobed(chips, lambda _: lag, range(500, 500 + 6 * n + 40),
                                other=other))
    assert demod.locked
    v = codes.bipolar(chips)
    assert (np.roll(v, demod.lag or 0) == np.roll(v, lag)).all()
    assert maps and all(m.phase == demod.lag for m in maps)
    assert all(m.values[20:22].mean() == pytest.approx(40 * n / 2, rel=0.15) for m in maps)


def test_lock_waits_for_a_laser() -> None:
    """Noise, drift and an interferer on an orthogonal code, but no own laser: no lock."""
    chips = codes.walsh_chips(8, 5)
    demod = SlidingDemodulator(chips, 10, lag=None)
    dark = _strobed(np.zeros(8, np.uint8), lambda _: 0, range(300), seed=3,
                    other=codes.walsh_chips(8, 2))
    assert _run(demod, dark) == [] and not demod.locked


def test_a_strobe_slip_after_lock_is_followed() -> None:
    chips = codes.walsh_chips(16, 5)
    demod = BlockDemodulator(chips, 10, lag=None)
    maps = _run(demod, _strobed(chips, lambda s: 1 if s < 200 else 2, range(100, 400)))
    assert demod.lag == 2 and demod.relocks == 1
    assert maps[-1].values[20:22].mean() == pytest.approx(40 * 8, rel=0.15)


# --- feature: processing gain and SNR (paper Eq. 5-6) ---------------------------------------

@pytest.mark.parametrize("noise", [2.0, 6.0])
def test_gain_and_snr_match_the_paper_equations(noise: float) -> None:
    n, laser = 16, 30.0
    chips = codes.walsh_chips(n, 9)
    rng = np.random.default_rng(7)
    frames = []
    for s in range(n):
        frame = 400.0 + rng.normal(0.0, noise, (200, 160))
        frame[50:53] += laser * chips[s]
        frames.append(_sub(np.rint(frame), s, 10))
    (m,) = _run(BlockDemodulator(chips, 10), frames)
    delta = np.hypot(noise, 1 / np.sqrt(12)) * np.sqrt(n)  # rms of the background sum
    assert m.snr == pytest.approx(laser * n / (2 * delta) + 1, rel=0.2)
    assert m.processing_gain == pytest.approx((laser * n + 2 * delta) / (2 * laser), rel=0.1)
    assert m.extra["residual_dn"] == pytest.approx(delta, rel=0.1)


def test_gain_without_laser_or_noise_stays_finite() -> None:
    flat = np.zeros((40, 40), np.int32)
    assert measure_gain(flat, 16) == (0.0, 0.0, 0.0, 0.5)
    lines = flat.copy()
    lines[10] = 160
    gain, snr, signal, residual = measure_gain(lines, 16)
    assert (signal, residual) == (160.0, 0.5)
    assert snr == 320.0 and gain == pytest.approx(160 / (2 * 159.5 / 16))


# --- smoke: the benchmark's rows ------------------------------------------------------------

def test_bench_rows_have_the_fields_other_tools_read() -> None:
    from atris_node.bench import demod as bench

    rows = bench.measure(64, 32, 10, 4, repeats=1, saturated=True)
    assert [r["mode"] for r in rows] == ["block", "sliding"]
    for row in rows:
        assert set(row) == {"width", "height", "bits", "mode", "ms", "copy_ms", "ratio"}
        assert (row["width"], row["height"], row["bits"]) == (64, 32, 10)
        assert row["ms"] > 0 and row["ratio"] == pytest.approx(row["ms"] / row["copy_ms"],
                                                                rel=0.05, abs=0.01)
    frames = bench.scene(64, 32, 10, codes.walsh_chips(4, 2), saturated=True)
    assert max(int(f.max()) for f in frames) == 1023


@pytest.mark.parametrize("cls", [BlockDemodulator, SlidingDemodulator])
def test_feature_a_map_carries_its_window_and_the_last_off_sub_frame_before_it(
        cls: type[Demod]) -> None:
    """The raw sub-frames of each map (oldest first, with their signs) and the last OFF
    sub-frame before its window reach the pipeline (its time-course test); a gap in the
    sequence numbers forgets the one before."""
    chips = [1, 0, 1, 0]
    frames = [np.full((3, 4), 10 + s, np.uint8) for s in range(20)]
    demod = cls(chips, bits=8, lag=0)
    maps = [m for s in range(12) if (m := demod.push(_sub(frames[s], s, 8))) is not None]
    if cls is SlidingDemodulator:
        maps = [m for m in maps if m.first_sequence != 1]  # sub-frame 0 before it is ON
    first = maps[0]
    assert first.window is not None and first.window.before is None  # nothing before it
    assert first.window.signs == (1, -1, 1, -1)
    assert [int(p[0, 0]) - 10 for p in first.window.pixels] == [0, 1, 2, 3]
    for later in maps[1:]:
        assert later.window is not None
        start = later.first_sequence
        assert [int(p[0, 0]) - 10 for p in later.window.pixels] == list(
            range(start, start + 4))
        assert later.window.before is not None
        offset, pixels = later.window.before  # the OFF sub-frames are the odd ones
        assert offset == (-1 if start % 2 == 0 else -2)
        assert int(pixels[0, 0]) - 10 == start + offset
    after_gap = [m for s in range(14, 20) if (m := demod.push(_sub(frames[s], s, 8)))]
    assert after_gap and after_gap[0].window is not None
    assert after_gap[0].window.before is None
