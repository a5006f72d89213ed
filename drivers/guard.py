"""A projector that darkens itself: lit only while strobes keep coming and are permitted.

The loop strobes once per sub-frame, just before it reads that sub-frame. When the loop
stops strobing (a camera read that hangs, a loop stuck anywhere) the laser must not stay
lit on the last command. :class:`GuardedProjector` wraps any projector:

- every strobe renews a lease of ``lease_s`` (one sub-frame period plus a margin); a
  watch thread switches the emitter off once the lease ran out (a *lapse*, counted in
  ``lapses`` so the loop can restart its window: a sub-frame may have been exposed dark);
- a strobe is taken only while ``permit()`` says so (the negotiator owns the code), and
  ``off()`` may come from any thread at any time (the negotiator losing its code): a
  strobe and an off are serialised, so once ``permit()`` went false and ``off()`` ran, no
  strobe lights the emitter again.

Times are on ``clock`` (the unit's clock): on a simulated clock, which stands still while
nothing is read, a lease does not run out.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from drivers.base import Projector

logger = logging.getLogger(__name__)


class GuardedProjector(Projector):
    """Wrap ``inner``: dark ``lease_s`` after the last strobe, and whenever not permitted.

    Example:
        >>> from drivers.sim import open_backend
        >>> camera, inner = open_backend("indoor_lab")
        >>> t = [0.0]
        >>> guard = GuardedProjector(inner, lease_s=0.01, clock=lambda: t[0])
        >>> guard.strobe(1, 0)
        >>> t[0] = 0.02
        >>> guard.expire(), guard.is_lit, guard.lapses
        (None, False, 1)
        >>> guard.close(); camera.close()
    """

    def __init__(self, inner: Projector, lease_s: float,
                 clock: Callable[[], float] = time.monotonic,
                 permit: Callable[[], bool] | None = None) -> None:
        if lease_s <= 0:
            raise ValueError(f"lease_s must be > 0, got {lease_s}")
        self.inner, self.lease_s, self.clock = inner, lease_s, clock
        self.permit: Callable[[], bool] = permit or (lambda: True)
        #: leases that ran out while lit (the emitter was switched off by the guard)
        self.lapses = 0
        self._lit_until = 0.0
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._watch: threading.Thread | None = None

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)

    def _strobe(self, chip: int, sequence: int) -> None:
        self.inner.strobe(chip, sequence)

    def _off(self) -> None:
        self.inner.off()

    def strobe(self, chip: int, sequence: int) -> None:
        """Set the chip and renew the lease; switched off instead when not permitted."""
        with self._lock:
            if not self.permit():
                self.off()
                return
            was_lit = self._lit
            super().strobe(chip, sequence)
            self._lit_until = self.clock() + self.lease_s
        if not was_lit:
            self._start_watch()
            self._wake.set()

    def off(self) -> None:
        """Switch off now, from any thread."""
        with self._lock:
            super().off()

    def set_intensity(self, fraction: float) -> None:
        self.inner.set_intensity(fraction)

    def expire(self, now: float | None = None) -> float | None:
        """Switch off when the lease ran out; the seconds it still runs, None when dark."""
        with self._lock:
            if not self._lit:
                return None
            left = self._lit_until - (self.clock() if now is None else now)
            if left > 0:
                return left
            self.lapses += 1
            super().off()
        logger.warning("projector dark: no strobe for %.3f s (lease ran out)", self.lease_s)
        return None

    def _start_watch(self) -> None:
        if self._watch is None and not self._closing.is_set():
            self._watch = threading.Thread(target=self._run_watch, name="atris-laser-guard",
                                           daemon=True)
            self._watch.start()

    def _run_watch(self) -> None:
        while not self._closing.is_set():
            try:
                left = self.expire()
            except Exception:  # the emitter's off() failed: keep watching, tell the log
                logger.exception("projector guard could not switch the emitter off")
                left = self.lease_s
            self._wake.wait(None if left is None else max(left, 0.001))
            self._wake.clear()

    def close(self) -> None:
        """Switch off, stop the watch, release the inner projector; idempotent."""
        with self._lock:
            if self._closed:
                return
            super().close()
        self._closing.set()
        self._wake.set()
        if self._watch is not None:
            self._watch.join()
        self.inner.close()
