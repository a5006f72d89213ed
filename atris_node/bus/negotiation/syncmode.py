"""Sync mode: the leader's SYNC at its cycle starts, and a follower's alignment to it.

In a sync plan every unit starts its code period together, so all N - 1 non-constant rows
are orthogonal. The lowest NAME sharing the plan (the sync leader) sends SYNC when its
period starts; a follower measures its own period start against the newest SYNC and may
strobe only while that error is small and fresh (:mod:`atris_node.bus.negotiation.sync`
has the maths). Written up in ``docs/negotiation.md``.

A service of one :class:`~atris_node.bus.negotiation.machine.Negotiator`: it runs under the
negotiator's lock and sends through the negotiator's link.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.sync import SyncState, worst_leak

if TYPE_CHECKING:
    from atris_node.bus.negotiation.inbox import SyncHeard
    from atris_node.bus.negotiation.machine import Negotiator


class SyncMode:
    """SYNC sending (leader) and alignment (followers) of one unit.

    Attributes:
        state: what this unit knows of the leader's SYNC and its own alignment.
        max_misalignment_chips: a follower strobes only when aligned this well.
        leak: worst leak of another unit's row into ours at the measured misalignment,
            fraction of our own line energy; None before a measurement.
    """

    def __init__(self, negotiator: Negotiator, max_misalignment_chips: float) -> None:
        self._unit = negotiator
        self.state = SyncState()
        self.max_misalignment_chips = max_misalignment_chips
        self.leak: float | None = None
        self._counter = 0

    def restart(self) -> None:
        """A start: the SYNC counter from 0 again."""
        self._counter = 0

    @property
    def is_leader(self) -> bool:
        """True in sync mode when no lower NAME shares our plan: this unit sends SYNC."""
        return self._unit.plan.mode == "sync" and self._unit._leader_peer() is None

    def on_sync(self, event: SyncHeard, now: float) -> None:
        """A SYNC of our plan's N from the sync leader is the reference."""
        plan = self._unit.plan
        if plan.mode != "sync" or event.code_length != plan.code_length:
            return
        if event.peer.name is not None and event.peer is self._unit._leader_peer():
            self.state.on_sync(event.counter, now)

    def cycle_started(self, now: float) -> float | None:
        """Our code period started at ``now``: send SYNC (leader) or measure the alignment
        error in chips (follower, None before a SYNC was heard)."""
        plan = self._unit.plan
        if self.is_leader:
            self._send(now)
            return None
        error = self.state.measure(now, plan.chip_rate_hz, plan.code_length)
        self._update_leak()
        return error

    def _send(self, now: float) -> None:
        unit = self._unit
        self._counter = (self._counter + 1) & 0xFFFF
        unit.link.outbox.append(nf.encode_sync(unit.name, unit.unit_id, self._counter,
                                               unit.plan))
        unit._flush(now)

    def _update_leak(self) -> None:
        error, row = self.state.error_chips, self._unit.code_row
        if error is None or row is None:
            self.leak = None
            return
        others = [r for r in self._unit.contest.taken_by() if r != row]
        self.leak = worst_leak(row, others, self._unit.plan.code_length, error)

    def aligned(self, now: float) -> bool:
        """True outside sync mode, for the leader, and for a follower whose fresh alignment
        error is within ``max_misalignment_chips``."""
        plan = self._unit.plan
        if plan.mode != "sync" or self._unit._leader_peer() is None:
            return True
        max_age = max(3.0 * plan.cycle_s, self._unit.window_s)
        error = self.state.error_chips
        return (self.state.fresh(now, max_age) and error is not None
                and abs(error) <= self.max_misalignment_chips)
