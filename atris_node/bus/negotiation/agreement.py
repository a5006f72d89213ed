"""Plan agreement: which plan (N, chip rate, mode) a unit runs.

The plan of the lowest NAME wins; a unit adopts it before it claims, and stays dark in
CONFLICT while it cannot run it. The leader (lowest NAME) fits N to the units that want a
code: it grows the plan when they exceed the codes, goes back towards the plan it grew from
when they are gone, and decides on the others' plan requests. The agreement is written up
in ``docs/negotiation.md``.

A service of one :class:`~atris_node.bus.negotiation.machine.Negotiator`: it runs under the
negotiator's lock, reads what the unit heard from the negotiator's peer table, and changes
the unit's state (claim again, conflict) only through the negotiator.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

from atris_node.bus.negotiation import choice
from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.peers import Peer
from atris_node.bus.negotiation.plan import Plan, capacity, grow_to_fit
from atris_node.bus.negotiation.state import NegotiationState

if TYPE_CHECKING:
    from atris_node.bus.negotiation.machine import Negotiator

logger = logging.getLogger(__name__)


class PlanAgreement:
    """The plan a unit runs, and the rules by which it changes.

    Attributes:
        configured_plan: the unit's own plan, used until the bus plan replaces it.
        plan: the plan in use.
        conflict: True while the bus plan is one this unit cannot run.
        history: ``(time, plan)`` at the start and after every change.
        growths: ``(from, to)`` of every change of N this unit made as leader.
    """

    def __init__(self, negotiator: Negotiator, plan: Plan, max_code_length: int,
                 can_sync: bool, can_adopt: Callable[[Plan], bool] | None) -> None:
        self._unit = negotiator
        self.configured_plan = plan
        self.max_code_length = max_code_length
        self.can_sync = can_sync
        self._can_adopt = can_adopt
        self.history: list[tuple[float, Plan]] = []
        self.growths: list[tuple[Plan, Plan]] = []
        self.plan = plan
        self.conflict = False
        self._growth: tuple[Plan, Plan] | None = None  # (plan grown from, grown plan)
        self._grown_by_leader: Plan | None = None  # the leader announced it grew this plan

    def reset(self) -> None:
        """Back to the configured plan (a start)."""
        self.plan, self.conflict, self._growth = self.configured_plan, False, None
        self._grown_by_leader = None

    def adoptable(self, plan: Plan) -> bool:
        """True when this unit can run ``plan`` (N, sync capability, the caller's check)."""
        if plan.code_length > self.max_code_length:
            return False
        if plan.mode == "sync" and not self.can_sync:
            return False
        return self._can_adopt is None or bool(self._can_adopt(plan))

    def demand(self) -> int:
        """Units that want a code: this one and every live peer whose NAME is known (it
        sent a REQUEST, CLAIM or CANNOT_CLAIM) and that is not in plan conflict. An
        identity heard only in SYNC or PLAN frames is no unit that wants a code."""
        return 1 + sum(1 for p in self._unit.peers.named() if not p.conflict)

    def join(self, now: float) -> None:
        """End of listening: join a running fleet on its plan, whatever our NAME, else take
        the lowest NAME's plan."""
        running = choice.running_plan(self._unit.peers.named())
        if running is not None:
            self.adopt_or_conflict(running, now)
        else:
            self.agree(now)

    def agree(self, now: float) -> None:
        """Adopt the plan of the lowest NAME heard (or retry our own after a conflict)."""
        winner = choice.plan_leader(self._unit.peers.named(), self._unit.name)
        if winner is not None:
            assert winner.plan is not None
            self._grown_by_leader = winner.plan if winner.grown else None
            self.adopt_or_conflict(winner.plan, now)
        elif self.conflict:
            self.adopt_or_conflict(self.plan, now)

    def adopt_or_conflict(self, plan: Plan, now: float) -> None:
        """Adopt ``plan``, or go dark in CONFLICT when this unit cannot run it."""
        unit = self._unit
        if not self.adoptable(plan):
            if not self.conflict:
                logger.error("plan N=%d %.3f Hz %s of a lower NAME cannot be adopted: "
                             "plan conflict, laser off", plan.code_length, plan.chip_rate_hz,
                             plan.mode)
            self.conflict, unit.conflict_reason = True, "plan"
            unit._set_state(NegotiationState.CONFLICT, None, now)
            unit.contest.announce_due = True
            return
        if self.conflict:
            self.conflict, unit.conflict_reason = False, None
            unit._set_state(NegotiationState.CLAIMING, None, now)
        self.adopt(plan, now)

    def adopt(self, plan: Plan, now: float) -> None:
        """Switch to ``plan``: laser off, re-claim (the same row when it is still in the
        set), unless a duplicate keeps the unit dark."""
        if plan == self.plan:
            return
        logger.info("plan N=%d %.3f Hz %s -> N=%d %.3f Hz %s", self.plan.code_length,
                    self.plan.chip_rate_hz, self.plan.mode, plan.code_length,
                    plan.chip_rate_hz, plan.mode)
        unit = self._unit
        previous_row = unit.code_row
        self.plan = plan
        unit.sync.state.reset()
        self.history.append((now, plan))
        unit.link.outbox.append(self.frame())
        if unit.conflict_reason is not None:  # a duplicate: stay dark, keep the plan
            unit._set_state(NegotiationState.CONFLICT, None, now)
            return
        unit._set_state(NegotiationState.CLAIMING, None, now)
        if not unit._listening:
            unit.contest.choose(now, prefer=previous_row)

    def _inherit_growth(self) -> None:
        """A new leader whose plan the former leader had grown for the units takes that
        growth over, from its own configured N: the fleet goes back to the smallest N that
        fits once the extra units are gone, whoever leads it by then."""
        if self._growth is None and self._grown_by_leader == self.plan:
            length = min(self.configured_plan.code_length, self.plan.code_length)
            self._growth = (replace(self.plan, code_length=length), self.plan)
            self._grown_by_leader = None

    def frame(self, plan: Plan | None = None, proposal: bool = False) -> nf.RawFrame:
        """Our PLAN frame: the plan in use (flagged grown while it is one this unit grew to
        fit the units), or a ``proposal`` of ``plan`` to the leader."""
        unit = self._unit
        owned = unit.state is NegotiationState.OWNED
        grown = (not proposal and self._growth is not None and self.plan == self._growth[1])
        announcement = nf.PlanAnnouncement(plan or self.plan, proposal, self.conflict,
                                           unit._nonce, owned and not proposal, grown)
        return nf.encode_plan(unit.name, unit.unit_id, announcement)

    def maybe_grow(self, now: float) -> None:
        """The leader fits N to the units: it grows when they exceed the codes, and goes
        back towards the plan it grew from when they are gone (never below that plan).
        The negotiator calls it only outside CONFLICT."""
        if not self._unit.is_leader:
            return
        units = self.demand()
        fitted = self._fitted(units)
        if fitted is None or fitted == self.plan:
            return
        logger.warning("%d units, %d codes: N %d -> %d, output rate %.2f -> %.2f Hz",
                       units, capacity(self.plan), self.plan.code_length,
                       fitted.code_length, self.plan.output_rate_hz, fitted.output_rate_hz)
        self.growths.append((self.plan, fitted))
        base = self.plan if self._growth is None else self._growth[0]
        self._growth = None if fitted == base else (base, fitted)
        self.adopt(fitted, now)

    def _fitted(self, units: int) -> Plan | None:
        self._inherit_growth()
        if units > capacity(self.plan) and self.plan.code_length < self.max_code_length:
            return grow_to_fit(self.plan, units, self.max_code_length)
        if self._growth is not None and self.plan == self._growth[1]:
            return grow_to_fit(self._growth[0], units, self.max_code_length)
        return None

    def on_proposal(self, peer: Peer | None, plan: Plan, now: float) -> bool:
        """The leader adopts a requested plan when it fits the units and every unit can run
        it (same chip rate and mode). True when adopted."""
        fits = capacity(plan) >= self.demand() and self.adoptable(plan)
        same_rate = (plan.chip_rate_hz, plan.mode) == (self.plan.chip_rate_hz, self.plan.mode)
        source = peer.label() if peer is not None else "this unit"
        if not (fits and same_rate):
            logger.warning("plan request N=%d from %s refused: %d units, %d codes",
                           plan.code_length, source, self.demand(), capacity(plan))
            return False
        logger.info("plan request N=%d from %s accepted", plan.code_length, source)
        self.adopt(plan, now)
        return True
