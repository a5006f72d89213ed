"""Who holds which row and whose plan leads: pure decisions over the live peers.

Every function reads the peers' announced NAME, plan and row and returns a decision; none
changes a peer or the negotiator. The lowest NAME wins codes and plan.
"""

from __future__ import annotations

from atris_node.bus.negotiation.hop import InterferenceMonitor
from atris_node.bus.negotiation.peers import Peer
from atris_node.bus.negotiation.plan import Plan, plan_code_rows


def same_plan(peer: Peer, plan: Plan) -> bool:
    """True when ``peer`` runs ``plan`` (or has not said) and is not in plan conflict."""
    return (peer.plan is None or peer.plan == plan) and not peer.conflict


def taken_by(peers: list[Peer], plan: Plan) -> dict[int, int]:
    """Rows of ``plan`` claimed by ``peers`` (named, live) -> the lowest NAME claiming each."""
    taken: dict[int, int] = {}
    for peer in peers:
        if peer.code_row is not None and same_plan(peer, plan):
            assert peer.name is not None
            taken[peer.code_row] = min(taken.get(peer.code_row, peer.name), peer.name)
    return taken


def free_rows(taken: dict[int, int], plan: Plan, interference: InterferenceMonitor,
              now: float) -> list[int]:
    """Rows of ``plan`` nobody claims and nobody jams, in the order of preference."""
    rows = [r for r in plan_code_rows(plan)
            if r not in taken and not interference.is_jammed(r, now)]
    return interference.preference(rows)


def preemptable(taken: dict[int, int], name: int, plan: Plan,
                interference: InterferenceMonitor, now: float) -> int | None:
    """The row held by the highest NAME above ``name`` (lowest NAME wins), or None."""
    higher = {row: held for row, held in taken.items()
              if held > name and not interference.is_jammed(row, now)
              and row in plan_code_rows(plan)}
    return max(higher, key=lambda row: higher[row]) if higher else None


def leader_peer(peers: list[Peer], plan: Plan, name: int) -> Peer | None:
    """The peer with the lowest NAME on ``plan`` when it is below ``name``, else None."""
    named = [p for p in peers if same_plan(p, plan)]
    lowest = min(named, key=lambda p: p.name or 0, default=None)
    return lowest if lowest is not None and (lowest.name or 0) < name else None


def plan_leader(peers: list[Peer], name: int) -> Peer | None:
    """The lowest NAME below ``name`` that announced a plan and is not in conflict (whose
    plan wins), or None."""
    candidates = [p for p in peers
                  if p.plan is not None and not p.conflict and (p.name or 0) < name]
    return min(candidates, key=lambda p: p.name or 0, default=None)


def running_plan(peers: list[Peer]) -> Plan | None:
    """The plan of the lowest NAME among the peers that own a code under it (a running
    fleet a starting unit joins, whatever its own NAME), or None."""
    running = [(p.name or 0, p.plan) for p in peers
               if p.plan is not None and p.established and not p.conflict]
    return min(running, key=lambda item: item[0])[1] if running else None
