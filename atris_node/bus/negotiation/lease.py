"""Whether the bus takes this unit's frames: the transmit half of the strobe lease.

A claim protects nobody that nobody heard, so the contest window runs from the moment the
bus TOOK our CLAIM of the row, not from when it was queued. A unit whose frames the bus
refuses (bus-off, a stuck queue, a dead link) for :data:`REFUSED_GRACE_S` with none taken
loses its permission to strobe. All times are seconds on the negotiator's clock.

Example::

    lease = TransmitLease()
    lease.refused(now=1.0)
    assert not lease.lapsed(1.05) and lease.lapsed(1.1)
    lease.taken()
    assert not lease.lapsed(2.0)
"""

from __future__ import annotations

#: how long the bus may refuse our frames with none taken before the laser goes off, s
#: (a momentary full queue is retried after the announce gap; bus-off is not)
REFUSED_GRACE_S = 0.1


class TransmitLease:
    """When the bus took our claim of the row, and since when it refuses our frames."""

    def __init__(self) -> None:
        self.claim_sent_s: float | None = None  # the bus took our CLAIM of the row at
        self.refused_since_s: float | None = None  # the bus refuses our frames since
        self.reset()

    def reset(self) -> None:
        """Forget both clocks (a start)."""
        self.claim_sent_s = None
        self.refused_since_s = None

    def flushed(self, taken: int, refused: int, claim_taken: bool, now: float) -> None:
        """Record one flush: ``taken`` / ``refused`` frames, ``claim_taken`` when our CLAIM
        of the row was among the taken ones."""
        if refused:
            self.refused(now)
        elif taken:
            self.taken()
        if self.claim_sent_s is None and claim_taken:
            self.claim_sent_s = now

    def refused(self, now: float) -> None:
        """The bus refused one of our frames: start the refusal clock (kept while nothing
        is taken)."""
        if self.refused_since_s is None:
            self.refused_since_s = now

    def taken(self) -> None:
        """The bus took one of our frames: the refusal clock stops."""
        self.refused_since_s = None

    def claim_again(self) -> None:
        """A new claim goes out: its window starts when the bus takes it."""
        self.claim_sent_s = None

    def lapsed(self, now: float) -> bool:
        """True when the bus refused our frames for REFUSED_GRACE_S with none taken."""
        since = self.refused_since_s
        return since is not None and now - since >= REFUSED_GRACE_S

    def window_passed(self, now: float, window_s: float) -> bool:
        """True when the bus took our claim ``window_s`` ago and takes our frames now."""
        sent_s = self.claim_sent_s
        return sent_s is not None and now - sent_s >= window_s and self.refused_since_s is None
