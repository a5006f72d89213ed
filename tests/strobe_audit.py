"""An independent record of what the projector was told, to hold against the negotiator.

The node's own ``strobe_lit_while_not_allowed`` counter is kept by the code it checks;
this wrapper records every ``strobe``/``off`` call at the projector with the host time, so
a test can compare it with the negotiator's strobe-permission timeline.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from drivers import Camera, Projector


class AuditedProjector(Projector):
    """Wraps ``inner``; ``calls`` holds (host time, chip 0/1 or None for off, sequence)."""

    def __init__(self, inner: Projector) -> None:
        self.inner = inner
        self.calls: list[tuple[float, int | None, int]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def _strobe(self, chip: int, sequence: int) -> None:
        self.calls.append((time.monotonic(), chip, sequence))
        self.inner.strobe(chip, sequence)

    def _off(self) -> None:
        self.calls.append((time.monotonic(), None, -1))
        self.inner.off()


def audited(opener: Callable[..., tuple[Camera, Projector]],
            projectors: list[AuditedProjector]) -> Callable[..., tuple[Camera, Projector]]:
    """An ``open_backend`` whose projectors are audited (appended to ``projectors``)."""
    def open_audited(name: str, **settings: Any) -> tuple[Camera, Projector]:
        camera, projector = opener(name, **settings)
        projectors.append(AuditedProjector(projector))
        return camera, projectors[-1]
    return open_audited


def unpermitted_light(projectors: list[AuditedProjector],
                      timeline: list[tuple[float, bool, int | None]]) -> list[float]:
    """Host times of the chips = 1 the projectors were told while the negotiator's
    timeline (time, may_strobe, row) said the unit may not strobe."""
    bad = []
    for projector in projectors:
        for t, chip, _ in projector.calls:
            if chip != 1:
                continue
            before = [entry for entry in timeline if entry[0] <= t]
            if not before or not before[-1][1]:
                bad.append(t)
    return bad
