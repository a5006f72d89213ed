"""What the other units said: negotiation frames into peer records and events.

:class:`Inbox` checks each frame (layout and field ranges), recognises our own echoes and
a unit that sends with our identity or NAME, keeps the peer table up to date (NAME, row,
plan, nonce, leaving) within the table's rate limits, and returns what the state machine
(:mod:`atris_node.bus.negotiation.machine`) must react to as events. It never sends and
never changes the machine's state.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.peers import Peer, PeerTable
from atris_node.bus.negotiation.plan import Plan

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Duplicate:
    """Another unit sends with our identity or our NAME: a misconfiguration."""

    reason: str


@dataclass(frozen=True)
class AnnounceDue:
    """A unit asked for claims: announce plan and claim soon."""


@dataclass(frozen=True)
class Claimed:
    """``peer`` claims ``row`` (its record already says so)."""

    peer: Peer
    row: int


@dataclass(frozen=True)
class Proposed:
    """``peer`` asks the leader for ``plan``."""

    peer: Peer
    plan: Plan


@dataclass(frozen=True)
class SyncHeard:
    """``peer`` started its code period: SYNC ``counter`` for code length ``code_length``."""

    peer: Peer
    counter: int
    code_length: int


Event = Duplicate | AnnounceDue | Claimed | Proposed | SyncHeard
Handler = Callable[[Peer, nf.Header, bytes, float], list[Event]]


class Inbox:
    """Reads the negotiation frames of the other units into ``peers``.

    Args:
        peers: the peer table (rate limits and quarantine are its own).
        name: our 64-bit NAME.
        unit_id: our unit id (for the duplicate-identity message).
        identity: the identity bits of our identifiers.
    """

    def __init__(self, peers: PeerTable, name: int, unit_id: int,
                 identity: nf.Identity) -> None:
        self.peers = peers
        self.name, self.unit_id, self.identity = name, unit_id, identity
        self._handlers: dict[nf.FrameKind, Handler] = {
            nf.FrameKind.REQUEST: self._request, nf.FrameKind.CLAIM: self._claim,
            nf.FrameKind.CANNOT_CLAIM: self._cannot_claim, nf.FrameKind.PLAN: self._plan,
            nf.FrameKind.SYNC: self._sync}

    def read(self, header: nf.Header, data: bytes, now: float,
             nonce: int) -> list[Event] | None:
        """The events of one frame received at ``now``; None when it was ours (an echo,
        ``nonce`` being our PLAN instance number) or its sender is rate-limited.

        Raises:
            FrameDecodeError: the payload or the identifier's field is malformed.
        """
        if header.identity == self.identity:
            return self._own_or_clash(header, data, nonce)
        check(header, data)
        peer = self.peers.accept(header.identity, now)
        if peer is None:
            return self._dropped_claim(header, data, now)
        return self._handlers[header.kind](peer, header, data, now)

    def _dropped_claim(self, header: nf.Header, data: bytes, now: float) -> list[Event] | None:
        """A CLAIM the table dropped still contests our row: ignoring it could leave two
        owners of a row. From a quarantined identity (a babbler, or a forger babbling
        under a real unit's identity) it updates the kept record; from an identity a full
        table of code owners cannot hold, it is judged from a record that is not kept."""
        if header.kind is not nf.FrameKind.CLAIM:
            return None
        peer = self.peers.peers.get(header.identity.bits) or Peer(header.identity, now)
        return self._claim(peer, header, data, now)

    def _own_or_clash(self, header: nf.Header, data: bytes, nonce: int) -> list[Event] | None:
        """None for our own echoed frame; a foreign frame with our identity is a clash."""
        kind = header.kind
        if kind is nf.FrameKind.SYNC:
            return None
        if kind is nf.FrameKind.PLAN:
            if nf.decode_plan(data).nonce == nonce:
                return None
        elif nf.decode_name(data) == self.name:
            return None
        return [Duplicate(f"another unit sends with our identity (unit_id {self.unit_id})")]

    def _learn_name(self, peer: Peer, data: bytes) -> Duplicate | None:
        """Store the NAME of ``peer``; a Duplicate when it is our own NAME."""
        name = nf.decode_name(data)
        if name == self.name:
            return Duplicate(f"duplicate NAME {name:#018x} from unit_id "
                             f"{peer.identity.unit_id}")
        peer.name = name
        return None

    def _request(self, peer: Peer, header: nf.Header, data: bytes, now: float) -> list[Event]:
        duplicate = self._learn_name(peer, data)
        return [duplicate or AnnounceDue()]

    def _claim(self, peer: Peer, header: nf.Header, data: bytes, now: float) -> list[Event]:
        duplicate = self._learn_name(peer, data)
        if duplicate is not None:
            return [duplicate]
        if peer.code_row != header.field:
            # counted (too many quarantine its other frames), never dropped: it may be the
            # claim of our row by a lower NAME
            self.peers.allow_change(peer, now)
        peer.code_row, peer.cannot_claim = header.field, False
        return [Claimed(peer, header.field)]

    def _cannot_claim(self, peer: Peer, header: nf.Header, data: bytes,
                      now: float) -> list[Event]:
        duplicate = self._learn_name(peer, data)
        if duplicate is not None:
            return [duplicate]
        peer.code_row, peer.cannot_claim = None, True
        if header.field == nf.LEAVING:
            logger.info("unit %s leaves the bus", peer.label())
            self.peers.forget(peer)
        return []

    def _plan(self, peer: Peer, header: nf.Header, data: bytes, now: float) -> list[Event]:
        announcement = nf.decode_plan(data)
        changed = announcement.proposal or peer.plan not in (None, announcement.plan)
        if changed and not self.peers.allow_change(peer, now):
            return []
        if announcement.proposal:  # only a unit that said its NAME may ask for a plan
            return [] if peer.name is None else [Proposed(peer, announcement.plan)]
        if peer.plan != announcement.plan:
            peer.code_row = None  # its claims were for its previous plan
        peer.plan, peer.conflict = announcement.plan, announcement.conflict
        peer.established, peer.grown = announcement.established, announcement.grown
        if peer.nonce is not None and peer.nonce != announcement.nonce and peer.name:
            logger.info("unit %s restarted", peer.label())
        peer.nonce = announcement.nonce
        return []

    def _sync(self, peer: Peer, header: nf.Header, data: bytes, now: float) -> list[Event]:
        counter, code_length, _ = nf.decode_sync(data)
        return [SyncHeard(peer, counter, code_length)]


def check(header: nf.Header, data: bytes) -> None:
    """Reject a frame of another unit whose payload or field no sender can mean.

    Raises:
        FrameDecodeError: naming what was wrong.
    """
    if header.kind is nf.FrameKind.PLAN:
        nf.decode_plan(data)
    elif header.kind is not nf.FrameKind.SYNC:
        nf.decode_name(data)
    if header.kind is nf.FrameKind.CLAIM and header.field < 2:
        raise nf.FrameDecodeError(f"CLAIM of row {header.field}: rows start at 2")
    if header.kind is not nf.FrameKind.CLAIM and header.field > nf.LEAVING:
        raise nf.FrameDecodeError(f"{header.kind.name} with field {header.field}")
