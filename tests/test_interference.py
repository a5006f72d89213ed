"""Foreign-code and same-code energy on the sampled strips (issue 6.5 / 11.1)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pytest

from atris_node import codes
from atris_node.demod import STRIP_POSITIONS, STRIP_WIDTH
from atris_node.errors import CodeError
from atris_node.pipeline.interference import InterferenceMeter, InterferenceReport
from atris_node.types import SubFrame

N = 8
PLAN = {r: codes.walsh_chips(N, r) for r in (2, 3, 5)}


def _scene(own_lag: int, intruders: Iterable[tuple[int, int, float, slice]],
           count: int = 3 * N) -> list[SubFrame]:
    """Own laser (row 2, 50 DN on rows 10-11) plus intruders (row, shift, level, rows)."""
    own = PLAN[2]
    subs = []
    for s in range(100, 100 + count):
        frame = np.full((48, 64), 200.0) + np.linspace(0, 40, 64)[None, :]
        frame[10:12] += 50.0 * own[(s - own_lag) % N]
        for row, shift, level, rows in intruders:
            frame[rows] += level * codes.walsh_chips(N, row)[(s + shift) % N]
        subs.append(SubFrame(frame.astype(np.uint16), s, 0.0, 0.0, 100.0, bits=10))
    return subs


def _reports(meter: InterferenceMeter, subs: list[SubFrame]) -> list[InterferenceReport]:
    return [r for r in (meter.push(s) for s in subs) if r is not None]


def test_foreign_code_energy_is_measured_at_its_shift() -> None:
    meter = InterferenceMeter(PLAN, own_row=2, lag=1)
    reports = _reports(meter, _scene(1, [(5, 3, 100.0, slice(20, 22))]))
    assert len(reports) == 3
    for report in reports:
        assert report.foreign[5] == pytest.approx(4.0)  # (100 / 50)^2, same pixel count
        assert report.foreign[3] == 0.0 and report.own_excess == 0.0
        columns = STRIP_WIDTH * len(STRIP_POSITIONS)
        assert report.own_energy == pytest.approx((50 * N / 2) ** 2 * 2 * columns)


def test_same_code_intruder_shows_as_own_excess() -> None:
    meter = InterferenceMeter(PLAN, own_row=2)
    (report, *_) = _reports(meter, _scene(0, [(2, 1, 50.0, slice(30, 32))]))
    assert report.own_excess == pytest.approx(1.0)
    assert report.foreign == {3: 0.0, 5: 0.0}


def test_only_the_given_codes_are_evaluated() -> None:
    meter = InterferenceMeter({2: PLAN[2], 5: PLAN[5]}, own_row=2)
    assert meter.rows == (5,)
    (report, *_) = _reports(meter, _scene(0, [(3, 0, 80.0, slice(20, 22))]))
    assert set(report.foreign) == {5} and report.foreign[5] == 0.0


def test_a_gap_restarts_the_window() -> None:
    meter = InterferenceMeter(PLAN, own_row=2)
    subs = _scene(0, [])
    reports = _reports(meter, subs[:5] + subs[6:])
    assert [r.first_sequence for r in reports] == [106, 114]


def test_bad_plans_are_refused() -> None:
    with pytest.raises(CodeError, match="own row 4"):
        InterferenceMeter(PLAN, own_row=4)
    with pytest.raises(CodeError, match="one length"):
        InterferenceMeter({2: PLAN[2], 3: codes.walsh_chips(4, 3)}, own_row=2)
