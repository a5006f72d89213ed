"""Where a unit is in the code negotiation; only OWNED may strobe."""

from __future__ import annotations

import enum


class NegotiationState(enum.Enum):
    """Where a unit is in the negotiation. Only OWNED may strobe."""

    IDLE = 0  # not started, or stopped
    CLAIMING = 1  # listening, or claimed a code whose window has not passed
    OWNED = 2  # the claim stood the window
    NO_CODE = 3  # every code is taken by a lower NAME: cannot-claim sent, laser off
    CONFLICT = 4  # plan it cannot adopt, or duplicate NAME/identity: laser off
