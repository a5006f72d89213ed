"""The contest for a row: choose a code, claim it, defend it, own it, lose it, hop.

A unit claims a free row of the plan (else the row of the highest NAME above its own),
owns it once the claim stood the contest window on a bus that takes its frames, answers a
higher NAME's claim of the row, gives the row up at once to a lower NAME, and re-announces
its plan and claim every ``reannounce_s`` (sooner when asked). The rules are written up in
``docs/negotiation.md``.

A service of one :class:`~atris_node.bus.negotiation.machine.Negotiator`: it runs under the
negotiator's lock, sends through the negotiator's link and changes the unit's state only
through the negotiator.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from atris_node.bus.negotiation import choice
from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.peers import Peer
from atris_node.bus.negotiation.plan import capacity
from atris_node.bus.negotiation.state import NegotiationState

if TYPE_CHECKING:
    from atris_node.bus.negotiation.machine import Negotiator

logger = logging.getLogger(__name__)

#: shortest gap between two re-announcements (answers to request-for-claims), seconds
MIN_ANNOUNCE_GAP_S = 0.05


class CodeContest:
    """Which row one unit claims, and when it announces it.

    Attributes:
        announce_due: re-announce plan and claim at the next tick (at most every
            :data:`MIN_ANNOUNCE_GAP_S`).
    """

    def __init__(self, negotiator: Negotiator) -> None:
        self._unit = negotiator
        self.announce_due = False
        self._last_announce_s = -1e9
        self._last_defence_s = -1e9
        self._last_tick_s: float | None = None

    def reset(self) -> None:
        """Nothing announced yet (a start)."""
        self.announce_due = False
        self._last_announce_s = -1e9
        self._last_defence_s = -1e9
        self._last_tick_s = None

    def check_own_silence(self, now: float) -> None:
        """After a gap in our own ticks long enough for the others to have forgotten us (a
        hung host, a stopped process), our claim is void: another unit may own the row by
        now. Laser off, claim the row again; OWNED again only after the window."""
        unit = self._unit
        last, self._last_tick_s = self._last_tick_s, now
        gap = 0.0 if last is None else now - last
        holding = unit.state in (NegotiationState.CLAIMING, NegotiationState.OWNED)
        if gap < unit.silence_timeout_s - unit.reannounce_s or not holding:
            return
        if unit.code_row is not None:
            logger.warning("row %d: this unit was silent for %.2f s, others may have taken "
                           "the row: laser off, claiming again", unit.code_row, gap)
            unit.lease.claim_again()
            unit._set_state(NegotiationState.CLAIMING, unit.code_row, now)
        self.announce_due = True

    # ------------------------------------------------------------------ what is free
    def taken_by(self) -> dict[int, int]:
        """Rows of our plan claimed by other units -> the lowest NAME claiming each."""
        return choice.taken_by(self._unit.peers.named(), self._unit.plan)

    def free_rows(self, now: float) -> list[int]:
        """Rows of our plan nobody claims and nobody jams, in preference order."""
        return choice.free_rows(self.taken_by(), self._unit.plan, self._unit.interference, now)

    def preemptable(self, now: float) -> int | None:
        """The row held by the highest NAME above ours (lowest NAME wins), or None."""
        return choice.preemptable(self.taken_by(), self._unit.name, self._unit.plan,
                                  self._unit.interference, now)

    # ------------------------------------------------------------------ claiming
    def choose(self, now: float, prefer: int | None = None) -> None:
        """Claim a free row (``prefer`` first), else the row of the highest higher NAME;
        NO_CODE (cannot-claim sent, laser off) when there is none."""
        unit = self._unit
        free = self.free_rows(now)
        row = prefer if prefer in free else (free[0] if free else self.preemptable(now))
        plan = unit.plan
        if row is None:
            if unit.state is not NegotiationState.NO_CODE:
                logger.warning("no free code in N=%d %s (%d codes): cannot-claim, laser off",
                               plan.code_length, plan.mode, capacity(plan))
                unit.link.outbox.append(nf.encode_cannot_claim(unit.name, unit.unit_id))
            unit._set_state(NegotiationState.NO_CODE, None, now)
            return
        unit.lease.claim_again()
        unit._set_state(NegotiationState.CLAIMING, row, now)
        unit.link.outbox.append(nf.encode_claim(unit.name, unit.unit_id, row))
        logger.debug("claiming row %d of N=%d", row, plan.code_length)

    def lose(self, now: float, reason: str) -> None:
        """Stop strobing at once and look for another code."""
        logger.warning("lost row %s: %s", self._unit.code_row, reason)
        self._unit._set_state(NegotiationState.CLAIMING, None, now)
        self.choose(now)

    def advance(self, now: float) -> None:
        """OWNED once the claim stood the window on a bus that takes our frames; claim
        when we hold no row and one is free or preemptable."""
        unit, state, row = self._unit, self._unit.state, self._unit.code_row
        if state is NegotiationState.CLAIMING and row is not None:
            if unit.lease.window_passed(now, unit.window_s) and unit.receive.caught_up():
                unit._set_state(NegotiationState.OWNED, row, now)
                logger.info("row %d of N=%d owned", row, unit.plan.code_length)
        elif row is None and (state is NegotiationState.CLAIMING or self.free_rows(now)
                              or self.preemptable(now) is not None):
            self.choose(now)

    def on_claim(self, peer: Peer, row: int, now: float) -> None:
        """A lower NAME's claim of our row takes it; a higher NAME's is answered."""
        unit = self._unit
        claiming = unit.state in (NegotiationState.CLAIMING, NegotiationState.OWNED)
        holds = claiming and unit.code_row == row
        if not holds or not choice.same_plan(peer, unit.plan):
            return
        assert peer.name is not None
        if peer.name < unit.name:
            self.lose(now, f"unit {peer.label()} (lower NAME) claims row {row}")
        elif now - self._last_defence_s >= MIN_ANNOUNCE_GAP_S:
            self._last_defence_s = now
            unit.link.outbox.append(nf.encode_claim(unit.name, unit.unit_id, row))
        else:  # answered a moment ago: answer again with the next announcement, never drop
            self.announce_due = True

    def check_refusals(self, now: float) -> None:
        """Laser off and claim again when the transmit lease lapsed (bus-off, a stuck
        queue, a dead link): a unit whose frames go nowhere protects nobody, and nobody may
        hear its claim. OWNED again only after the bus took the new claim and the window
        passed."""
        unit = self._unit
        if not unit.lease.lapsed(now):
            return
        owned = unit.state is NegotiationState.OWNED
        if not owned and unit.lease.claim_sent_s is None:
            return
        if owned:
            logger.warning("row %s: the bus takes none of our frames since %.2f s: laser "
                           "off, claiming again", unit.code_row,
                           now - (unit.lease.refused_since_s or now))
        unit.lease.claim_again()
        if unit.state in (NegotiationState.CLAIMING, NegotiationState.OWNED):
            unit._set_state(NegotiationState.CLAIMING, unit.code_row, now)

    def hop(self, now: float) -> None:
        """Leave our jammed row for a free one (stay when none is free)."""
        unit = self._unit
        row = unit.code_row
        assert row is not None
        if not [r for r in self.free_rows(now) if r != row]:
            logger.warning("row %d is jammed and no other code is free: staying", row)
            return
        unit.interference.mark_jammed(row, now)
        logger.warning("row %d jammed by a unit not on this bus: hopping (hop %d)", row,
                       unit.interference.hop_count)
        unit._set_state(NegotiationState.CLAIMING, None, now)
        self.choose(now)

    # ------------------------------------------------------------------ announcing
    def reannounce(self, now: float) -> None:
        """PLAN and CLAIM (or CANNOT_CLAIM) every ``reannounce_s``, sooner when due."""
        unit = self._unit
        since = now - self._last_announce_s
        due = since >= unit.reannounce_s
        if not (due or (self.announce_due and since >= MIN_ANNOUNCE_GAP_S)):
            return
        if unit._listening:
            return
        self.announce_due, self._last_announce_s = False, now
        unit.link.outbox.append(unit.agreement.frame())
        if unit.code_row is not None and unit.state is not NegotiationState.CONFLICT:
            unit.link.outbox.append(nf.encode_claim(unit.name, unit.unit_id, unit.code_row))
        else:
            unit.link.outbox.append(nf.encode_cannot_claim(unit.name, unit.unit_id))

    def is_our_claim(self, frame: nf.RawFrame) -> bool:
        """True for our own CLAIM of the row we hold."""
        header = nf.parse_id(frame.can_id)
        return (header is not None and header.kind is nf.FrameKind.CLAIM
                and header.identity == self._unit.identity
                and header.field == self._unit.code_row)
