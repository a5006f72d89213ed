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

import enum
import logging
import secrets
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import replace

import can

from atris_node.bus.negotiation import choice, inbox
from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.hop import InterferenceMonitor
from atris_node.bus.negotiation.link import Link
from atris_node.bus.negotiation.peers import Peer, PeerTable
from atris_node.bus.negotiation.plan import MAX_CODE_LENGTH, Plan, capacity, grow_to_fit
from atris_node.bus.negotiation.sync import SyncState, worst_leak
from atris_node.errors import BusError, ConfigError, NegotiationError
from atris_node.types import FaultBits

logger = logging.getLogger(__name__)

Clock = Callable[[], float]
ChangeCallback = Callable[["NegotiationState", int | None, Plan], None]
#: shortest gap between two re-announcements (answers to request-for-claims), seconds
MIN_ANNOUNCE_GAP_S = 0.05
#: how long the bus may refuse our frames with none taken before the laser goes off, s
#: (a momentary full queue is retried after MIN_ANNOUNCE_GAP_S; bus-off is not)
REFUSED_GRACE_S = 0.1


class NegotiationState(enum.Enum):
    """Where a unit is in the negotiation. Only OWNED may strobe."""

    IDLE = 0  # not started, or stopped
    CLAIMING = 1  # listening, or claimed a code whose window has not passed
    OWNED = 2  # the claim stood the window
    NO_CODE = 3  # every code is taken by a lower NAME: cannot-claim sent, laser off
    CONFLICT = 4  # plan it cannot adopt, or duplicate NAME/identity: laser off


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
                 interference: InterferenceMonitor | None = None) -> None:
        self.name = name
        self.unit_id = unit_id
        self.identity = nf.identity_of(name, unit_id)
        self.clock = clock
        self._check_timing(window_s, reannounce_s, silence_timeout_s, listen_s)
        self.window_s, self.reannounce_s = window_s, reannounce_s
        self.silence_timeout_s, self.listen_s = silence_timeout_s, listen_s
        self.configured_plan = replace(plan, mode=mode) if mode else plan
        self.max_code_length = max_code_length
        self.can_sync = can_sync
        self._can_adopt = can_adopt
        self.max_misalignment_chips = max_misalignment_chips
        self.on_change = on_change
        self.interference = interference or InterferenceMonitor()
        self.link = Link(bus, lambda msg: self.on_message(msg, self.clock()), self.store_error,
                         notifier, poll_bus)
        self.receive = self.link.receive
        self._lock = threading.RLock()
        self.peers = PeerTable()
        self.inbox = inbox.Inbox(self.peers, name, unit_id, self.identity)
        self.sync = SyncState()
        self.timeline: list[tuple[float, bool, int | None]] = []
        self.plan_history: list[tuple[float, Plan]] = []
        self.malformed_frames = 0
        self.plan_growths: list[tuple[Plan, Plan]] = []
        self.sync_leak: float | None = None
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
        self._plan = self.configured_plan
        self._code_row: int | None = None
        self._may_strobe = False
        self._claim_sent_s: float | None = None  # our CLAIM of the row first went out
        self._refused_since_s: float | None = None  # the bus refuses our frames since
        self._started_s = 0.0
        self._listening = False
        self._last_announce_s = -1e9
        self._announce_due = False
        self.link.outbox.clear()
        self._nonce = secrets.randbelow(255) + 1
        self._duplicate_until_s = -1e9
        self._plan_conflict = False
        self._growth: tuple[Plan, Plan] | None = None  # (plan grown from, grown plan)
        self._sync_counter = 0
        self._last_defence_s = -1e9
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
        return self._plan

    @property
    def may_strobe(self) -> bool:
        """True only when OWNED, the claim stood the window and (sync) the chips are aligned."""
        return self._may_strobe

    @property
    def is_leader(self) -> bool:
        """True when this unit has the lowest NAME it knows of (it sends SYNC, decides N)."""
        return all(p.name is not None and p.name > self.name for p in self._live_named())

    @property
    def is_sync_leader(self) -> bool:
        """True in sync mode when no lower NAME shares our plan: this unit sends SYNC."""
        return self._plan.mode == "sync" and self._leader_peer() is None

    @property
    def alignment_error_chips(self) -> float | None:
        """Last measured cycle start minus the leader's SYNC, in chips (sync followers)."""
        return self.sync.error_chips

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
            self._plan_changed(now)
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
            self._announce_due = True
        elif isinstance(event, inbox.Claimed):
            self._on_claim(event.peer, event.row, now)
        elif isinstance(event, inbox.Proposed):
            self._on_proposal(event.peer, event.plan, now)
        else:
            self._on_sync(event, now)

    def _on_claim(self, peer: Peer, row: int, now: float) -> None:
        """A lower NAME's claim of our row takes it; a higher NAME's is answered."""
        if not self._holds(row) or not self._same_plan(peer):
            return
        assert peer.name is not None
        if peer.name < self.name:
            self._lose(now, f"unit {peer.label()} (lower NAME) claims row {row}")
        elif now - self._last_defence_s >= MIN_ANNOUNCE_GAP_S:
            self._last_defence_s = now
            self.link.outbox.append(nf.encode_claim(self.name, self.unit_id, row))
        else:  # answered a moment ago: answer again with the next announcement, never drop
            self._announce_due = True

    def _on_sync(self, event: inbox.SyncHeard, now: float) -> None:
        if self._plan.mode != "sync" or event.code_length != self._plan.code_length:
            return
        if event.peer.name is not None and event.peer is self._leader_peer():
            self.sync.on_sync(event.counter, now)

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
            self._expire(now)
            if self._listening:
                self._end_listening(now)
            else:
                self._agree_plan(now)
                self._advance(now)
            self._reannounce(now)
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
        if now >= self._duplicate_until_s and self.conflict_reason and not self._plan_conflict:
            logger.info("duplicate gone: negotiating again")
            self.conflict_reason = None
            self._set_state(NegotiationState.CLAIMING, None, now)

    def _end_listening(self, now: float) -> None:
        if now - self._started_s < self.listen_s or not self.receive.caught_up():
            return
        self._listening = False
        running = choice.running_plan(self._live_named())
        if running is not None:  # join a running fleet on its plan, whatever our NAME
            self._adopt_or_conflict(running, now)
        else:
            self._agree_plan(now)
        self._maybe_grow(now)
        if self._state is NegotiationState.CLAIMING and self._code_row is None:
            self._choose_code(now)
        self._announce_due = True

    def _advance(self, now: float) -> None:
        if self._state is NegotiationState.CONFLICT:
            return
        self._maybe_grow(now)
        self._check_refusals(now)
        if self._state is NegotiationState.CLAIMING and self._code_row is not None:
            sent_s = self._claim_sent_s
            if (sent_s is not None and now - sent_s >= self.window_s
                    and self._refused_since_s is None and self.receive.caught_up()):
                self._set_state(NegotiationState.OWNED, self._code_row, now)
                logger.info("row %d of N=%d owned", self._code_row, self._plan.code_length)
        elif self._code_row is None and (self._state is NegotiationState.CLAIMING
                                         or self._free_rows(now)
                                         or self._preemptable(now) is not None):
            self._choose_code(now)

    def _reannounce(self, now: float) -> None:
        due = now - self._last_announce_s >= self.reannounce_s
        if not (due or (self._announce_due and now - self._last_announce_s >= MIN_ANNOUNCE_GAP_S)):
            return
        if self._listening:
            return
        self._announce_due, self._last_announce_s = False, now
        self.link.outbox.append(self._plan_frame())
        if self._code_row is not None and self._state is not NegotiationState.CONFLICT:
            self.link.outbox.append(nf.encode_claim(self.name, self.unit_id, self._code_row))
        else:
            self.link.outbox.append(nf.encode_cannot_claim(self.name, self.unit_id))

    def _plan_frame(self, plan: Plan | None = None, proposal: bool = False) -> nf.RawFrame:
        owned = self._state is NegotiationState.OWNED
        announcement = nf.PlanAnnouncement(plan or self._plan, proposal, self._plan_conflict,
                                           self._nonce, owned and not proposal)
        return nf.encode_plan(self.name, self.unit_id, announcement)

    # ------------------------------------------------------------------ sending
    def _flush(self, now: float) -> None:
        """Send the queued frames. The claim window runs from the moment the bus took our
        CLAIM of the row; a refused frame starts the refusal clock, a taken one ends it."""
        taken, refused = self.link.flush(now)
        if refused:
            self._bus_refused(now)
        elif taken:
            self._refused_since_s = None
        if self._claim_sent_s is None and any(self._is_our_claim(f) for f in taken):
            self._claim_sent_s = now

    def _is_our_claim(self, frame: nf.RawFrame) -> bool:
        header = nf.parse_id(frame.can_id)
        return (header is not None and header.kind is nf.FrameKind.CLAIM
                and header.identity == self.identity and header.field == self._code_row)

    def report_send_failure(self, now: float | None = None) -> None:
        """Another of this unit's frames (its distances) could not be sent."""
        with self._lock:
            now = self.clock() if now is None else now
            self._bus_refused(now)
            self._check_refusals(now)
        self._notify()

    def report_send_ok(self) -> None:
        """Another of this unit's frames (its distances) was taken by the bus."""
        self._refused_since_s = None

    def _bus_refused(self, now: float) -> None:
        """Start the refusal clock (kept while nothing is taken) and send our claim again
        soon: a momentary full queue takes the retry."""
        if self._refused_since_s is None:
            self._refused_since_s = now
        self._announce_due = True

    def _check_refusals(self, now: float) -> None:
        """Laser off and claim again when the bus refused our frames for REFUSED_GRACE_S
        with none taken (bus-off, a stuck queue, a dead link): a unit whose frames go
        nowhere protects nobody, and nobody may hear its claim. OWNED again only after
        the bus took the new claim and the window passed."""
        since = self._refused_since_s
        if since is None or now - since < REFUSED_GRACE_S:
            return
        if self._state is not NegotiationState.OWNED and self._claim_sent_s is None:
            return
        if self._state is NegotiationState.OWNED:
            logger.warning("row %s: the bus takes none of our frames since %.2f s: laser "
                           "off, claiming again", self._code_row, now - since)
        self._claim_sent_s = None
        if self._state in (NegotiationState.CLAIMING, NegotiationState.OWNED):
            self._set_state(NegotiationState.CLAIMING, self._code_row, now)

    # ------------------------------------------------------------------ codes
    def _live_named(self) -> list[Peer]:
        return self.peers.named()

    def _same_plan(self, peer: Peer) -> bool:
        return choice.same_plan(peer, self._plan)

    def _holds(self, row: int) -> bool:
        claiming = self._state in (NegotiationState.CLAIMING, NegotiationState.OWNED)
        return claiming and self._code_row == row

    def _taken_by(self) -> dict[int, int]:
        """Rows of our plan claimed by other units -> the lowest NAME claiming each."""
        return choice.taken_by(self._live_named(), self._plan)

    def _free_rows(self, now: float) -> list[int]:
        return choice.free_rows(self._taken_by(), self._plan, self.interference, now)

    def _choose_code(self, now: float, prefer: int | None = None) -> None:
        """Claim a free row (``prefer`` first), else the row of the highest higher NAME."""
        free = self._free_rows(now)
        row = prefer if prefer in free else (free[0] if free else self._preemptable(now))
        if row is None:
            if self._state is not NegotiationState.NO_CODE:
                logger.warning("no free code in N=%d %s (%d codes): cannot-claim, laser off",
                               self._plan.code_length, self._plan.mode, capacity(self._plan))
                self.link.outbox.append(nf.encode_cannot_claim(self.name, self.unit_id))
            self._set_state(NegotiationState.NO_CODE, None, now)
            return
        self._claim_sent_s = None  # the window starts when the claim went out
        self._set_state(NegotiationState.CLAIMING, row, now)
        self.link.outbox.append(nf.encode_claim(self.name, self.unit_id, row))
        logger.debug("claiming row %d of N=%d", row, self._plan.code_length)

    def _preemptable(self, now: float) -> int | None:
        """The row held by the highest NAME above ours (lowest NAME wins), or None."""
        return choice.preemptable(self._taken_by(), self.name, self._plan, self.interference,
                                  now)

    def _lose(self, now: float, reason: str) -> None:
        """Stop strobing at once and look for another code."""
        logger.warning("lost row %s: %s", self._code_row, reason)
        self._set_state(NegotiationState.CLAIMING, None, now)
        self._choose_code(now)

    # ------------------------------------------------------------------ plan
    def _leader_peer(self) -> Peer | None:
        return choice.leader_peer(self._live_named(), self._plan, self.name)

    def _agree_plan(self, now: float) -> None:
        winner = choice.plan_leader(self._live_named(), self.name)
        if winner is not None:
            self._adopt_or_conflict(winner, now)
        elif self._plan_conflict:
            self._adopt_or_conflict(self._plan, now)

    def adoptable(self, plan: Plan) -> bool:
        """True when this unit can run ``plan`` (N, sync capability, the caller's check)."""
        if plan.code_length > self.max_code_length:
            return False
        if plan.mode == "sync" and not self.can_sync:
            return False
        return self._can_adopt is None or bool(self._can_adopt(plan))

    def _adopt_or_conflict(self, plan: Plan, now: float) -> None:
        if not self.adoptable(plan):
            if not self._plan_conflict:
                logger.error("plan N=%d %.3f Hz %s of a lower NAME cannot be adopted: "
                             "plan conflict, laser off", plan.code_length, plan.chip_rate_hz,
                             plan.mode)
            self._plan_conflict, self.conflict_reason = True, "plan"
            self._set_state(NegotiationState.CONFLICT, None, now)
            self._announce_due = True
            return
        leaving_conflict = self._plan_conflict
        self._plan_conflict = False
        if leaving_conflict:
            self.conflict_reason = None
            self._set_state(NegotiationState.CLAIMING, None, now)
        self._adopt(plan, now)

    def _adopt(self, plan: Plan, now: float) -> None:
        """Switch to ``plan``: laser off, re-claim (the same row when it is still in the set)."""
        if plan == self._plan:
            return
        logger.info("plan N=%d %.3f Hz %s -> N=%d %.3f Hz %s", self._plan.code_length,
                    self._plan.chip_rate_hz, self._plan.mode, plan.code_length,
                    plan.chip_rate_hz, plan.mode)
        previous_row = self._code_row
        self._plan = plan
        self.sync.reset()
        self._plan_changed(now)
        self.link.outbox.append(self._plan_frame())
        if self.conflict_reason is not None:  # a duplicate: stay dark, keep the plan
            self._set_state(NegotiationState.CONFLICT, None, now)
            return
        self._set_state(NegotiationState.CLAIMING, None, now)
        if not self._listening:
            self._choose_code(now, prefer=previous_row)

    def _plan_changed(self, now: float) -> None:
        self.plan_history.append((now, self._plan))

    def demand(self) -> int:
        """Units that want a code: this one and every live peer whose NAME is known (it
        sent a REQUEST, CLAIM or CANNOT_CLAIM) and that is not in plan conflict. An
        identity heard only in SYNC or PLAN frames is no unit that wants a code."""
        return 1 + sum(1 for p in self.peers.named() if not p.conflict)

    def _maybe_grow(self, now: float) -> None:
        """The leader fits N to the units: it grows when they exceed the codes, and goes
        back towards the plan it grew from when they are gone (never below that plan)."""
        if not self.is_leader or self._state is NegotiationState.CONFLICT:
            return
        units = self.demand()
        if units > capacity(self._plan) and self._plan.code_length < self.max_code_length:
            fitted = grow_to_fit(self._plan, units, self.max_code_length)
        elif self._growth is not None and self._plan == self._growth[1]:
            fitted = grow_to_fit(self._growth[0], units, self.max_code_length)
        else:
            return
        if fitted == self._plan:
            return
        logger.warning("%d units, %d codes: N %d -> %d, output rate %.2f -> %.2f Hz",
                       units, capacity(self._plan), self._plan.code_length, fitted.code_length,
                       self._plan.output_rate_hz, fitted.output_rate_hz)
        self.plan_growths.append((self._plan, fitted))
        base = self._plan if self._growth is None else self._growth[0]
        self._growth = None if fitted == base else (base, fitted)
        self._adopt(fitted, now)

    def request_plan(self, code_length: int) -> None:
        """Ask the bus for code length ``code_length`` (same chip rate and mode).

        The lowest NAME decides: it adopts the request when this many codes fit the units on
        the bus and every unit can run it; everyone then re-claims under the new plan.

        Raises:
            CodeError: ``code_length`` is not a power of two in 2..128.
        """
        with self._lock:
            wanted = replace(self._plan, code_length=code_length)
            if self.is_leader:
                self._on_proposal(None, wanted, self.clock())
            else:
                self.link.outbox.append(self._plan_frame(wanted, proposal=True))
                self._flush(self.clock())
        self._notify()

    def _on_proposal(self, peer: Peer | None, plan: Plan, now: float) -> None:
        if not self.is_leader or self._listening:
            return
        fits = capacity(plan) >= self.demand() and self.adoptable(plan)
        same_rate = (plan.chip_rate_hz, plan.mode) == (self._plan.chip_rate_hz, self._plan.mode)
        source = peer.label() if peer is not None else "this unit"
        if not (fits and same_rate):
            logger.warning("plan request N=%d from %s refused: %d units, %d codes",
                           plan.code_length, source, self.demand(), capacity(plan))
            return
        logger.info("plan request N=%d from %s accepted", plan.code_length, source)
        self._adopt(plan, now)
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
            if self._plan.mode != "sync" or self._state is NegotiationState.IDLE:
                return None
            if self._leader_peer() is None:
                self._send_sync(now)
                return None
            error = self.sync.measure(now, self._plan.chip_rate_hz, self._plan.code_length)
            self._update_leak()
            self._refresh(now)
        self._notify()
        return error

    def _send_sync(self, now: float) -> None:
        self._sync_counter = (self._sync_counter + 1) & 0xFFFF
        self.link.outbox.append(nf.encode_sync(self.name, self.unit_id, self._sync_counter,
                                           self._plan))
        self._flush(now)

    def _update_leak(self) -> None:
        error = self.sync.error_chips
        if error is None or self._code_row is None:
            self.sync_leak = None
            return
        others = [r for r in self._taken_by() if r != self._code_row]
        self.sync_leak = worst_leak(self._code_row, others, self._plan.code_length, error)

    def _aligned(self, now: float) -> bool:
        if self._plan.mode != "sync" or self._leader_peer() is None:
            return True
        max_age = max(3.0 * self._plan.cycle_s, self.window_s)
        error = self.sync.error_chips
        return (self.sync.fresh(now, max_age) and error is not None
                and abs(error) <= self.max_misalignment_chips)

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
                self._hop(now)
                self._flush(now)
        self._notify()

    def _hop(self, now: float) -> None:
        row = self._code_row
        assert row is not None
        others = [r for r in self._free_rows(now) if r != row]
        if not others:
            logger.warning("row %d is jammed and no other code is free: staying", row)
            return
        self.interference.mark_jammed(row, now)
        logger.warning("row %d jammed by a unit not on this bus: hopping (hop %d)", row,
                       self.interference.hop_count)
        self._set_state(NegotiationState.CLAIMING, None, now)
        self._choose_code(now)

    # ------------------------------------------------------------------ bookkeeping
    def _set_state(self, state: NegotiationState, row: int | None, now: float) -> None:
        self._state, self._code_row = state, row
        self._refresh(now)

    def _refresh(self, now: float) -> None:
        """Recompute may_strobe and extend the strobe timeline when it or the row changed."""
        owned = self._state is NegotiationState.OWNED and self._code_row is not None
        self._may_strobe = owned and self._aligned(now)
        entry = (now, self._may_strobe, self._code_row)
        if not self.timeline or self.timeline[-1][1:] != entry[1:]:
            self.timeline.append(entry)

    def _notify(self) -> None:
        current = (self._state, self._code_row, self._plan)
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
