"""What a unit knows about the other units on its bus, keyed by their identifier identity.

The table is bounded and rate-limited so that a babbling or flooding sender costs memory
and time in proportion to the limits, never more: an identity that sends more than
``babble_limit`` frames in one second is quarantined (its frames are counted and dropped,
except its CLAIMs: a claim may contest our row, and a forger babbling under a real unit's
identity must not silence that unit's claims; see ``Inbox``), and beyond ``max_peers`` identities a
new one takes the place of one that owns no code (:class:`PeerTable`).
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

from atris_node.bus.negotiation.frames import Identity
from atris_node.bus.negotiation.plan import Plan

logger = logging.getLogger(__name__)

BABBLE_WINDOW_S = 1.0


@dataclass
class Peer:
    """Another unit as last heard.

    Attributes:
        identity: identity bits of its identifiers.
        last_seen_s: receipt time of its newest frame, on the negotiator's clock.
        name: its 64-bit NAME, None until a frame carrying it was heard.
        plan: the plan it announced, None until heard.
        code_row: the row it claims (1-based), None when it has none.
        cannot_claim: it said it has no code.
        conflict: it cannot adopt the winning plan (it claims nothing in ours).
        established: it owns a code under its plan (a running fleet a joiner adopts).
        grown: its plan is one it grew to fit the units (a leader's; see agreement).
        nonce: the random instance number in its PLAN frames.
        quarantined_until_s: frames before this time are dropped (babbling).
        recent_s / changes_s: receipt times of its frames / of its claim and plan changes
            in the last second.
    """

    identity: Identity
    last_seen_s: float
    name: int | None = None
    plan: Plan | None = None
    code_row: int | None = None
    cannot_claim: bool = False
    conflict: bool = False
    established: bool = False
    grown: bool = False
    nonce: int | None = None
    quarantined_until_s: float = 0.0
    recent_s: deque[float] = field(default_factory=deque)
    changes_s: deque[float] = field(default_factory=deque)

    def label(self) -> str:
        """NAME in hex (or the identity when the NAME is not known yet), for logs."""
        if self.name is not None:
            return f"{self.name:#018x}"
        return f"identity {self.identity.bits:#06x}"


class PeerTable:
    """Bounded table of peers with per-identity rate limiting.

    When the table is full, a new identity takes the place of the peer that matters
    least (:func:`keep_rank`): one whose NAME is unknown, then one that claims nothing,
    then a claimant shadowed by a lower NAME on its row, least recently heard first. The
    lowest NAME claiming each row is never evicted, so identities that are no unit cannot
    push a code's owner out. Only when every entry owns a row is a new identity's frame
    dropped (``overflowed`` says so for that frame).

    Args:
        max_peers: most identities remembered at once.
        babble_limit: frames per second above which an identity is quarantined.
        max_changes: claim or plan changes per second above which it is quarantined (an
            honest unit changes its claim at most once per lower NAME it meets).
        quarantine_s: how long a babbling identity's frames (but its claims) are dropped;
            extended while it keeps sending above ``babble_limit``.
    """

    def __init__(self, max_peers: int = 64, babble_limit: int = 100, max_changes: int = 20,
                 quarantine_s: float = 2.0) -> None:
        self.max_peers = max_peers
        self.babble_limit = babble_limit
        self.max_changes = max_changes
        self.quarantine_s = quarantine_s
        self.peers: dict[int, Peer] = {}
        self.dropped_frames = 0
        self.babblers = 0
        self.evicted = 0
        self.overflowed = False

    def accept(self, identity: Identity, now: float) -> Peer | None:
        """The peer a frame received at ``now`` belongs to, or None to drop the frame."""
        peer = self.peers.get(identity.bits)
        self.overflowed = False
        if peer is None:
            if len(self.peers) >= self.max_peers and not self._make_room():
                self.dropped_frames += 1
                self.overflowed = True
                return None
            peer = self.peers[identity.bits] = Peer(identity, now)
        peer.last_seen_s = now
        too_many = _count(peer.recent_s, now) > self.babble_limit
        if too_many and now >= peer.quarantined_until_s:
            self._quarantine(peer, now, f"more than {self.babble_limit} frames/s")
        elif too_many:
            peer.quarantined_until_s = now + self.quarantine_s
        if now < peer.quarantined_until_s:
            self.dropped_frames += 1
            return None
        return peer

    def _make_room(self) -> bool:
        """Evict the entry that matters least; False when every entry owns a row."""
        owners = row_owners(self.peers.values())
        victim = min(self.peers.values(), key=lambda p: keep_rank(p, owners))
        if keep_rank(victim, owners)[0] >= OWNER_RANK:
            return False
        del self.peers[victim.identity.bits]
        self.evicted += 1
        logger.debug("peer table full: %s makes room", victim.label())
        return True

    def allow_change(self, peer: Peer, now: float) -> bool:
        """Count a change of claim or plan; False (and quarantine) when there are too many."""
        if _count(peer.changes_s, now) <= self.max_changes:
            return True
        self._quarantine(peer, now, f"more than {self.max_changes} claim/plan changes/s")
        return False

    def _quarantine(self, peer: Peer, now: float, why: str) -> None:
        peer.quarantined_until_s = now + self.quarantine_s
        peer.changes_s.clear()
        self.babblers += 1
        logger.warning("unit %s babbles (%s): its frames but its claims are dropped for "
                       "%.1f s", peer.label(), why, self.quarantine_s)

    def forget(self, peer: Peer) -> None:
        """Remove ``peer`` (it said it leaves)."""
        self.peers.pop(peer.identity.bits, None)

    def expire(self, now: float, silence_timeout_s: float) -> list[Peer]:
        """Remove and return the peers silent for longer than ``silence_timeout_s``."""
        gone = [p for p in self.peers.values() if now - p.last_seen_s > silence_timeout_s]
        for peer in gone:
            del self.peers[peer.identity.bits]
        return gone

    def named(self) -> list[Peer]:
        """Peers whose NAME is known."""
        return [p for p in self.peers.values() if p.name is not None]

    def clear(self) -> None:
        """Forget everyone (stop)."""
        self.peers.clear()


def _count(times: deque[float], now: float) -> int:
    """Append ``now`` to ``times``, drop entries older than one second, return the count."""
    times.append(now)
    while times and now - times[0] > BABBLE_WINDOW_S:
        times.popleft()
    return len(times)


#: :func:`keep_rank` of the lowest NAME claiming a row: never evicted
OWNER_RANK = 3


def row_owners(peers: Iterable[Peer]) -> dict[tuple[Plan | None, int], int]:
    """(plan, row) -> the lowest NAME claiming that row under that plan."""
    owners: dict[tuple[Plan | None, int], int] = {}
    for p in peers:
        if p.name is not None and p.code_row is not None:
            key = (p.plan, p.code_row)
            owners[key] = min(owners.get(key, p.name), p.name)
    return owners


def keep_rank(peer: Peer, owners: dict[tuple[Plan | None, int], int]) -> tuple[int, float]:
    """How much ``peer`` matters, lowest first: (0) NAME unknown, (1) claims no row,
    (2) claims a row a lower NAME also claims, (3) the lowest NAME on its row; then the
    time it was last heard (the least recent goes first)."""
    if peer.name is None:
        rank = 0
    elif peer.code_row is None:
        rank = 1
    elif owners.get((peer.plan, peer.code_row)) != peer.name:
        rank = 2
    else:
        rank = OWNER_RANK
    return rank, peer.last_seen_s
