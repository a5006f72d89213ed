"""Walsh-Hadamard modulation codes and their cyclic orthogonality (paper sections 3 and 6).

A code is a sequence of N chips, 1 = projector ON, 0 = OFF (uint8). Its bipolar form
``v = +1 / -1`` is what the demodulator multiplies the sub-frames with. Rows are numbered
1-based as in the paper: row 1 of the Sylvester matrix H_N is the constant row (never
usable), row 2 alternates.

Two units with codes v (own, bipolar) and u (other, unipolar) do not see each other when
the periodic cross-correlation ``R(tau) = sum_i v_i u_(i+tau)`` is zero at every shift
(paper Eq. 7a), and when the continuous version with chips as rectangles is zero at every
fractional shift too (Eq. 7b). Sets of mutually orthogonal rows (Table 1): row 2, then one
row from each range [2^j + 1, 2^(j+1)] for j = 1 .. k-1, which gives k = log2 N codes.

Example:
    >>> code_set(8)
    (2, 3, 5)
    >>> walsh_chips(8, 3).tolist()
    [1, 1, 0, 0, 1, 1, 0, 0]
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Iterator, Sequence
from functools import lru_cache
from typing import Literal

import numpy as np
import numpy.typing as npt

from atris_node.errors import CodeError

logger = logging.getLogger(__name__)

#: longest code accepted; H_N is N x N int8, so 4096 is already 16 MiB.
MAX_LENGTH = 4096
Mode = Literal["async", "sync"]
ChipsLike = Sequence[int] | npt.NDArray[np.integer]


def check_length(n: int) -> int:
    """Return ``n`` if it is a power of two in [4, MAX_LENGTH], else raise CodeError."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer):
        raise CodeError(f"code length must be an integer, got {n!r}")
    n = int(n)
    if n < 4 or n > MAX_LENGTH or n & (n - 1):
        raise CodeError(
            f"code length {n} is not allowed; accepted: a power of two from 4 to {MAX_LENGTH}"
        )
    return n


@lru_cache(maxsize=16)
def _sylvester(n: int) -> npt.NDArray[np.int8]:
    matrix = np.ones((1, 1), dtype=np.int8)
    while matrix.shape[0] < n:
        matrix = np.block([[matrix, matrix], [matrix, -matrix]])
    matrix.setflags(write=False)
    return matrix


def walsh_matrix(n: int) -> npt.NDArray[np.int8]:
    """The Sylvester Hadamard matrix H_N, (N, N) int8 of +1/-1 (a fresh, writable copy)."""
    return _sylvester(check_length(n)).copy()


def _check_row(n: int, row: int) -> None:
    if not 1 <= row <= n:
        raise CodeError(f"Walsh row {row} does not exist for length {n}; accepted: 1..{n}")


def walsh_chips(n: int, row: int) -> npt.NDArray[np.uint8]:
    """Chips of Walsh row ``row`` (1-based) of H_N: (N,) uint8, 1 where H_N has +1."""
    _check_row(check_length(n), row)
    return (_sylvester(n)[row - 1] > 0).astype(np.uint8)


def _as_chips(chips: ChipsLike, name: str = "chips") -> npt.NDArray[np.uint8]:
    array = np.asarray(chips)
    if array.ndim != 1 or array.size == 0 or not np.isin(array, (0, 1)).all():
        raise CodeError(f"{name} must be a non-empty 1-D sequence of 0/1 chips, got {chips!r}")
    return array.astype(np.uint8)


def bipolar(chips: ChipsLike) -> npt.NDArray[np.int8]:
    """Bipolar form of a code: (N,) int8, +1 where the chip is 1, -1 where it is 0."""
    return (2 * _as_chips(chips).astype(np.int8) - 1).astype(np.int8)


def is_balanced(chips: ChipsLike) -> bool:
    """True when the code has as many ON chips as OFF chips (ambient light cancels)."""
    array = _as_chips(chips)
    return 2 * int(array.sum()) == array.size


def _same_length(a: npt.NDArray[np.uint8], b: npt.NDArray[np.uint8]) -> None:
    if a.size != b.size:
        raise CodeError(
            f"codes of different lengths ({a.size} and {b.size}) are never orthogonal; "
            "accepted: codes of one length"
        )


def cross_correlation(v_chips: ChipsLike, u_chips: ChipsLike) -> npt.NDArray[np.int64]:
    """Paper Eq. 7a at every integer shift: ``R[tau] = sum_i v_i * u_((i + tau) mod N)``.

    ``v`` is the own code in bipolar form, ``u`` the other code in unipolar (0/1) form, as
    it strobes its laser. Returns (N,) int64, in units of one chip of laser intensity.
    """
    v_unipolar, u = _as_chips(v_chips, "v_chips"), _as_chips(u_chips, "u_chips")
    _same_length(v_unipolar, u)
    v = bipolar(v_unipolar).astype(np.float64)
    spectrum = np.conj(np.fft.rfft(v)) * np.fft.rfft(u.astype(np.float64))
    return np.rint(np.fft.irfft(spectrum, n=u.size)).astype(np.int64)


def fractional_cross_correlation(
    v_chips: ChipsLike, u_chips: ChipsLike, shift: float
) -> float:
    """Paper Eq. 7b: ``integral over one period of v(t) u(t + shift) dt``, chips as rectangles.

    Time and ``shift`` are in chips. Chip i of v covers [i, i + 1); with ``shift = n + f``
    (0 <= f < 1) it overlaps chip ``i + n`` of u for ``1 - f`` and chip ``i + n + 1`` for
    ``f``, so the integral is ``(1 - f) R[n] + f R[n + 1]``, exactly.
    """
    correlation = cross_correlation(v_chips, u_chips)
    n = math.floor(shift)
    fraction = shift - n
    size = correlation.size
    return float((1.0 - fraction) * correlation[n % size] + fraction * correlation[(n + 1) % size])


def fractionally_orthogonal(a_chips: ChipsLike, b_chips: ChipsLike) -> bool:
    """True when neither code sees the other at any integer or fractional shift.

    Both directions are checked (a demodulating b's strobe and b demodulating a's). With
    rectangular chips the integral of Eq. 7b is piecewise linear in the shift with its
    corners at whole chips, so it is zero everywhere iff it is zero at every whole chip;
    the half-chip midpoints are evaluated as well, as the criterion itself.
    """
    a, b = _as_chips(a_chips, "a_chips"), _as_chips(b_chips, "b_chips")
    _same_length(a, b)
    return _integral_zero(cross_correlation(a, b)) and _integral_zero(cross_correlation(b, a))


def _integral_zero(correlation: npt.NDArray[np.int64]) -> bool:
    """Eq. 7b at every whole and half-chip shift, from the integer correlation R."""
    whole = correlation.astype(np.float64)
    half = 0.5 * whole + 0.5 * np.roll(whole, -1)
    return not (whole.any() or half.any())


def max_async_codes(n: int) -> int:
    """k = log2 N: the most codes that are mutually orthogonal at every shift."""
    return check_length(n).bit_length() - 1


def async_set_count(n: int) -> int:
    """Number of maximal asynchronous sets: prod over j = 1..k-1 of 2^j."""
    k = max_async_codes(n)
    return 2 ** (k * (k - 1) // 2)


def sync_rows(n: int) -> tuple[int, ...]:
    """The N - 1 non-constant rows (1-based), orthogonal when chips are aligned (shift 0)."""
    return tuple(range(2, check_length(n) + 1))


@lru_cache(maxsize=65536)
def rows_orthogonal(n: int, row_a: int, row_b: int) -> bool:
    """True when Walsh rows ``row_a`` and ``row_b`` (1-based) of H_N pass Eq. 7b."""
    if row_a == row_b:
        return False
    return fractionally_orthogonal(walsh_chips(n, row_a), walsh_chips(n, row_b))


def orthogonality_table(n: int) -> npt.NDArray[np.bool_]:
    """(N + 1, N + 1) bool; ``[r, s]`` is True when rows r and s (1-based) pass Eq. 7b.

    Row 1 and index 0 are False everywhere. Computed from the criterion, not from the rule.
    """
    table = np.zeros((check_length(n) + 1, n + 1), dtype=bool)
    for r, s in itertools.combinations(range(2, n + 1), 2):
        table[r, s] = table[s, r] = rows_orthogonal(n, r, s)
    return table


def _rule_choices(n: int) -> list[range]:
    k = max_async_codes(n)
    return [range(2, 3)] + [range(2**j + 1, 2 ** (j + 1) + 1) for j in range(1, k)]


def _verify(n: int, rows: tuple[int, ...]) -> tuple[int, ...]:
    for r, s in itertools.combinations(rows, 2):
        if not rows_orthogonal(n, r, s):
            raise CodeError(f"rows {r} and {s} of length {n} are not cyclic orthogonal")
    return rows


def iter_async_sets(n: int) -> Iterator[tuple[int, ...]]:
    """Every maximal asynchronous set (1-based rows, ascending), each checked by Eq. 7b.

    Sets come in lexicographic order; there are ``async_set_count(n)`` of them (2^21 for
    N = 128), so prefer this iterator to :func:`async_sets` for long codes.
    """
    for rows in itertools.product(*_rule_choices(n)):
        yield _verify(n, tuple(rows))


def async_sets(n: int) -> list[tuple[int, ...]]:
    """All maximal asynchronous sets as a list (see :func:`iter_async_sets`)."""
    return list(iter_async_sets(n))


def code_set(n: int, mode: Mode | str = "async", count: int | None = None) -> tuple[int, ...]:
    """One maximal code set (1-based rows, lowest rows first), or its first ``count`` rows.

    ``mode="async"``: rows 2, 3, 5, 9, ... (orthogonal at any shift, k codes).
    ``mode="sync"``: rows 2..N (orthogonal with aligned chips only, N - 1 codes).
    """
    if mode == "async":
        rows = _verify(n, tuple(choice[0] for choice in _rule_choices(check_length(n))))
    elif mode == "sync":
        rows = sync_rows(n)
    else:
        raise CodeError(f"code mode {mode!r} is not known; accepted: 'async', 'sync'")
    if count is None:
        return rows
    if not 1 <= count <= len(rows):
        raise CodeError(
            f"{count} {mode} codes of length {n} do not exist; accepted: 1..{len(rows)}"
        )
    return rows[:count]


def chips_string(chips: ChipsLike) -> str:
    """A code as a string of '0'/'1' chips, first chip first."""
    return "".join(str(int(c)) for c in _as_chips(chips))
