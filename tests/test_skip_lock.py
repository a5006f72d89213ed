"""No phase search once locked: after the lock the correlation runs once per lock history
(a low-rate re-check), not every sub-frame, and the maps equal those of a demodulator
told the lag."""

from __future__ import annotations

import numpy as np

from atris_node.codes import walsh_chips
from atris_node.demod import BlockDemodulator
from atris_node.types import DistortionMap, SubFrame

N, LAG = 8, 3
CHIPS = walsh_chips(N, 5)  # period N: every lag gives its own sign sequence


def sub_frames(count: int) -> list[SubFrame]:
    """A laser line strobed ``LAG`` sub-frames late over ambient with noise, 10-bit."""
    rng = np.random.default_rng(11)
    out = []
    for seq in range(count):
        pixels = rng.normal(300.0, 5.0, (32, 96))
        pixels[12:14] += 80.0 * CHIPS[(seq - LAG) % N]
        out.append(SubFrame(np.clip(pixels, 0, 1023).astype(np.uint16), seq, seq / 240.0,
                            seq / 240.0, 500.0, bits=10))
    return out


def _maps(demod: BlockDemodulator, frames: list[SubFrame]) -> list[DistortionMap]:
    return [m for m in (demod.push(sub) for sub in frames) if m is not None]


def test_feature_locked_maps_equal_known_lag_maps_with_rare_rechecks() -> None:
    searching = BlockDemodulator(CHIPS, bits=10, lag=None)
    lock = searching._lock
    decide, calls = lock._decide, []

    def counted() -> int | None:
        calls.append(lock._levels[-1][0])  # the sequence it was run at
        return decide()

    lock._decide = counted  # type: ignore[method-assign]
    frames = sub_frames(30 * N)
    found = _maps(searching, frames)
    assert searching.lag == LAG and len(found) >= 20
    first = found[0].first_sequence  # the window the lock replayed from
    told = _maps(BlockDemodulator(CHIPS, bits=10, lag=LAG), frames[first:])
    assert [(m.first_sequence, m.last_sequence) for m in told] == [
        (m.first_sequence, m.last_sequence) for m in found]
    assert all(np.array_equal(a.values, b.values) for a, b in zip(found, told, strict=True))
    locked_at = found[0].last_sequence  # the lock replays its pending window at once
    after_lock = len(frames) - 1 - locked_at
    rechecks = sum(1 for seq in calls if seq > locked_at)
    assert 1 <= rechecks <= after_lock // lock.history + 1  # not once per sub-frame
