"""What a unit's status frame says: its state and fault bits, from its parts.

A unit is RUNNING only while its negotiator lets it strobe and nothing is broken; FAULT
when the camera or the projector failed or its loop died; NO_CODE when every code is
taken or the plan cannot be run; NEGOTIATING otherwise.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from atris_node.node.measure import Measurer
from atris_node.node.stats import NodeStats
from atris_node.types import FaultBits, UnitState, UnitStatus

#: faults that make the unit unable to measure at all
BROKEN = FaultBits.CAMERA_LOST | FaultBits.LASER_FAULT


def unit_state(faults: FaultBits, loop_failed: bool, negotiator: Any) -> UnitState:
    """The unit's state from its own fault bits, its loop and its negotiation."""
    if faults & BROKEN or loop_failed:
        return UnitState.FAULT
    if negotiator.may_strobe:
        return UnitState.RUNNING
    name = getattr(negotiator.state, "name", str(negotiator.state))
    return UnitState.NO_CODE if name in ("NO_CODE", "CONFLICT") else UnitState.NEGOTIATING


def negotiated_status(status: UnitStatus, negotiator: Any) -> UnitStatus:
    """``status`` as it may go out now, whatever the loop handed over last (it may be
    blocked in a camera read while the code is lost): RUNNING only while the negotiator
    still lets the unit strobe the code (N, row) the status names. Otherwise the state the
    negotiation gives now (NEGOTIATING, or NO_CODE) and no row, so the distances go out
    invalid; a code owned anew is NEGOTIATING until the loop measures on it."""
    if status.state is not UnitState.RUNNING or owns_code_of(status, negotiator):
        return status
    state = unit_state(FaultBits.NONE, False, negotiator)
    if state is UnitState.RUNNING:  # another code than the one measured on
        state = UnitState.NEGOTIATING
    return replace(status, state=state, code_row=0)


def owns_code_of(status: UnitStatus, negotiator: Any) -> bool:
    """True while the negotiator lets the unit strobe the code ``status`` names."""
    return (bool(negotiator.may_strobe) and int(negotiator.code_row or 0) == status.code_row
            and int(negotiator.plan.code_length) == status.code_length)


def measure_faults(work: Measurer | None, measuring: bool) -> FaultBits:
    """CALIBRATION while the sub-frames do not fit the calibration, the adaptation's
    LOW_SIGNAL, and the pipeline's verdict on the newest map while the unit measures."""
    if work is None:
        return FaultBits.NONE
    bits = FaultBits.NONE if work.fits_calibration else FaultBits.CALIBRATION
    if work.low_signal:
        bits |= FaultBits.LOW_SIGNAL
    if measuring:
        bits |= work.map_faults
    return bits


def compose_status(state: UnitState, faults: FaultBits, negotiator: Any,
                   work: Measurer | None, chip_rate_hz: float, counter: int,
                   stats: NodeStats) -> UnitStatus:
    """The content of the status frame: ``faults`` are the unit's own bits; the
    negotiation's and the measurement's are added here."""
    dmap = None if work is None else work.last_map
    extra = dmap.extra if dmap is not None else {}
    return UnitStatus(
        state=state,
        code_row=int(negotiator.code_row or 0) if negotiator.may_strobe else 0,
        code_length=int(negotiator.plan.code_length),
        chip_rate_hz=chip_rate_hz,
        measurement_counter=counter,
        faults=faults | negotiator.faults | measure_faults(work, negotiator.may_strobe),
        ambient_level=float(extra.get("ambient_level", 0.0)),
        saturated_fraction=float(extra.get("saturated_fraction", 0.0)),
        foreign_code_energy=0.0 if work is None else work.foreign_energy(extra),
        dropped_sub_frames=stats.dropped_sub_frames,
    )
