"""Bookkeeping for fuzz tests: every input either works or is refused with a clear error."""

from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any

from atris_node.errors import AtrisError


class FuzzTally:
    """Counts the examples tried per target; ``settle`` runs one of them."""

    def __init__(self) -> None:
        self.counts: collections.Counter[str] = collections.Counter()

    def settle(self, target: str, call: Callable[[], Any]) -> Any:
        """Run ``call``; an AtrisError with a message is a clear refusal (None), any other
        exception propagates and fails the test."""
        self.counts[target] += 1
        try:
            return call()
        except AtrisError as exc:
            assert str(exc), f"{target}: {type(exc).__name__} without a message"
            return None

    def report(self) -> str:
        """One line: examples per target."""
        return f"fuzz examples per target: {dict(sorted(self.counts.items()))}"
