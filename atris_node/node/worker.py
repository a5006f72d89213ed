"""The map thread: complete distortion maps are measured beside the camera loop.

The camera loop must read every sub-frame in time: a sub-frame the driver had to drop is a
gap in the sequence, and a gap restarts the demodulation window (N sub-frames of output
lost in sliding mode, the map in progress in block mode). A pipeline pass takes longer
than a sub-frame period, so the loop hands each complete map to this thread and goes back
to the camera. The thread measures one map at a time; a map that arrives while another
is being measured waits in a single slot, and a newer map replaces the waiting one (it
is counted in ``skipped``): the output is the newest map the thread can keep up with,
never a queue of older ones.

Each map carries the loop's *epoch*: the loop starts a new epoch whenever it publishes
invalid distances (no code, camera or projector fault, a rejected sub-frame) or stops.
The measurement of a map from an older epoch is not published (``stale``), so a result
that finishes after the loop went invalid can never make the output valid again. The
numba kernels release the GIL, so on two cores the pipeline's compiled stages run in
parallel with the loop's demodulation.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from atris_node.demod import PendingMap

logger = logging.getLogger(__name__)

#: takes and measures one map of the given epoch (and publishes it if the epoch is
#: still current)
Measure = Callable[[PendingMap, int], None]


class MapThread:
    """One thread that measures the newest complete map.

    Args:
        measure: called on the thread with each map and its epoch.
        on_error: called on the thread with an exception ``measure`` raised; the thread
            ends after it (the unit stores the error, switches the laser off and
            publishes FAULT).
        name: the thread's name.
    """

    def __init__(self, measure: Measure, on_error: Callable[[BaseException], None],
                 name: str) -> None:
        self._measure = measure
        self._on_error = on_error
        self._name = name
        self._cond = threading.Condition()
        self._slot: tuple[PendingMap, int] | None = None
        self._busy = False
        self._stopping = False
        self._thread: threading.Thread | None = None
        #: maps replaced in the slot by a newer one before they were measured
        self.skipped = 0
        #: maps measured
        self.measured = 0

    def start(self) -> None:
        """Start the thread (again after stop())."""
        with self._cond:
            self._stopping, self._slot = False, None
        self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
        self._thread.start()

    def submit(self, pending: PendingMap, epoch: int) -> None:
        """Hand over a complete map; it replaces a map still waiting in the slot (which is
        then never built)."""
        with self._cond:
            if self._slot is not None:
                self.skipped += 1
            self._slot = (pending, epoch)
            self._cond.notify()

    def wait_idle(self, timeout_s: float) -> bool:
        """Until no map waits or is being measured; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._slot is None and not self._busy,
                                       timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Drop the waiting map, let the one being measured finish, join the thread."""
        with self._cond:
            self._stopping, self._slot = True, None
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                logger.error("%s did not stop within %.1f s", self._name, timeout_s)
            self._thread = None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def idle(self) -> bool:
        """True when no map is being measured or waits. While one is, progress is the
        thread's to report (by publishing): a pipeline that hangs then makes the output
        FAULT one max age after it took the map, whatever the loop does."""
        with self._cond:
            return not self._busy and self._slot is None

    def _set_idle(self) -> None:
        with self._cond:
            self._busy = False
            self._cond.notify_all()

    def _take(self) -> tuple[PendingMap, int] | None:
        self._set_idle()
        with self._cond:
            self._cond.wait_for(lambda: self._slot is not None or self._stopping)
            if self._stopping:
                return None
            job, self._slot, self._busy = self._slot, None, True
            return job

    def _run(self) -> None:
        try:
            while (job := self._take()) is not None:
                self._measure(*job)
                self.measured += 1
        except Exception as exc:  # handed to the unit: laser off, FAULT published
            logger.exception("%s failed", self._name)
            self._set_idle()
            self._on_error(exc)
        self._set_idle()
