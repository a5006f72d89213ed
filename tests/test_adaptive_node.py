"""Adaptive operation of a running unit on simulated scenes, in process on a virtual bus:
short N indoors, long N and LOW_SIGNAL in strong sun, a passing cloud, two units that
always agree on N, and no window that mixes two N or two exposures."""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import can
import pytest

from atris_node import config as cfg
from atris_node.bench.adaptive import stepped_unit
from atris_node.demod import PendingMap
from atris_node.node.unit import Unit
from atris_node.types import FaultBits, SectorState, SubFrame

BASE = ["negotiation.window_s=0.05", "negotiation.reannounce_s=0.5", "adaptive.enabled=true",
        "adaptive.grow_frames=1", "adaptive.shrink_frames=2"]


class Windows:
    """Every sub-frame a unit demodulated (N and exposure) and every map it published."""

    def __init__(self, unit: Unit) -> None:
        self.unit = unit
        self.pushed: dict[int, tuple[int, float]] = {}
        self.maps: list[PendingMap] = []
        demodulate, on_map = unit._demodulate, unit._on_map

        def recording_demodulate(sub: SubFrame) -> PendingMap | None:
            assert unit.measure is not None and unit.measure.demod is not None
            self.pushed[sub.sequence] = (unit.measure.demod.code_length, sub.exposure_us)
            return demodulate(sub)

        def recording_on_map(dmap: PendingMap) -> None:
            self.maps.append(dmap)
            on_map(dmap)

        unit._demodulate = recording_demodulate  # type: ignore[method-assign]
        unit._on_map = recording_on_map  # type: ignore[method-assign]

    def assert_unmixed(self) -> None:
        """Each map's sub-frames were all pushed under its N and one exposure."""
        assert self.maps
        for m in self.maps:
            window = [self.pushed[s] for s in range(m.first_sequence, m.last_sequence + 1)
                      if s in self.pushed]
            assert {n for n, _ in window} == {m.code_length}, (m.first_sequence, window)
            assert len({e for _, e in window}) == 1, (m.first_sequence, window)


@pytest.fixture
def bus(request: pytest.FixtureRequest) -> Iterator[can.BusABC]:
    bus = can.Bus(interface="virtual", channel=f"adaptive-{request.node.name}")
    yield bus
    bus.shutdown()


def make_unit(bus: can.BusABC, *extra: str) -> Unit:
    unit = Unit(cfg.load(environ={}, overrides=[*BASE, *extra]), bus)
    unit.configure()
    unit.activate(threaded=False)
    return unit


def steps(unit: Unit, count: int) -> None:
    for _ in range(count):
        unit.step()
        unit.check()


#: wall-clock floor of steps_until, s: the negotiation windows are wall time
WALL_FLOOR_S = 20.0


def steps_until(unit: Unit, done: Any, most: int) -> None:
    """Step until ``done()``: at least ``most`` sub-frames and at least WALL_FLOOR_S of
    wall clock (dark negotiation windows are wall time, so the sub-frames a change takes
    vary with the machine's load and with the cost of a map: a fixed sub-frame budget
    failed once when the sub-frames ran faster than the contest window)."""
    start, steps = time.monotonic(), 0
    while steps < most or time.monotonic() - start < WALL_FLOOR_S:
        if done():
            return
        unit.step()
        unit.check()
        steps += 1
    assert done(), unit.status()


def simulator(unit: Unit) -> Any:
    return unit.camera.simulator  # type: ignore[union-attr]


def test_feature_indoor_settles_on_short_n_with_higher_rate(bus: can.BusABC) -> None:
    unit = make_unit(bus, "driver.scene=indoor_lab", "code.length=16")
    windows = Windows(unit)
    published: list[Any] = []
    unit.on_measurement = published.append
    try:
        steps_until(unit, lambda: unit.status().code_length <= 8, 400)
        published.clear()
        # settled: running, with maps of the current N (a further step, e.g. 8 -> 4,
        # renegotiates for a moment, which is allowed)
        steps_until(unit, lambda: len(published) >= 3 and unit.status().state.name ==
                    "RUNNING" and windows.maps[-1].code_length == unit.status().code_length,
                    200)
        status = unit.status()
        assert 4 <= status.code_length <= 8
        assert status.chip_rate_hz / status.code_length > status.chip_rate_hz / 16
        assert status.state.name == "RUNNING" and not status.faults & FaultBits.LOW_SIGNAL
        assert windows.maps[-1].code_length == status.code_length
        assert any(s.state is SectorState.VALID for s in published[-1].sectors)
        windows.assert_unmixed()
    finally:
        unit.shutdown()


def test_feature_strong_sun_grows_n_and_reports_low_signal(bus: can.BusABC) -> None:
    unit = make_unit(bus, "driver.scene=outdoor_strong_sun", "code.length=8",
                     "adaptive.max_length=32")
    windows = Windows(unit)
    published: list[Any] = []
    unit.on_measurement = published.append
    try:
        steps_until(unit, lambda: unit.status().code_length == 32, 400)
        published.clear()
        steps_until(unit, lambda: len(published) >= 2, 200)  # maps at N = 32
        status = unit.status()
        assert status.code_length == 32
        assert status.faults & FaultBits.LOW_SIGNAL
        assert published and all(s.state is SectorState.INVALID
                                 for m in published for s in m.sectors)
        windows.assert_unmixed()
    finally:
        unit.shutdown()


def _set_lamp(unit: Unit, lux: float) -> None:
    """Change the scene's lamp at run time (a cloud over a skylight)."""
    sim = simulator(unit)
    ambient = sim.scene.ambient
    sim.scene = replace(sim.scene, ambient=replace(ambient, lamp=replace(ambient.lamp, lux=lux)))
    sim._static = None
    sim._prepared.clear()


def _last_change(history: list[tuple[int, int, float]]) -> int:
    """Sequence of the last change of (N, exposure) in ``history``."""
    last = history[0][0]
    for before, after in itertools.pairwise(history):
        if before[1:] != after[1:]:
            last = after[0]
    return last


def test_feature_cloud_passing_converges_without_mixed_windows(bus: can.BusABC) -> None:
    # min_length 8: in lamp light N = 4 and 8 are both right and the choice between them is
    # a coin toss that may fall late (the indoor test covers it); here convergence is timed
    unit = make_unit(bus, "driver.scene=indoor_lab", "code.length=8", "adaptive.min_length=8")
    windows = Windows(unit)
    budget = 480  # sub-frames: 2 s at 240 Hz, for exposure and N to settle
    settled = {}
    try:
        steps(unit, 100)  # settle in the lamp light first
        for lux in (3000.0, 300.0):  # the cloud moves off a skylight and back
            _set_lamp(unit, lux)
            start = unit.stats.sub_frames
            history: list[tuple[int, int, float]] = []
            for _ in range(budget + 20):
                unit.step()
                history.append((unit.stats.sub_frames, unit.status().code_length,
                                simulator(unit).exposure_us))
            settled[lux] = _last_change(history) - start
        assert all(s <= budget for s in settled.values()), settled
        assert history[-1][2] > 1000.0  # back in lamp light the exposure is long again
        windows.assert_unmixed()
    finally:
        unit.shutdown()


def test_feature_units_on_one_bus_always_agree_on_n(request: pytest.FixtureRequest) -> None:
    # the contest window must outlast a peer's loop period (two units share one thread here)
    channel = f"adaptive-pair-{request.node.name}"
    buses = [can.Bus(interface="virtual", channel=channel) for _ in range(2)]
    units = [make_unit(b, "driver.scene=indoor_lab", "code.length=16", f"unit.unit_id={i}",
                       f"driver.seed={i + 1}", "negotiation.window_s=0.4")
             for i, b in enumerate(buses)]
    try:
        strobing_lengths = set()
        # bounded by the wall clock, not a step count: the contest windows run on the wall
        # clock, which the simulated sub-frames outpace on a fast machine
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            if all(u.negotiator.may_strobe and u.status().code_length <= 8 for u in units):
                break
            for unit in units:
                unit.step()
                unit.check()
            live = {u.negotiator.plan.code_length for u in units if u.negotiator.may_strobe}
            assert len(live) <= 1, live
            strobing_lengths |= live
        assert len(strobing_lengths) >= 2  # the plan did change while they ran
        assert units[0].status().code_length == units[1].status().code_length <= 8
    finally:
        for unit in units:
            unit.shutdown()
        for b in buses:
            b.shutdown()


@pytest.mark.parametrize("seed", [1, 2])
def test_safety_strong_sun_publishes_no_valid_distance_at_any_n(seed: int) -> None:
    # outdoor_strong_sun (100 klux on a white wall, 15 us): the pipeline's few samples are
    # noise peaks metres off (one bench run reported them as a 2.14 m RMSE). What counts is
    # what the unit publishes: from its first map on, at N = 4 and every N it grows to,
    # no sector is VALID (LOW_SIGNAL, held until two frames in a row are above the limit).
    # On the simulated clock (bench.adaptive.stepped_unit): the same maps every run.
    bus = can.Bus(interface="virtual", channel=f"adaptive-sun-{seed}")
    unit = stepped_unit("outdoor_strong_sun", [*BASE, "code.length=4", f"driver.seed={seed}"],
                        bus)
    windows = Windows(unit)
    published: list[Any] = []
    unit.on_measurement = published.append
    try:
        steps(unit, 600)
        lengths = {m.code_length for m in windows.maps}
        assert published and {4, 32} <= lengths, lengths
        assert unit.status().faults & FaultBits.LOW_SIGNAL
        # neither a distance nor "free" (NO_RETURN is a claim too)
        claims = [(m.newest_sequence, s.index, s.state, s.distance_m) for m in published
                  for s in m.sectors if s.state is not SectorState.INVALID]
        assert not claims
    finally:
        unit.shutdown()
        bus.shutdown()


def _lengths_run(bus: can.BusABC, *extra: str) -> set[int]:
    """The N of every map of a stepped indoor_lab unit with a low SNR target (6)."""
    unit = stepped_unit("indoor_lab", [*BASE, "code.length=16", "adaptive.shrink_frames=4",
                                       "adaptive.snr_target=6", *extra], bus)
    windows = Windows(unit)
    try:
        steps(unit, 260)
        return {m.code_length for m in windows.maps}
    finally:
        unit.shutdown()


def test_feature_error_bound_stops_the_shrink_the_snr_rule_wants(bus: can.BusABC) -> None:
    # indoor_lab at SNR target 6: the share rule alone takes N from 16 to 4, where the
    # published RMSE was 0.111 m against 0.0066 m at N = 32 (docs/benchmarks.md); the range
    # sigma predicted at 5 m is about 0.16 m at N = 4, over the 0.15 m bound, and 0.12 m
    # at N = 8. On the simulated clock: the same maps in both runs.
    assert 4 in _lengths_run(bus, "adaptive.max_range_sigma_m=10")  # the bound off
    assert min(_lengths_run(bus)) == 8
