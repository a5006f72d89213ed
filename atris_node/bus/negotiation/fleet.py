"""A fleet of negotiating units on one python-can virtual bus, on a shared fake clock.

Each unit has its own :class:`ShimBus` (a real virtual bus underneath) that stamps what it
sends and receives with the fake clock, can drop received frames (a partition) and can echo
its own frames back as udp_multicast and socketcan-with-loopback do. Units read their bus
inside ``tick`` (``poll_bus=True``), so a run is deterministic. Events (ticks, code-period
starts for synchronous mode) run in time order from a heap.

Example:
    >>> fleet = Fleet(channel="doctest-fleet", plan=Plan(16, 480.0), names=[0x30, 0x10, 0x20])
    >>> fleet.start_all(spread_s=0.01)
    >>> fleet.run_until(1.0)
    >>> sorted(u.code_row for u in fleet.units)
    [2, 3, 5]
    >>> fleet.close()
"""

from __future__ import annotations

import functools
import heapq
import itertools
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import can

from atris_node.bus.negotiation.frames import FrameKind, parse_id
from atris_node.bus.negotiation.machine import Negotiator
from atris_node.bus.negotiation.plan import Plan

DropRule = Callable[[can.Message], bool]


class FakeClock:
    """A clock the simulation sets; call it for the time in seconds."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


class ShimBus(can.BusABC):
    """A virtual bus that records, drops and (optionally) echoes frames, on a fake clock.

    Attributes:
        sent: (time, message) of every frame this unit sent.
        received: (time, message) of every frame delivered to this unit.
        drop: frames for which it returns True are not delivered (partitions, faults).
    """

    def __init__(self, channel: str, clock: Callable[[], float], echo: bool = False) -> None:
        super().__init__(channel=channel)
        self.inner = can.Bus(interface="virtual", channel=channel)
        self.clock = clock
        self.echo = echo
        self._echoes: list[can.Message] = []
        self.sent: list[tuple[float, can.Message]] = []
        self.received: list[tuple[float, can.Message]] = []
        self.drop: DropRule | None = None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)
        self.sent.append((self.clock(), msg))
        if self.echo:
            self._echoes.append(can.Message(arbitration_id=msg.arbitration_id, data=msg.data,
                                            is_extended_id=msg.is_extended_id, is_rx=True))

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        while True:
            msg = self._echoes.pop(0) if self._echoes else self.inner.recv(0.0)
            if msg is None:
                return None, False
            if self.drop is None or not self.drop(msg):
                self.received.append((self.clock(), msg))
                return msg, False

    def shutdown(self) -> None:
        super().shutdown()
        self.inner.shutdown()


@dataclass(order=True)
class _Event:
    time_s: float
    order: int
    action: Callable[[], None] = field(compare=False)


class Fleet:
    """Several units negotiating on one virtual channel, driven by a fake clock.

    Args:
        channel: virtual channel name (use one per test).
        plan: the plan every unit is configured with (``plans`` overrides per unit).
        names: the units' NAMEs; unit i gets ``unit_id = i``.
        tick_s: how often each unit ticks.
        echo: echo each unit's own frames back to it.
        negotiator_args: extra keyword arguments for every :class:`Negotiator`.
    """

    def __init__(self, channel: str, plan: Plan, names: Sequence[int], *, tick_s: float = 0.005,
                 echo: bool = False, plans: Sequence[Plan] | None = None,
                 **negotiator_args: Any) -> None:
        self.clock = FakeClock()
        self.channel = channel
        self.tick_s = tick_s
        self.echo = echo
        self.negotiator_args = negotiator_args
        self.buses: list[ShimBus] = []
        self.units: list[Negotiator] = []
        self._running: list[bool] = []
        self._events: list[_Event] = []
        self._nonces = itertools.count()  # distinct per start, so no twin shares ours
        self._order = itertools.count()
        for i, name in enumerate(names):
            self.add(name, (plans or [plan] * len(names))[i], unit_id=i)

    def add(self, name: int, plan: Plan, unit_id: int) -> int:
        """Add a unit (not started) with its own bus; returns its index."""
        bus = ShimBus(self.channel, self.clock, self.echo)
        self.buses.append(bus)
        self.units.append(Negotiator(bus, name, plan, unit_id, clock=self.clock, poll_bus=True,
                                     nonce_source=self._next_nonce, **self.negotiator_args))
        self._running.append(False)
        return len(self.units) - 1

    def _next_nonce(self) -> int:
        return next(self._nonces) % 255 + 1

    def at(self, time_s: float, action: Callable[[], None]) -> None:
        """Run ``action`` at ``time_s`` (fake clock; never earlier than now)."""
        when = max(time_s, self.clock.now)
        heapq.heappush(self._events, _Event(when, next(self._order), action))

    def start(self, index: int, time_s: float) -> None:
        """Start unit ``index`` at ``time_s`` and tick it every ``tick_s`` from then on."""
        def begin() -> None:
            self._running[index] = True
            self.units[index].start()
            self.at(self.clock.now + self.tick_s, lambda: self._tick(index))
        self.at(time_s, begin)

    def start_all(self, spread_s: float = 0.0, seed: int = 1) -> None:
        """Start every unit at a random time in ``[0, spread_s]``."""
        rng = random.Random(seed)
        for index in range(len(self.units)):
            self.start(index, rng.uniform(0.0, spread_s))

    def stop(self, index: int, time_s: float) -> None:
        """Stop unit ``index`` at ``time_s`` (it sends cannot-claim and goes quiet)."""
        def end() -> None:
            self._running[index] = False
            self.units[index].stop()
        self.at(time_s, end)

    def silence(self, index: int, time_s: float) -> None:
        """Unit ``index`` falls silent at ``time_s`` without a word (power loss)."""
        def cut() -> None:
            self._running[index] = False
            self.units[index].timeline.append((self.clock.now, False, None))  # power is gone
        self.at(time_s, cut)

    def hang(self, index: int, from_s: float, to_s: float) -> None:
        """Unit ``index`` hangs from ``from_s`` to ``to_s``: no tick, nothing sent, frames
        pile up in its receive queue; its laser is dark meanwhile (its lease ran out)."""
        def freeze() -> None:
            self._running[index] = False
            self.units[index].timeline.append((self.clock.now, False, None))

        def thaw() -> None:
            self._running[index] = True
            self._tick(index)
        self.at(from_s, freeze)
        self.at(to_s, thaw)

    def _tick(self, index: int) -> None:
        if not self._running[index]:
            return
        self.units[index].tick()
        self.at(self.clock.now + self.tick_s, lambda: self._tick(index))

    def run_cycles(self, jitter_chips: float, seed: int = 2) -> None:
        """Give every unit a code-period clock that follows the leader's SYNC.

        Every unit starts at a random phase. At each of its period starts it calls
        :meth:`Negotiator.cycle_started`; the leader's SYNC reaches the others at once; a
        follower starts its next period a whole number of periods after the newest SYNC,
        off by a Gaussian trigger error of ``jitter_chips`` (standard deviation, chips).
        """
        rng = random.Random(seed)
        for index, unit in enumerate(self.units):
            first = self.clock.now + rng.uniform(0.0, unit.plan.cycle_s)
            self.at(first, functools.partial(self._cycle, index, rng, jitter_chips))

    def _cycle(self, index: int, rng: random.Random, jitter_chips: float) -> None:
        unit, now = self.units[index], self.clock.now
        unit.cycle_started(now)
        if unit.is_sync_leader:
            for other, running in enumerate(self._running):
                if running and other != index:
                    self.units[other].tick()
        cycle = unit.plan.cycle_s
        reference = None if unit.is_sync_leader else unit.sync.state.last_sync_s
        next_start = now + cycle
        if reference is not None:
            periods = int((now - reference) // cycle) + 1
            trigger_error_s = rng.gauss(0.0, jitter_chips) / unit.plan.chip_rate_hz
            next_start = max(reference + periods * cycle + trigger_error_s, now + 1e-6)
        self.at(next_start, functools.partial(self._cycle, index, rng, jitter_chips))

    def run_until(self, time_s: float) -> None:
        """Run events in time order up to ``time_s``."""
        while self._events and self._events[0].time_s <= time_s:
            event = heapq.heappop(self._events)
            self.clock.now = event.time_s
            event.action()
        self.clock.now = time_s

    def partition(self, groups: Sequence[Sequence[int]]) -> None:
        """From now on, frames cross only between units of the same group."""
        group_of = {unit_id: g for g, members in enumerate(groups) for unit_id in members}
        for index, bus in enumerate(self.buses):
            mine = group_of.get(index)
            bus.drop = lambda msg, mine=mine: group_of.get(msg.arbitration_id & 0xF) != mine

    def heal(self) -> None:
        """Deliver every frame again."""
        for bus in self.buses:
            bus.drop = None

    def close(self) -> None:
        """Stop every unit and shut every bus down."""
        for unit in self.units:
            unit.stop()
        for bus in self.buses:
            bus.shutdown()


def strobe_intervals(unit: Negotiator, end_s: float) -> list[tuple[float, float, int]]:
    """(start, end, row) of every interval in which ``unit`` was allowed to strobe."""
    intervals = []
    entries = [*unit.timeline, (end_s, False, None)]
    for (t0, may, row), (t1, _, _) in itertools.pairwise(entries):
        if may and row is not None and t1 > t0:
            intervals.append((t0, t1, row))
    return intervals


def plan_at(unit: Negotiator, time_s: float) -> Plan:
    """The plan ``unit`` used at ``time_s``."""
    plan = unit.agreement.configured_plan
    for t, p in unit.plan_history:
        if t <= time_s:
            plan = p
    return plan


def overlaps(fleet: Fleet, end_s: float) -> list[tuple[int, int, float, float, int]]:
    """Every time two units strobed the same row under the same plan: (i, j, start, end, row)."""
    found = []
    spans = [strobe_intervals(u, end_s) for u in fleet.units]
    for i, j in itertools.combinations(range(len(spans)), 2):
        for a0, a1, ra in spans[i]:
            for b0, b1, rb in spans[j]:
                start, end = max(a0, b0), min(a1, b1)
                same_plan = plan_at(fleet.units[i], start) == plan_at(fleet.units[j], start)
                if ra == rb and end > start and same_plan:
                    found.append((i, j, start, end, ra))
    return found


def claim_times(bus: ShimBus, row: int) -> list[float]:
    """Times this unit sent a CLAIM for ``row``."""
    times = []
    for t, msg in bus.sent:
        header = parse_id(msg.arbitration_id)
        if header is not None and header.kind is FrameKind.CLAIM and header.field == row:
            times.append(t)
    return times


def window_violations(fleet: Fleet, end_s: float, window_s: float) -> list[tuple[int, float, int]]:
    """Strobe starts not preceded by a continuous claim of that row for ``window_s``.

    For each interval the unit must have held the row (timeline) since some time t_c with a
    CLAIM for the row sent at t_c and ``start - t_c >= window_s``.
    """
    bad = []
    for index, unit in enumerate(fleet.units):
        for start, _, row in strobe_intervals(unit, end_s):
            held_since = _held_since(unit, row, start)
            sent = [t for t in claim_times(fleet.buses[index], row) if held_since <= t <= start]
            if not sent or start - min(sent) < window_s - 1e-9:
                bad.append((index, start, row))
    return bad


def _held_since(unit: Negotiator, row: int, time_s: float) -> float:
    """Start of the run of timeline entries up to ``time_s`` that all hold ``row``."""
    since = time_s
    for t, _, r in reversed([e for e in unit.timeline if e[0] <= time_s]):
        if r != row:
            break
        since = t
    return since
