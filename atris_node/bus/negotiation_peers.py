"""What a unit knows about the other units on its bus, keyed by their identifier identity.

The table is bounded and rate-limited so that a babbling or flooding sender costs memory
and time in proportion to the limits, never more: an identity that sends more than
``babble_limit`` frames in one second is quarantined (its frames are counted and dropped,
its last accepted claim still counts as taken), and identities beyond ``max_peers`` are
ignored.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

from atris_node.bus.negotiation_frames import Identity
from atris_node.bus.negotiation_plan import Plan

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
        nonce: the random instance number in its PLAN frames.
        quarantined_until_s: frames before this time are dropped (babbling).
    """

    identity: Identity
    last_seen_s: float
    name: int | None = None
    plan: Plan | None = None
    code_row: int | None = None
    cannot_claim: bool = False
    conflict: bool = False
    nonce: int | None = None
    quarantined_until_s: float = 0.0
    recent_s: deque[float] = field(default_factory=deque)

    def label(self) -> str:
        """NAME in hex (or the identity when the NAME is not known yet), for logs."""
        if self.name is not None:
            return f"{self.name:#018x}"
        return f"identity {self.identity.bits:#06x}"


class PeerTable:
    """Bounded table of peers with per-identity rate limiting.

    Args:
        max_peers: most identities remembered at once.
        babble_limit: frames per second above which an identity is quarantined.
        quarantine_s: how long a babbling identity's frames are dropped.
    """

    def __init__(self, max_peers: int = 64, babble_limit: int = 100,
                 quarantine_s: float = 2.0) -> None:
        self.max_peers = max_peers
        self.babble_limit = babble_limit
        self.quarantine_s = quarantine_s
        self.peers: dict[int, Peer] = {}
        self.dropped_frames = 0
        self.babblers = 0

    def accept(self, identity: Identity, now: float) -> Peer | None:
        """The peer a frame received at ``now`` belongs to, or None to drop the frame."""
        peer = self.peers.get(identity.bits)
        if peer is None:
            if len(self.peers) >= self.max_peers:
                self.dropped_frames += 1
                return None
            peer = self.peers[identity.bits] = Peer(identity, now)
        peer.last_seen_s = now
        if self._babbling(peer, now):
            self.dropped_frames += 1
            return None
        return peer

    def _babbling(self, peer: Peer, now: float) -> bool:
        if now < peer.quarantined_until_s:
            return True
        peer.recent_s.append(now)
        while peer.recent_s and now - peer.recent_s[0] > BABBLE_WINDOW_S:
            peer.recent_s.popleft()
        if len(peer.recent_s) <= self.babble_limit:
            return False
        peer.quarantined_until_s = now + self.quarantine_s
        peer.recent_s.clear()
        self.babblers += 1
        logger.warning("unit %s sends more than %d frames/s: ignored for %.1f s",
                       peer.label(), self.babble_limit, self.quarantine_s)
        return True

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
