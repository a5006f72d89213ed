"""Walsh rows, the orthogonality criterion (paper Eq. 7) and Table 1."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atris_node import codes
from atris_node.errors import CodeError

LENGTHS = (4, 8, 16, 32)


def _rect_integral(v_chips: np.ndarray, u_chips: np.ndarray, shift: float) -> float:
    """Eq. 7b by brute force: both codes sampled 1000 times per chip, shift rounded to it."""
    per_chip = 1000
    v = np.repeat(codes.bipolar(v_chips).astype(np.float64), per_chip)
    u = np.repeat(u_chips.astype(np.float64), per_chip)
    return float(v @ np.roll(u, -round(shift * per_chip))) / per_chip


# --- feature: the Sylvester matrix and the chips -------------------------------------------

@pytest.mark.parametrize("n", LENGTHS)
def test_walsh_matrix_is_hadamard(n: int) -> None:
    h = codes.walsh_matrix(n).astype(np.int64)
    assert h.dtype == np.int64 and set(np.unique(h)) == {-1, 1}
    np.testing.assert_array_equal(h @ h.T, n * np.eye(n, dtype=np.int64))
    assert (h[0] == 1).all()


def test_walsh_chips_follow_sylvester_rows() -> None:
    assert codes.walsh_chips(4, 2).tolist() == [1, 0, 1, 0]
    assert codes.walsh_chips(8, 5).tolist() == [1, 1, 1, 1, 0, 0, 0, 0]
    assert codes.walsh_chips(8, 4).tolist() == [1, 0, 0, 1, 1, 0, 0, 1]
    assert codes.walsh_chips(8, 4).dtype == np.uint8
    np.testing.assert_array_equal(codes.bipolar(codes.walsh_chips(16, 7)),
                                  codes.walsh_matrix(16)[6])


@pytest.mark.parametrize("n", LENGTHS)
def test_every_row_but_the_first_is_balanced(n: int) -> None:
    assert not codes.is_balanced(codes.walsh_chips(n, 1))
    assert all(codes.is_balanced(codes.walsh_chips(n, r)) for r in range(2, n + 1))
    assert not codes.is_balanced([1, 1, 1, 0])


# --- feature: correlation at integer and fractional shifts ---------------------------------

@given(st.lists(st.integers(0, 1), min_size=4, max_size=4).flatmap(
    lambda _: st.tuples(st.lists(st.integers(0, 1), min_size=12, max_size=12),
                        st.lists(st.integers(0, 1), min_size=12, max_size=12))))
@settings(max_examples=30, deadline=None)
def test_cross_correlation_matches_the_sum(pair: tuple[list[int], list[int]]) -> None:
    v_chips, u_chips = pair
    v = [2 * c - 1 for c in v_chips]
    expected = [sum(v[i] * u_chips[(i + t) % 12] for i in range(12)) for t in range(12)]
    assert codes.cross_correlation(v_chips, u_chips).tolist() == expected


@given(row_a=st.integers(1, 16), row_b=st.integers(1, 16),
       shift=st.integers(0, 15 * 1000).map(lambda s: s / 1000))
@settings(max_examples=40, deadline=None)
def test_fractional_correlation_is_the_rectangle_integral(
        row_a: int, row_b: int, shift: float) -> None:
    a, b = codes.walsh_chips(16, row_a), codes.walsh_chips(16, row_b)
    assert codes.fractional_cross_correlation(a, b, shift) == pytest.approx(
        _rect_integral(a, b, shift), abs=1e-9)


@given(data=st.data(), shift=st.floats(-40.0, 40.0, allow_nan=False))
@settings(max_examples=60, deadline=None)
def test_rows_of_an_async_set_never_see_each_other(data: st.DataObject, shift: float) -> None:
    n = data.draw(st.sampled_from(LENGTHS))
    chosen = data.draw(st.sampled_from(codes.async_sets(n)))
    own, other = data.draw(st.permutations(chosen))[:2]
    value = codes.fractional_cross_correlation(
        codes.walsh_chips(n, own), codes.walsh_chips(n, other), shift)
    assert value == pytest.approx(0.0, abs=1e-9)


def test_rows_of_one_range_do_see_each_other() -> None:
    """Rows 3 and 4 of H_8 share their spectrum: orthogonal at shift 0, not at shift 1."""
    a, b = codes.walsh_chips(8, 3), codes.walsh_chips(8, 4)
    correlation = codes.cross_correlation(a, b)
    assert correlation[0] == 0 and correlation[1] != 0
    assert not codes.fractionally_orthogonal(a, b)
    assert codes.fractional_cross_correlation(a, b, 0.5) != 0.0


def test_a_half_chip_offset_of_the_same_code_leaks() -> None:
    row2 = codes.walsh_chips(8, 2)
    assert codes.fractional_cross_correlation(row2, row2, 0.5) == 0.0
    assert codes.fractional_cross_correlation(row2, row2, 0.25) == pytest.approx(2.0)


# --- feature: Table 1 and the bound ---------------------------------------------------------

TABLE_1 = {
    4: [(2,), range(3, 5)],
    8: [(2,), range(3, 5), range(5, 9)],
    16: [(2,), range(3, 5), range(5, 9), range(9, 17)],
    32: [(2,), range(3, 5), range(5, 9), range(9, 17), range(17, 33)],
}


@pytest.mark.parametrize("n", LENGTHS)
def test_table_1_is_reproduced(n: int) -> None:
    expected = sorted(itertools.product(*TABLE_1[n]))
    sets = codes.async_sets(n)
    assert sets == expected
    assert codes.max_async_codes(n) == len(TABLE_1[n]) == len(sets[0])
    assert codes.async_set_count(n) == len(sets)
    for example in [(2, 3, 5), (2, 4, 7), (2, 4, 8)]:
        assert (example in sets) == (n == 8)


def _maximal_orthogonal_sets(n: int) -> tuple[int, list[tuple[int, ...]]]:
    """Exhaustive search over all subsets of balanced rows, by the criterion alone."""
    table = codes.orthogonality_table(n)
    balanced = [r for r in range(1, n + 1) if codes.is_balanced(codes.walsh_chips(n, r))]
    best: list[tuple[int, ...]] = []
    size = 1
    while True:
        found = [s for s in itertools.combinations(balanced, size)
                 if all(table[a, b] for a, b in itertools.combinations(s, 2))]
        if not found:
            return size - 1, best
        best, size = found, size + 1


@pytest.mark.parametrize("n", [8, 16])
def test_no_larger_set_exists(n: int) -> None:
    largest, sets = _maximal_orthogonal_sets(n)
    assert largest == codes.max_async_codes(n)
    assert sorted(sets) == codes.async_sets(n)


def test_set_counts_for_long_codes() -> None:
    assert codes.async_set_count(64) == 2**15
    assert codes.async_set_count(128) == 2**21
    first = next(codes.iter_async_sets(128))
    assert first == codes.code_set(128) == (2, 3, 5, 9, 17, 33, 65)


# --- feature: synchronous set and the chosen set -------------------------------------------

@pytest.mark.parametrize("n", LENGTHS)
def test_sync_rows_are_orthogonal_when_aligned_only(n: int) -> None:
    rows = codes.sync_rows(n)
    assert rows == tuple(range(2, n + 1)) == codes.code_set(n, "sync")
    for a, b in itertools.combinations(rows, 2):
        assert codes.cross_correlation(codes.walsh_chips(n, a), codes.walsh_chips(n, b))[0] == 0
    assert not all(codes.rows_orthogonal(n, a, b) for a, b in itertools.combinations(rows, 2))


def test_code_set_lowest_rows_first_and_count() -> None:
    assert codes.code_set(32) == (2, 3, 5, 9, 17)
    assert codes.code_set(32, count=2) == (2, 3)
    assert codes.code_set(8, "sync", count=7) == (2, 3, 4, 5, 6, 7, 8)


# --- exception ------------------------------------------------------------------------------

@pytest.mark.parametrize("bad", [0, 1, 2, 3, 6, 12, 24, -8, 8192, True, 8.0, "8"])
def test_lengths_that_are_not_a_power_of_two_from_4_are_refused(bad: object) -> None:
    with pytest.raises(CodeError, match="code length"):
        codes.check_length(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(("mode", "count"), [("async", 4), ("sync", 8), ("async", 0)])
def test_more_codes_than_exist_are_refused(mode: codes.Mode, count: int) -> None:
    with pytest.raises(CodeError, match="do not exist"):
        codes.code_set(8, mode, count)


def test_bad_rows_modes_and_chips_are_refused() -> None:
    with pytest.raises(CodeError, match=r"accepted: 1\.\.8"):
        codes.walsh_chips(8, 9)
    with pytest.raises(CodeError, match="mode"):
        codes.code_set(8, "hopping")  # type: ignore[arg-type]
    with pytest.raises(CodeError, match="0/1 chips"):
        codes.bipolar([1, 2, 0, 1])
    with pytest.raises(CodeError, match="different lengths"):
        codes.cross_correlation([1, 0, 1, 0], [1, 0])
