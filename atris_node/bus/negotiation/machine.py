"""Code negotiation between the units on one bus (J1939-81 address claim, for Walsh codes).

Two units strobing the same code corrupt each other's ranges, so a unit strobes a code
only after its claim stood uncontested for the contest window, and stops at once when a
lower NAME claims it. The plan (N, chip rate, mode) of the lowest NAME wins; a unit adopts
it before claiming. The protocol is written up in ``docs/negotiation.md``.

The class is a canopen-style service: frames arrive as ``(can_id, data, timestamp)``
through :meth:`Negotiator.on_frame` (from a python-can Notifier, or read by :meth:`tick`
itself with ``poll_bus=True``), callbacks never block and never send, and all timing is
driven by :meth:`tick` on an injectable clock, so tests run on a fake clock.

Example (one unit alone on a virtual bus, fake time)::

    bus = can.Bus(interface="virtual", channel="doc")
    t = [0.0]
    unit = Negotiator(bus, name=0x10, plan=Plan(16, 480.0), unit_id=1,
                      clock=lambda: t[0], poll_bus=True)
    unit.start()
    for step in range(100):
        t[0] = step * 0.01
        unit.tick()
    assert unit.may_strobe and unit.code_row == 2
    unit.stop(); bus.shutdown()
"""

from __future__ import annotations

import logging
import secrets
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import replace

import can

from atris_node.bus.negotiation import choice, inbox
from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.agreement import PlanAgreement
from atris_node.bus.negotiation.contest import CodeContest
from atris_node.bus.negotiation.hop import InterferenceMonitor
from atris_node.bus.negotiation.lease import TransmitLease
from atris_node.bus.negotiation.link import Link
from atris_node.bus.negotiation.peers import Peer, PeerTable
from atris_node.bus.negotiation.plan import MAX_CODE_LENGTH, Plan
from atris_node.bus.negotiation.state import NegotiationState
from atris_node.bus.negotiation.syncmode import SyncMode
from atris_node.errors import BusError, ConfigError, NegotiationError
from atris_node.types import FaultBits

logger = logging.getLogger(__name__)

Clock = Callable[[], float]
ChangeCallback = Callable[["NegotiationState", int | None, Plan], None]


class Negotiator:
    """Claims a cyclic orthogonal code for one unit and says when it may strobe.

    Args:
        bus: the unit's python-can bus (29-bit frames must pass its filters).
        name: the unit's 64-bit NAME; the lowest NAME wins codes and plan.
        plan: the unit's configured plan; replaced by the bus plan when it loses.
        unit_id: 0..15, the unit's ID block; part of the identity bits.
        clock: seconds, monotonic; every time below is on this clock.
        window_s: contest window between claim and first strobe, seconds.
        reannounce_s: period of PLAN + CLAIM re-announcements, seconds.
        silence_timeout_s: a peer silent this long is gone and its code free, seconds.
        mode: overrides ``plan.mode`` when given (``"async"`` or ``"sync"``).
        listen_s: how long a starting unit listens for the bus plan before claiming.
        max_code_length: the longest N this unit accepts or grows the plan to.
        can_sync: the camera can be triggered, so sync plans can be adopted.
        can_adopt: extra check of a plan (camera rate etc.); False makes a CONFLICT.
        max_misalignment_chips: sync followers strobe only when aligned this well.
        notifier: a Notifier the node already runs on ``bus`` (one per bus); else one is made.
        poll_bus: read the bus inside :meth:`tick` instead (no thread; deterministic tests).
        on_change: called with ``(state, code_row, plan)`` after every change.
        nonce_source: draws the random 1..255 instance number of each start (PLAN frames:
            tells our echo from a unit with our identity); default ``secrets``.
    """

    def __init__(self, bus: can.BusABC, name: int, plan: Plan, unit_id: int,
                 clock: Clock = time.monotonic, window_s: float = 0.25,
                 reannounce_s: float = 1.0, silence_timeout_s: float = 3.0,
                 mode: str | None = None, *, listen_s: float = 0.1,
                 max_code_length: int = MAX_CODE_LENGTH, can_sync: bool = True,
                 can_adopt: Callable[[Plan], bool] | None = None,
                 max_misalignment_chips: float = 0.1,
                 notifier: can.Notifier | None = None, poll_bus: bool = False,
                 on_change: ChangeCallback | None = None,
                 interference: InterferenceMonitor | None = None,
                 nonce_source: Callable[[], int] | None = None) -> None:
        self.name = name
        self.unit_id = unit_id
        self.identity = nf.identity_of(name, unit_id)
        self.clock = clock
        self._check_timing(window_s, reannounce_s, silence_timeout_s, listen_s)
        self.window_s, self.reannounce_s = window_s, reannounce_s
        self.silence_timeout_s, self.listen_s = silence_timeout_s, listen_s
        self.agreement = PlanAgreement(self, replace(plan, mode=mode) if mode else plan,
                                       max_code_length, can_sync, can_adopt)
        self.on_change = on_change
        self._draw_nonce = nonce_source or (lambda: secrets.randbelow(255) + 1)
        self.interference = interference or InterferenceMonitor()
        self.link = Link(bus, lambda msg: self.on_message(msg, self.clock()), self.store_error,
                         notifier, poll_bus)
        self.receive = self.link.receive
        self._lock = threading.RLock()
        self.peers = PeerTable()
        self.inbox = inbox.Inbox(self.peers, name, unit_id, self.identity)
        self.sync = SyncMode(self, max_misalignment_chips)
        self.lease = TransmitLease()
        self.contest = CodeContest(self)
        self.timeline: list[tuple[float, bool, int | None]] = []
        self.malformed_frames = 0
        self.conflict_reason: str | None = None
        self._reset_runtime()

    @staticmethod
    def _check_timing(window_s: float, reannounce_s: float, silence_s: float,
                      listen_s: float) -> None:
        if not (0.0 < window_s < reannounce_s < silence_s and 0.0 <= listen_s < reannounce_s):
            raise ConfigError(
                "negotiation timing must satisfy 0 < window_s < reannounce_s < "
                f"silence_timeout_s and 0 <= listen_s < reannounce_s; got window_s={window_s}, "
                f"reannounce_s={reannounce_s}, silence_timeout_s={silence_s}, "
                f"listen_s={listen_s}")

    def _reset_runtime(self) -> None:
        self._state = NegotiationState.IDLE
        self.agreement.reset()
        self._code_row: int | None = None
        self._may_strobe = False
        self.lease.reset()
        self._started_s = 0.0
        self._listening = False
        self.contest.reset()
        self.link.outbox.clear()
        self._nonce = self._draw_nonce()
        self._duplicate_until_s = -1e9
        self.sync.restart()
        self._error: BaseException | None = None
        self._reported: tuple[NegotiationState, int | None, Plan] | None = None

    # ------------------------------------------------------------------ public state
    @property
    def bus(self) -> can.BusABC:
        """The python-can bus the negotiation frames go over (replaceable before start)."""
        return self.link.bus

    @bus.setter
    def bus(self, bus: can.BusABC) -> None:
        self.link.bus = bus

    @property
    def state(self) -> NegotiationState:
        """The negotiation state."""
        return self._state

    @property
    def code_row(self) -> int | None:
        """The claimed or owned 1-based Walsh row, None when none."""
        return self._code_row

    @property
    def plan(self) -> Plan:
        """The plan in use: the configured one until the bus plan replaced it."""
        return self.agreement.plan

    @property
    def plan_history(self) -> list[tuple[float, Plan]]:
        """``(time, plan)`` at every start and after every change."""
        return self.agreement.history

    @property
    def may_strobe(self) -> bool:
        """True only when OWNED, the claim stood the window and (sync) the chips are aligned."""
        return self._may_strobe

    @property
    def is_leader(self) -> bool:
        """True when this unit has the lowest NAME it knows of (it sends SYNC, decides N)."""
        return all(p.name is not None and p.name > self.name for p in self.peers.named())

    @property
    def is_sync_leader(self) -> bool:
        """True in sync mode when no lower NAME shares our plan: this unit sends SYNC."""
        return self.sync.is_leader

    @property
    def alignment_error_chips(self) -> float | None:
        """Last measured cycle start minus the leader's SYNC, in chips (sync followers)."""
        return self.sync.state.error_chips

    @property
    def hop_count(self) -> int:
        """Hops away from jammed codes since the start."""
        return self.interference.hop_count

    @property
    def faults(self) -> FaultBits:
        """Status-frame fault bits from the negotiation: PLAN_CONFLICT, FOREIGN_CODE."""
        bits = FaultBits.NONE
        if self._state is NegotiationState.CONFLICT:
            bits |= FaultBits.PLAN_CONFLICT
        if self.interference.active(self.clock()):
            bits |= FaultBits.FOREIGN_CODE
        return bits

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Send a request for claims and listen ``listen_s`` before claiming."""
        with self._lock:
            if self._state is not NegotiationState.IDLE:
                return
            self._reset_runtime()
            now = self.clock()
            self._started_s, self._listening = now, True
            self._set_state(NegotiationState.CLAIMING, None, now)
            self.plan_history.append((now, self.plan))
            self.link.outbox.append(nf.encode_request(self.name, self.unit_id))
            try:
                self.link.attach()
            except BusError:
                self._set_state(NegotiationState.IDLE, None, self.clock())
                raise
            self._flush(now)

    def stop(self) -> None:
        """Laser off, send cannot-claim so the code frees at once, detach. Idempotent."""
        with self._lock:
            if self._state is NegotiationState.IDLE:
                return
            now = self.clock()
            self._set_state(NegotiationState.IDLE, None, now)
            self.link.outbox = [nf.encode_cannot_claim(self.name, self.unit_id, leaving=True)]
            self._flush(now)
            self.peers.clear()
        self.link.detach()
        self._notify()

    def store_error(self, exc: BaseException) -> None:
        """Keep a receive error; :meth:`tick` turns the laser off and raises it."""
        self._error = exc

    # ------------------------------------------------------------------ receiving
    def on_message(self, msg: can.Message, now: float) -> None:
        """Handle one python-can message received at ``now`` (negotiator clock)."""
        self.receive.handled(msg.timestamp)
        if not msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return
        # msg.is_rx is not a test for our own frames: python-can's socketcan marks every
        # frame sent from this host is_rx=False, other local processes' frames included.
        # Own echoes are recognised by the identity and NAME they carry (on_frame).
        self.on_frame(msg.arbitration_id, bytes(msg.data), now)

    def on_frame(self, can_id: int, data: bytes, timestamp: float) -> None:
        """Handle one frame; ``timestamp`` is its receipt time on the negotiator clock."""
        header = nf.parse_id(can_id)
        if header is None:
            return
        with self._lock:
            if self._state is NegotiationState.IDLE:
                return
            try:
                self._dispatch(header, data, timestamp)
            except nf.FrameDecodeError as exc:
                self.malformed_frames += 1
                logger.debug("malformed negotiation frame %#x: %s", can_id, exc)
        self._notify()

    def _dispatch(self, header: nf.Header, data: bytes, now: float) -> None:
        events = self.inbox.read(header, data, now, self._nonce)
        if events is None:
            return
        for event in events:
            self._react(event, now)
        self._refresh(now)

    def _react(self, event: inbox.Event, now: float) -> None:
        if isinstance(event, inbox.Duplicate):
            self._duplicate(now, event.reason)
        elif isinstance(event, inbox.AnnounceDue):
            self.contest.announce_due = True
        elif isinstance(event, inbox.Claimed):
            self.contest.on_claim(event.peer, event.row, now)
        elif isinstance(event, inbox.Proposed):
            self._on_proposal(event.peer, event.plan, now)
        else:
            self.sync.on_sync(event, now)

    # ------------------------------------------------------------------ the tick
    def tick(self, now: float | None = None) -> None:
        """Advance timers: windows, re-announcements, silence, plan; send queued frames.

        Raises:
            BusError: a receive error was stored; the laser is already off.
        """
        if self._state is NegotiationState.IDLE:
            return
        now = self.clock() if now is None else now
        if self.link.poll:
            for msg in self.link.received():
                self.on_message(msg, now)
        with self._lock:
            self._raise_stored_error(now)
            self.contest.check_own_silence(now)
            self._expire(now)
            if self._listening:
                self._end_listening(now)
            else:
                self.agreement.agree(now)
                self._advance(now)
            self.contest.reannounce(now)
            self._refresh(now)
            self._flush(now)
        self._notify()

    def _raise_stored_error(self, now: float) -> None:
        if self._error is None:
            return
        error, self._error = self._error, None
        self._set_state(NegotiationState.CLAIMING, None, now)
        raise BusError(f"negotiation lost the bus, laser off: {error}") from error

    def _expire(self, now: float) -> None:
        for peer in self.peers.expire(now, self.silence_timeout_s):
            logger.info("unit %s silent for %.1f s: row %s is free", peer.label(),
                        self.silence_timeout_s, peer.code_row)
        if (now >= self._duplicate_until_s and self.conflict_reason
                and not self.agreement.conflict):
            logger.info("duplicate gone: negotiating again")
            self.conflict_reason = None
            self._set_state(NegotiationState.CLAIMING, None, now)

    def _end_listening(self, now: float) -> None:
        if now - self._started_s < self.listen_s or not self.receive.caught_up():
            return
        self._listening = False
        self.agreement.join(now)
        self._maybe_grow(now)
        if self._state is NegotiationState.CLAIMING and self._code_row is None:
            self.contest.choose(now)
        self.contest.announce_due = True

    def _advance(self, now: float) -> None:
        if self._state is NegotiationState.CONFLICT:
            return
        self._maybe_grow(now)
        self.contest.check_refusals(now)
        self.contest.advance(now)

    # ------------------------------------------------------------------ sending
    def _flush(self, now: float) -> None:
        """Send the queued frames. The claim window runs from the moment the bus took our
        CLAIM of the row; a refused frame starts the refusal clock, a taken one ends it."""
        taken, refused = self.link.flush(now)
        self.lease.flushed(len(taken), refused, any(map(self.contest.is_our_claim, taken)), now)
        if refused:
            self.contest.announce_due = True

    def report_send_failure(self, now: float | None = None) -> None:
        """Another of this unit's frames (its distances) could not be sent."""
        with self._lock:
            now = self.clock() if now is None else now
            self.lease.refused(now)
            self.contest.announce_due = True  # a momentary full queue takes the retry
            self.contest.check_refusals(now)
        self._notify()

    def report_send_ok(self) -> None:
        """Another of this unit's frames (its distances) was taken by the bus."""
        self.lease.taken()

    # ------------------------------------------------------------------ plan
    def _leader_peer(self) -> Peer | None:
        """The lowest NAME sharing our plan below ours (the sync leader), or None."""
        return choice.leader_peer(self.peers.named(), self.plan, self.name)

    def _maybe_grow(self, now: float) -> None:
        if self._state is not NegotiationState.CONFLICT:
            self.agreement.maybe_grow(now)

    def request_plan(self, code_length: int) -> None:
        """Ask the bus for code length ``code_length`` (same chip rate and mode).

        The lowest NAME decides: it adopts the request when this many codes fit the units on
        the bus and every unit can run it; everyone then re-claims under the new plan.

        Raises:
            CodeError: ``code_length`` is not a power of two in 2..128.
        """
        with self._lock:
            wanted = replace(self.plan, code_length=code_length)
            if self.is_leader:
                self._on_proposal(None, wanted, self.clock())
            else:
                self.link.outbox.append(self.agreement.frame(wanted, proposal=True))
                self._flush(self.clock())
        self._notify()

    def _on_proposal(self, peer: Peer | None, plan: Plan, now: float) -> None:
        if self.is_leader and not self._listening and self.agreement.on_proposal(peer, plan,
                                                                                now):
            self._flush(now)

    # ------------------------------------------------------------------ conflicts
    def _duplicate(self, now: float, reason: str) -> None:
        if self.conflict_reason != reason:
            logger.error("%s: misconfiguration, laser off while it lasts", reason)
        self.conflict_reason = reason
        self._duplicate_until_s = now + self.silence_timeout_s
        self._set_state(NegotiationState.CONFLICT, None, now)

    # ------------------------------------------------------------------ sync mode
    def cycle_started(self, now: float | None = None) -> float | None:
        """Tell the negotiator this unit's code period started (chip 0) at ``now``.

        The sync leader sends SYNC here; a follower measures its alignment error to the
        newest SYNC and the leak it causes. Returns the error in chips (None for the leader,
        in async mode, or before a SYNC was heard).
        """
        with self._lock:
            now = self.clock() if now is None else now
            if self.plan.mode != "sync" or self._state is NegotiationState.IDLE:
                return None
            error = self.sync.cycle_started(now)
            self._refresh(now)
        self._notify()
        return error

    # ------------------------------------------------------------------ interference
    def report_interference(self, own_excess: float, foreign: Mapping[int, float],
                            now: float | None = None) -> None:
        """Feed one interference measurement; sustained own-code excess makes the unit hop.

        Args:
            own_excess: energy on the own code beyond what the own strobe explains,
                fraction of the own line energy (>= 0).
            foreign: 1-based row -> energy of that code of the plan, same unit.
            now: measurement time (default: the clock).
        """
        with self._lock:
            now = self.clock() if now is None else now
            strobing = self._state is NegotiationState.OWNED
            if self.interference.report(own_excess, foreign, now, strobing):
                self.contest.hop(now)
                self._flush(now)
        self._notify()

    # ------------------------------------------------------------------ bookkeeping
    def _set_state(self, state: NegotiationState, row: int | None, now: float) -> None:
        self._state, self._code_row = state, row
        self._refresh(now)

    def _refresh(self, now: float) -> None:
        """Recompute may_strobe and extend the strobe timeline when it or the row changed."""
        owned = self._state is NegotiationState.OWNED and self._code_row is not None
        self._may_strobe = owned and self.sync.aligned(now)
        entry = (now, self._may_strobe, self._code_row)
        if not self.timeline or self.timeline[-1][1:] != entry[1:]:
            self.timeline.append(entry)

    def _notify(self) -> None:
        current = (self._state, self._code_row, self.plan)
        if current == self._reported or self.on_change is None:
            self._reported = current
            return
        self._reported = current
        try:
            self.on_change(*current)
        except Exception:
            logger.exception("negotiation on_change callback failed")

    def require_code(self) -> int:
        """The owned row; raises :class:`NegotiationError` when the unit may not strobe."""
        if not self._may_strobe or self._code_row is None:
            raise NegotiationError(f"no code to strobe: state {self._state.name}, "
                                   f"reason {self.conflict_reason or 'window not passed'}")
        return self._code_row
