"""The negotiation safety invariant while claims are lost on the bus.

Every unit of a fake-clock :class:`Fleet` reads and writes through its own
:class:`FaultyBus`, which drops frames it sends (``drop_tx``), frames it receives
(``drop_rx``) or every frame with given identifiers (``drop_ids``). Loss cannot be told
from silence, so the protocol cannot promise that no two units ever strobe one row; what
it does promise, and what is checked on every unit's strobe timeline:

1. Window: a unit strobes a row only after it sent a CLAIM of that row at least
   ``window_s`` earlier and held the row since (a local rule; loss cannot break it).
2. Yield: once a CLAIM of its row from a lower NAME under the same plan has reached a
   unit, it does not strobe that row again until it re-claims it (same instant).
3. Bounded sharing: two units strobe the same row only until the first CLAIM of the
   lower NAME reaches the higher one, plus one tick. Without loss that is never
   (claims cross inside the window); with a frame loss rate p a sharing outlives k
   re-announce periods (``reannounce_s``) with probability about p**k.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest

from atris_node.bus.negotiation.fleet import (
    Fleet,
    ShimBus,
    overlaps,
    plan_at,
    strobe_intervals,
    window_violations,
)
from atris_node.bus.negotiation.frames import (
    FrameKind,
    Identity,
    PlanAnnouncement,
    decode_name,
    encode_claim,
    encode_plan,
    encode_request,
    encode_sync,
    make_id,
    parse_id,
)
from atris_node.bus.negotiation.lease import REFUSED_GRACE_S
from atris_node.bus.negotiation.machine import Negotiator
from atris_node.bus.negotiation.peers import PeerTable
from atris_node.bus.negotiation.plan import Plan
from atris_node.testing.faultbus import Faults, FaultyBus

PLAN = Plan(code_length=16, chip_rate_hz=480.0)
WINDOW_S = 0.25
TICK_S = 0.005
NAMES = [0x7A, 0x13, 0x5C, 0x21, 0x9E]
_channels = itertools.count()


class TappedBus(FaultyBus):
    """A FaultyBus that records, on the fleet clock, what its unit sent (the bus took it;
    a loss fault may then drop it on the way), the times the bus refused a frame (a send
    that raised: not sent), and what was delivered to it."""

    def __init__(self, inner: ShimBus, faults: Faults, seed: int) -> None:
        super().__init__(inner, faults, seed=seed)
        self.clock = inner.clock
        self.sent: list[tuple[float, can.Message]] = []
        self.refused: list[float] = []
        self.received: list[tuple[float, can.Message]] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            super().send(msg, timeout)
        except can.CanError:
            self.refused.append(self.clock())
            raise
        self.sent.append((self.clock(), msg))

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg, filtered = super()._recv_internal(timeout)
        if msg is not None:
            self.received.append((self.clock(), msg))
        return msg, filtered


class LossyFleet(Fleet):
    """A Fleet whose units talk through :class:`TappedBus` with per-unit faults."""

    faults: list[Faults]

    def add(self, name: int, plan: Plan, unit_id: int) -> int:
        index = super().add(name, plan, unit_id)
        unit = self.units[index]
        faults = Faults()
        tapped = TappedBus(self.buses[index], faults, seed=100 + index)
        unit.bus = tapped
        self.buses[index] = tapped  # type: ignore[call-overload]
        self.faults = [*getattr(self, "faults", []), faults]
        return index


MakeFleet = Callable[..., "LossyFleet"]


@pytest.fixture
def lossy_fleet() -> Iterator[MakeFleet]:
    fleets: list[LossyFleet] = []

    def make(names: list[int], **kwargs: Any) -> LossyFleet:
        fleet = LossyFleet(f"reliability-negotiation-{next(_channels)}", PLAN, names,
                           tick_s=TICK_S, **kwargs)
        fleets.append(fleet)
        return fleet

    yield make
    for fleet in fleets:
        fleet.close()


def delivered_lower_claims(fleet: LossyFleet, index: int) -> list[tuple[float, int]]:
    """(time, row) of CLAIMs from a lower NAME under the same plan delivered to ``index``."""
    unit, found = fleet.units[index], []
    for t, msg in fleet.buses[index].received:
        header = parse_id(msg.arbitration_id)
        if header is None or header.kind is not FrameKind.CLAIM or len(msg.data) != 8:
            continue
        if not any(u.identity == header.identity for u in fleet.units):
            continue  # a forged identity, no unit of the fleet
        sender = fleet.units[header.identity.unit_id]
        if decode_name(bytes(msg.data)) < unit.name and plan_at(sender, t) == plan_at(unit, t):
            found.append((t, header.field))
    return found


def yield_violations(fleet: LossyFleet, end_s: float) -> list[tuple[int, float, int]]:
    """Rule 2: strobing a row after a lower NAME's claim of it arrived, before re-claiming."""
    bad = []
    for index, unit in enumerate(fleet.units):
        spans = strobe_intervals(unit, end_s)
        for t, row in delivered_lower_claims(fleet, index):
            if any(s0 <= t < s1 - TICK_S - 1e-9 and r == row for s0, s1, r in spans):
                bad.append((index, t, row))
    return bad


def sharing_violations(fleet: LossyFleet, end_s: float) -> list[tuple[int, int, float, float]]:
    """Rule 3: a shared row that outlived the first delivered claim of the lower NAME."""
    bad = []
    for i, j, start, end, row in overlaps(fleet, end_s):
        low, high = sorted((i, j), key=lambda k: fleet.units[k].name)
        heard = [t for t, r in delivered_lower_claims(fleet, high)
                 if r == row and t >= start and fleet.units[low].name < fleet.units[high].name]
        limit = (min(heard) + TICK_S) if heard else end_s
        if end > limit + 1e-9:
            bad.append((low, high, start, end))
    return bad


def assert_invariant(fleet: LossyFleet, end_s: float) -> None:
    assert window_violations(fleet, end_s, WINDOW_S) == []
    assert yield_violations(fleet, end_s) == []
    assert sharing_violations(fleet, end_s) == []


def owners(fleet: Fleet) -> list[int | None]:
    return [u.code_row if u.may_strobe else None for u in fleet.units]


@pytest.mark.parametrize(("drop_tx", "drop_rx"), [(0.0, 0.3), (0.2, 0.0), (0.2, 0.3)])
def test_invariant_holds_while_a_share_of_all_frames_is_lost(
        lossy_fleet: MakeFleet, drop_tx: float, drop_rx: float) -> None:
    fleet = lossy_fleet(NAMES, max_code_length=16)  # five units, four codes: one waits
    for faults in fleet.faults:
        faults.drop_tx, faults.drop_rx = drop_tx, drop_rx
    fleet.start_all(spread_s=0.01)
    fleet.run_until(20.0)
    assert_invariant(fleet, 20.0)
    lost = sum(b.counts.dropped_tx + b.counts.dropped_rx for b in fleet.buses)  # type: ignore[attr-defined]
    assert lost > 30, "the faults did not bite"
    shared = [end - start for *_, start, end, _ in overlaps(fleet, 20.0)]
    print(f"drop_tx={drop_tx} drop_rx={drop_rx}: {lost} frames lost, {len(shared)} shared "
          f"row intervals, longest {max(shared, default=0.0):.3f} s")
    for faults in fleet.faults:  # the loss ends: everything converges within a few periods
        faults.drop_tx = faults.drop_rx = 0.0
    fleet.run_until(26.0)
    rows = [r for r in owners(fleet) if r is not None]
    assert len(rows) == 4 and len(set(rows)) == 4
    assert [o for o in overlaps(fleet, 26.0) if o[3] > 24.0] == []
    assert_invariant(fleet, 26.0)


def test_claims_of_a_joining_unit_lost_for_two_seconds_share_a_row_only_until_one_arrives(
        lossy_fleet: MakeFleet) -> None:
    fleet = lossy_fleet(NAMES, max_code_length=16)  # five units, four codes
    joiner = min(range(5), key=lambda i: fleet.units[i].name)
    highest = max(range(5), key=lambda i: fleet.units[i].name)
    for index in range(5):
        if index != joiner:
            fleet.start(index, 0.0)
    fleet.run_until(1.0)
    identity = fleet.units[joiner].identity
    fleet.faults[joiner].drop_ids = {make_id(FrameKind.CLAIM, identity, r) for r in range(128)}
    fleet.start(joiner, 1.0)  # no free row: it takes the highest NAME's, which never hears
    fleet.run_until(3.0)
    shared = overlaps(fleet, 3.0)
    assert {(o[0], o[1]) for o in shared} == {tuple(sorted((joiner, highest)))}
    assert fleet.faults[joiner] and fleet.buses[joiner].counts.dropped_tx >= 2  # type: ignore[attr-defined]
    fleet.faults[joiner].drop_ids = set()
    fleet.run_until(6.0)
    assert_invariant(fleet, 6.0)
    assert max(o[3] for o in overlaps(fleet, 6.0)) <= 3.0 + 1.0 + TICK_S + 1e-9, (
        "sharing outlived the first re-announcement after the loss ended")
    assert fleet.units[highest].code_row is None or not fleet.units[highest].may_strobe
    rows = [r for r in owners(fleet) if r is not None]
    assert len(rows) == 4 and len(set(rows)) == 4


def test_a_unit_whose_frames_the_bus_refuses_does_not_strobe_and_an_owner_goes_dark_at_once(
        lossy_fleet: MakeFleet) -> None:
    """A claim the bus refused protects nobody, and neither does a unit whose frames go
    nowhere. Unit 2 starts on a bus that refuses every frame (bus-off); unit 0, owning its
    row, loses its bus at 2 s; both buses come back at 4 s.

    Unit 0 goes dark REFUSED_GRACE_S after its first refused frame (its retries every
    50 ms are refused too).

    Checked by removing the protections: with ``Negotiator._check_refusals`` doing
    nothing, unit 0 strobed through the whole outage (to 4.0 s; the assert on
    ``last_lit`` failed); with that, the refusal clock not blocking ownership and the
    claim window counted from when the claim was queued instead of when the bus took
    it, unit 2 also owned row 5, never claimed on the bus, from 0.36 s on (the first
    assert failed).
    """
    fleet = lossy_fleet(NAMES[:3], max_code_length=16)
    fleet.faults[2].bus_off = True
    fleet.start_all(spread_s=0.01)
    fleet.run_until(2.0)
    assert strobe_intervals(fleet.units[2], 2.0) == []
    assert fleet.units[0].may_strobe and fleet.units[1].may_strobe
    fleet.faults[0].bus_off = True
    fleet.run_until(4.0)
    refused = [t for t in fleet.buses[0].refused if t >= 2.0]  # type: ignore[attr-defined]
    assert refused, "unit 0 sent nothing during the outage: the test proves nothing"
    last_lit = max(end for _, end, _ in strobe_intervals(fleet.units[0], 4.0))
    assert last_lit <= refused[0] + REFUSED_GRACE_S + TICK_S + 1e-9
    assert strobe_intervals(fleet.units[2], 4.0) == []
    fleet.faults[0].bus_off = fleet.faults[2].bus_off = False
    fleet.run_until(7.0)
    rows = [r for r in owners(fleet) if r is not None]
    assert len(rows) == 3 and len(set(rows)) == 3
    assert overlaps(fleet, 7.0) == []
    assert_invariant(fleet, 7.0)
    print(f"\nowner's first refused frame at {refused[0]:.3f} s, dark at {last_lit:.3f} s")


def test_garbage_sync_and_plan_frames_do_not_change_n_and_growth_goes_back(
        lossy_fleet: MakeFleet) -> None:
    """Frames from identities that never said a NAME (SYNC, PLAN, PLAN proposals for
    N = 128) leave the fleet on N = 16. Units that do say their NAME count: one more
    makes the leader grow N to 32 (five units, four codes at 16, five at 32); once it is
    silent for the silence timeout the fleet goes back to 16 and every unit owns a
    distinct row.

    Checked by counting every peer as demand again (``PlanAgreement.demand`` over all peers,
    as before): N went 16 -> 128 on the garbage and the first assert failed; by letting
    unnamed identities propose (the inbox's NAME check removed): N went to 128 on the
    proposals; and without the way back (``_maybe_grow`` growing only): N stayed 32 and
    the last plan assert failed.
    """
    fleet = lossy_fleet(NAMES[:4], max_code_length=128)
    fleet.start_all(spread_s=0.01)
    fleet.run_until(1.0)
    forger = ShimBus(fleet.channel, fleet.clock)
    try:
        run_garbage_then_a_joiner(fleet, forger)
    finally:
        forger.shutdown()
    assert {u.plan.code_length for u in fleet.units} == {16}
    rows = [r for r in owners(fleet) if r is not None]
    assert len(rows) == 4 and len(set(rows)) == 4
    assert_invariant(fleet, 12.0)


def run_garbage_then_a_joiner(fleet: LossyFleet, forger: ShimBus) -> None:
    huge = Plan(code_length=128, chip_rate_hz=480.0)

    def garbage(k: int) -> None:
        unit_id = 8 + k % 8
        name = 0x1000 + k
        for frame in (encode_sync(name, unit_id, k, PLAN),
                      encode_plan(name, unit_id, PlanAnnouncement(huge, True, False, k % 250 + 1,
                                                                  False)),
                      encode_plan(name, unit_id, PlanAnnouncement(huge, False, False,
                                                                  k % 250 + 1, True))):
            forger.send(can.Message(arbitration_id=frame.can_id, data=frame.data,
                                    is_extended_id=True))

    for k in range(40):
        fleet.at(1.0 + 0.02 * k, lambda k=k: garbage(k))
    fleet.run_until(3.0)
    assert {u.plan.code_length for u in fleet.units} == {16}

    def joiner() -> None:
        frame = encode_request(0x2000, 12)
        forger.send(can.Message(arbitration_id=frame.can_id, data=frame.data,
                                is_extended_id=True))

    for k in range(10):
        fleet.at(3.0 + 0.2 * k, joiner)
    fleet.run_until(5.0)
    assert {u.plan.code_length for u in fleet.units} == {32}
    fleet.run_until(12.0)  # the joiner fell silent at 4.8 s; gone after 3 s


def test_seventy_forged_identities_neither_overflow_the_peer_table_nor_hide_an_owner(
        lossy_fleet: MakeFleet) -> None:
    """Seventy identities that are no unit (forged NAMEs above the real ones, each
    claiming one of the rows 3, 5, 9 every 0.5 s, well under the babbling limits) keep
    the 64-entry peer tables full. The owner (row 2) and a unit that starts at 2 s into
    a full table must still contest row 2: the newcomer must not strobe it.

    Checked without the protection (``PeerTable.accept`` dropping every new identity when
    the table is full, as before, and no contest for a claim the full table cannot
    hold): both units strobed row 2 from 2.36 s to the end, and the overlap assert failed.
    """
    fleet = lossy_fleet([0x50, 0x60], max_code_length=16)
    forger = ShimBus(fleet.channel, fleet.clock)
    try:
        forged = [(0x9000 + 7 * k, 8 + k % 8) for k in range(70)]

        def claims() -> None:  # every forged identity at once, every 0.5 s
            for k, (name, unit_id) in enumerate(forged):
                frame = encode_claim(name, unit_id, (3, 5, 9)[k % 3])
                forger.send(can.Message(arbitration_id=frame.can_id, data=frame.data,
                                        is_extended_id=True))

        for step in range(16):
            fleet.at(0.5 * step + 0.499, claims)  # just before the newcomer's start at 2.0
        def fresh_start() -> None:  # a unit that starts hears nothing sent before
            while fleet.buses[1].recv(0.0) is not None:
                pass

        fleet.at(1.998, fresh_start)
        fleet.start(0, 0.05)
        fleet.run_until(2.0)
        fleet.start(1, 2.0)
        fleet.run_until(8.0)
    finally:
        forger.shutdown()
    real = [(i, j, s, e, r) for i, j, s, e, r in overlaps(fleet, 8.0)]
    assert real == []
    assert all(len(u.peers.peers) <= u.peers.max_peers for u in fleet.units)
    assert fleet.units[0].may_strobe
    assert_invariant(fleet, 8.0)


def test_a_claim_a_full_table_of_owners_cannot_hold_still_contests_the_row(
        lossy_fleet: MakeFleet) -> None:
    """Every entry of a (two-entry) peer table owns a row: identities that are no unit
    claim rows 3 and 5. The real units cannot store each other, yet the newcomer's claim
    of the owner's row 2 is contested and it never strobes row 2.

    Checked by making ``Inbox._unheld_claim`` return None (the frame simply dropped, as
    before): the newcomer strobed row 2 beside the owner from 2.36 s on and the overlap
    assert failed; and by dropping a defence that comes within 50 ms of the last one
    instead of sending it with the next announcement (as before): overlap from 2.42 s.
    (Neither unit can store the other here, so the newcomer keeps re-claiming row 2 and
    losing it: no code for it, no sharing.)
    """
    fleet = lossy_fleet([0x50, 0x60], max_code_length=16)
    for unit in fleet.units:
        unit.peers.max_peers = 2
    forger = ShimBus(fleet.channel, fleet.clock)
    try:
        def claims() -> None:
            for name, unit_id, row in ((0x9000, 9, 3), (0x9100, 10, 5)):
                frame = encode_claim(name, unit_id, row)
                forger.send(can.Message(arbitration_id=frame.can_id, data=frame.data,
                                        is_extended_id=True))

        for step in range(16):
            fleet.at(0.5 * step + 0.001, claims)
        fleet.start(0, 0.05)
        fleet.run_until(2.0)
        fleet.start(1, 2.0)
        fleet.run_until(8.0)
    finally:
        forger.shutdown()
    assert fleet.units[0].code_row == 2 and fleet.units[0].may_strobe
    assert all(len(u.peers.peers) <= 2 for u in fleet.units)
    assert overlaps(fleet, 8.0) == []
    assert_invariant(fleet, 8.0)


def test_a_full_peer_table_evicts_what_matters_least_and_never_a_rows_owner() -> None:
    """Checked by making ``PeerTable._make_room`` evict nothing: the new identities were
    dropped (``accept`` returned None) and the assert in the loop failed."""
    table = PeerTable(max_peers=4)
    ids = [Identity(k) for k in range(8)]

    def heard(k: int, now: float, name: int | None = None, row: int | None = None) -> None:
        peer = table.accept(ids[k], now)
        assert peer is not None
        peer.name, peer.code_row, peer.plan = name, row, PLAN

    heard(0, 0.0, 0x10, 2)  # owner of row 2
    heard(1, 0.1, 0x20, 2)  # shadowed on row 2
    heard(2, 0.2, 0x30)  # named, no row
    heard(3, 0.3)  # NAME unknown
    order = []
    for k in (4, 5, 6):
        before = set(table.peers)
        assert table.accept(ids[k], 1.0 + k) is not None
        order += [bits for bits in before if bits not in table.peers]
        table.peers[ids[k].bits].name, table.peers[ids[k].bits].code_row = 0x40 + k, 3 + k
        table.peers[ids[k].bits].plan = PLAN
    assert order == [ids[3].bits, ids[2].bits, ids[1].bits]
    assert table.accept(ids[7], 9.0) is None and table.overflowed  # four owners: full
    assert ids[0].bits in table.peers and table.evicted == 3


@pytest.mark.parametrize("babble", ["sync_flood", "claim_changes"])
def test_a_quarantined_identity_still_takes_our_row_by_the_name_rule(babble: str) -> None:
    """Frames forged under another unit's identity make it a babbler (a SYNC flood of
    300 frames/s, or 25 claim changes/s of rows outside the plan); the unit quarantines
    that identity. Then the real unit behind it, a lower NAME, claims our row: we yield
    at once and do not take the row back. Checked to fail with ``Inbox._dropped_claim``
    returning None and ``Inbox._claim`` dropping a claim ``allow_change`` refuses (as
    before): the unit kept strobing the row the lower NAME claimed."""
    bus = can.Bus(interface="virtual", channel=f"quarantine-{babble}-{next(_channels)}")
    now = [0.0]
    plan = Plan(code_length=4, chip_rate_hz=60.0)
    unit = Negotiator(bus, name=0x500, plan=plan, unit_id=0, clock=lambda: now[0],
                      poll_bus=True, max_code_length=4)
    lower_name, lower_id = 0x100, 1

    def babble_frame(k: int) -> Any:
        if babble == "sync_flood":
            return encode_sync(lower_name, lower_id, k, plan)
        return encode_claim(lower_name, lower_id, 100 + k // 12 % 2) if k % 12 == 0 else None

    def advance(seconds: float, frame_of: Callable[[int], Any] = lambda k: None) -> None:
        for k in range(round(seconds * 300)):
            now[0] += 1 / 300
            frame = frame_of(k)
            if frame is not None:
                unit.on_frame(frame.can_id, frame.data, now[0])
            unit.tick()

    unit.start()
    try:
        advance(1.0)
        row = unit.code_row
        assert unit.may_strobe and row is not None
        advance(1.0, babble_frame)
        assert unit.peers.babblers >= 1 and unit.may_strobe and unit.code_row == row
        claim = encode_claim(lower_name, lower_id, row)
        unit.on_frame(claim.can_id, claim.data, now[0])
        assert not unit.may_strobe and unit.code_row != row
        advance(1.0)
        assert unit.code_row != row
    finally:
        unit.stop()
        bus.shutdown()
