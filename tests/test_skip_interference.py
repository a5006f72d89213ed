"""Interference analysis only for codes someone uses: the own row, rows claimed on the
bus and the scene's known interferers. The energies reported are unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from atris_node import codes
from atris_node.adaptive.controller import rows_in_use, used_chips
from atris_node.pipeline.interference import InterferenceMeter
from atris_node.types import SubFrame

N = 16
PLAN = {r: codes.walsh_chips(N, r) for r in codes.code_set(N, "async")}  # rows 2, 3, 5, 9


def sub_frames(count: int) -> list[SubFrame]:
    """Own laser on row 2, another unit on row 5 shifted by 3 chips, noise, ambient."""
    rng = np.random.default_rng(4)
    own, other = PLAN[2], PLAN[5]
    out = []
    for seq in range(count):
        pixels = rng.normal(200.0, 4.0, (48, 128))
        pixels[20:22] += 60.0 * own[seq % N]
        pixels[30:32] += 40.0 * other[(seq - 3) % N]
        out.append(SubFrame(np.clip(pixels, 0, 1023).astype(np.uint16), seq, 0.0, 0.0,
                            100.0, bits=10))
    return out


def test_feature_rows_in_use_from_bus_and_scene() -> None:
    assert rows_in_use(PLAN, 2, [5, None]) == (2, 5)
    assert rows_in_use(PLAN, 2, [], scene_rows=[9, 7]) == (2, 9)  # 7 is not in the plan
    assert rows_in_use(PLAN, 3, []) == (3,)


def test_feature_skipped_codes_leave_the_reported_energies_unchanged() -> None:
    full = InterferenceMeter(PLAN, own_row=2)
    gated = InterferenceMeter(used_chips(PLAN, 2, peer_rows=[5]), own_row=2)
    assert gated.rows == (5,)
    for sub in sub_frames(2 * N):
        a, b = full.push(sub), gated.push(sub)
        assert (a is None) == (b is None)
        if a is not None and b is not None:
            assert b.foreign[5] == pytest.approx(a.foreign[5], rel=1e-12)
            assert b.own_excess == pytest.approx(a.own_excess, rel=1e-12)
            assert a.foreign[5] > 10 * max(a.foreign[3], a.foreign[9])  # the one in use
