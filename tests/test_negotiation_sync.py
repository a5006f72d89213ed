"""Synchronous mode (SYNC alignment and its leak), code hopping, plan maths and NAMEs."""

from __future__ import annotations

import itertools
import math
import random

import numpy as np
import pytest

from atris_node.bus.negotiation.fleet import Fleet, overlaps, strobe_intervals, window_violations
from atris_node.bus.negotiation.hop import InterferenceMonitor
from atris_node.bus.negotiation.machine import NegotiationState
from atris_node.bus.negotiation.name import name_from_serial, persisted_name, unit_name
from atris_node.bus.negotiation.plan import (
    Plan,
    capacity,
    code_rows,
    grow_to_fit,
)
from atris_node.bus.negotiation.sync import (
    fold_offset_chips,
    misalignment_leak,
    walsh_bipolar,
    worst_leak,
)
from atris_node.errors import CodeError, ConfigError, DemodulationError
from atris_node.types import FaultBits

_channels = itertools.count()


def channel() -> str:
    return f"negotiation-sync-test-{next(_channels)}"


# ---------------------------------------------------------------- plan and code sets
def test_code_sets_follow_table_1_and_the_sync_rule():
    assert code_rows(16, "async") == (2, 3, 5, 9)
    assert code_rows(32, "async") == (2, 3, 5, 9, 17)
    assert code_rows(8, "sync") == tuple(range(2, 9))
    assert capacity(Plan(128, 480.0)) == 7


def test_growth_picks_the_shortest_n_that_fits_and_stops_at_the_limit():
    assert grow_to_fit(Plan(16, 480.0), 6, 128) == Plan(64, 480.0)
    assert grow_to_fit(Plan(16, 480.0), 9, 128) == Plan(128, 480.0)  # 7 codes at most
    assert grow_to_fit(Plan(16, 480.0), 6, 32) == Plan(32, 480.0)
    assert Plan(64, 480.0).output_rate_hz == 7.5


def test_plans_refuse_values_no_unit_can_share():
    with pytest.raises(CodeError, match="power of two"):
        Plan(12, 480.0)
    with pytest.raises(ConfigError, match="chip_rate_hz"):
        Plan(16, math.nan)
    with pytest.raises(ConfigError, match="async, sync"):
        Plan(16, 480.0, "gold")
    assert Plan(16, 480.0004) == Plan(16, 480.0)  # the PLAN frame carries millihertz


# ---------------------------------------------------------------- leak of a misalignment
def _numeric_leak(own: int, other: int, n: int, shift: float, oversample: int = 1000) -> float:
    """Integrate rectangle chips on a fine grid: own bipolar times other's shifted strobe."""
    v = np.repeat(walsh_bipolar(n, own), oversample).astype(float)
    u = (np.repeat(walsh_bipolar(n, other), oversample) + 1) / 2
    shifted = np.roll(u, -round(shift * oversample))
    return abs(float(np.sum(v * shifted)) / oversample) / (n / 2)


def test_leak_equals_the_integral_over_rectangle_chips():
    rng = random.Random(3)
    for _ in range(40):
        n = rng.choice([4, 8, 16, 32])
        own, other = rng.sample(range(2, n + 1), 2)
        shift = rng.uniform(-2.0, 2.0)
        assert misalignment_leak(own, other, n, shift) == pytest.approx(
            _numeric_leak(own, other, n, shift), abs=2e-3)


def test_aligned_sync_codes_do_not_leak_and_cyclic_pairs_never_leak():
    for own, other in itertools.permutations(range(2, 17), 2):
        assert misalignment_leak(own, other, 16, 0.0) == pytest.approx(0.0, abs=1e-12)
    async_rows = code_rows(16, "async")
    for own, other in itertools.permutations(async_rows, 2):
        assert worst_leak(own, [other], 16, 0.37) == pytest.approx(0.0, abs=1e-12)
    assert worst_leak(3, [4], 16, 0.1) == pytest.approx(0.1)  # grows linearly with error


def test_offsets_fold_to_the_nearest_code_period():
    assert fold_offset_chips(0.5 / 480.0, 480.0, 16) == pytest.approx(0.5)
    assert fold_offset_chips(15.75 / 480.0, 480.0, 16) == pytest.approx(-0.25)
    assert fold_offset_chips(-8.0 / 480.0, 480.0, 16) == pytest.approx(8.0)


# ---------------------------------------------------------------- sync fleets
@pytest.fixture
def fleets():  # type: ignore[no-untyped-def]
    made: list[Fleet] = []
    yield made
    for fleet in made:
        fleet.close()


def _sync_fleet(made: list[Fleet], names: list[int], jitter_chips: float,
                **kwargs: object) -> Fleet:
    fleet = Fleet(channel(), Plan(16, 480.0, "sync"), names, **kwargs)  # type: ignore[arg-type]
    made.append(fleet)
    fleet.start_all(spread_s=0.01)
    fleet.run_cycles(jitter_chips=jitter_chips)
    return fleet


def test_sync_followers_align_to_the_leader_and_report_the_leak(fleets):
    fleet = _sync_fleet(fleets, [0x50, 0x10, 0x40, 0x20, 0x60, 0x30, 0x70, 0x45], 0.01)
    fleet.run_until(2.0)
    leader = min(fleet.units, key=lambda u: u.name)
    assert leader.is_sync_leader and all(not u.is_sync_leader for u in fleet.units
                                         if u is not leader)
    rows = [u.code_row for u in fleet.units]
    assert all(u.may_strobe for u in fleet.units) and len(set(rows)) == 8
    sent_sync = [m for _, m in fleet.buses[fleet.units.index(leader)].sent
                 if m.arbitration_id >> 21 & 7 == 4]
    assert len(sent_sync) >= 2.0 / leader.plan.cycle_s - 2  # one per code period
    for unit in fleet.units:
        if unit is leader:
            continue
        error = unit.alignment_error_chips
        assert error is not None and abs(error) < 0.05
        others = [r for r in rows if r != unit.code_row]
        assert unit.sync.leak == pytest.approx(worst_leak(unit.code_row, others, 16, error))
    assert max(u.sync.leak or 0.0 for u in fleet.units) > 0.0  # misaligned rows do leak
    assert overlaps(fleet, 2.0) == [] and window_violations(fleet, 2.0, 0.25) == []


def test_followers_that_cannot_align_well_enough_keep_the_laser_off(fleets):
    fleet = _sync_fleet(fleets, [0x10, 0x20, 0x30], 0.5, max_misalignment_chips=0.05)
    fleet.run_until(2.0)
    leader, *followers = fleet.units
    assert leader.may_strobe
    for unit in followers:
        assert unit.state is NegotiationState.OWNED
        lit = sum(t1 - t0 for t0, t1, _ in strobe_intervals(unit, 2.0))
        assert lit < 0.2  # only in the periods whose trigger error happened to be small
        for t0, _, _ in strobe_intervals(unit, 2.0):
            assert t0 >= 0.35  # never before the window


def test_a_new_sync_leader_takes_over_when_the_leader_stops(fleets):
    fleet = _sync_fleet(fleets, [0x10, 0x20, 0x30], 0.01)
    fleet.run_until(1.0)
    fleet.stop(0, 1.0)
    fleet.run_until(2.0)
    assert fleet.units[1].is_sync_leader and fleet.units[1].may_strobe
    assert fleet.units[2].may_strobe and abs(fleet.units[2].alignment_error_chips or 1) < 0.05
    assert overlaps(fleet, 2.0) == []


# ---------------------------------------------------------------- hopping
def _owned_pair(made: list[Fleet]) -> Fleet:
    fleet = Fleet(channel(), Plan(16, 480.0), [0x10, 0x20])
    made.append(fleet)
    fleet.start_all(spread_s=0.0)
    fleet.run_until(1.0)
    return fleet


def test_sustained_interference_on_the_own_code_makes_the_unit_hop(fleets):
    fleet = _owned_pair(fleets)
    unit = fleet.units[0]
    jammed = unit.code_row
    foreign = {3: 0.01, 5: 0.4, 9: 0.02}
    for step in range(10):  # 0.9 s of excess: not sustained long enough
        fleet.at(1.0 + 0.1 * step, lambda: unit.report_interference(0.5, foreign))
    fleet.run_until(1.95)
    assert unit.may_strobe and unit.code_row == jammed and unit.hop_count == 0
    for step in range(10, 13):
        fleet.at(1.0 + 0.1 * step, lambda: unit.report_interference(0.5, foreign))
    fleet.run_until(2.2)
    assert unit.hop_count == 1 and unit.code_row not in (jammed, fleet.units[1].code_row)
    assert unit.code_row == 9  # free rows ordered by the foreign energy measured on them
    assert strobing_at(unit, 2.0) == (False, 9)  # the normal claim path: window first
    assert FaultBits.FOREIGN_CODE in unit.faults
    fleet.run_until(2.5)
    assert unit.may_strobe and unit.code_row == 9
    assert window_violations(fleet, 2.5, 0.25) == [] and overlaps(fleet, 2.5) == []


def strobing_at(unit, time_s):  # type: ignore[no-untyped-def]
    state = (False, None)
    for t, may, row in unit.timeline:
        if t <= time_s:
            state = (may, row)
    return state


def test_interference_that_stops_in_time_does_not_make_a_hop():
    monitor = InterferenceMonitor(threshold=0.2, sustain_s=1.0)
    assert not monitor.report(0.5, {}, 0.0, strobing=True)
    assert not monitor.report(0.1, {}, 0.9, strobing=True)  # dropped below: timer reset
    assert not monitor.report(0.5, {}, 1.0, strobing=True)
    assert monitor.report(0.5, {}, 2.0, strobing=True)
    with pytest.raises(DemodulationError, match="finite"):
        monitor.report(math.nan, {}, 2.1, strobing=True)
    with pytest.raises(DemodulationError, match="foreign"):
        monitor.report(0.1, {3: -1.0}, 2.1, strobing=True)


# ---------------------------------------------------------------- NAMEs
def test_names_from_serial_config_or_a_persisted_random_value(tmp_path):
    assert unit_name(0x42) == 0x42
    assert unit_name(0, camera_serial="14442C10") == name_from_serial("14442C10")
    assert name_from_serial("A") != name_from_serial("B")
    state = tmp_path / "name"
    first = unit_name(0, state_path=state)
    assert 0 < first < 2**64 and persisted_name(state) == first
    state.write_text("zz")
    with pytest.raises(ConfigError, match="hex"):
        persisted_name(state)
    with pytest.raises(ConfigError, match="no NAME"):
        unit_name(0)
