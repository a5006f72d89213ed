"""Order statistics by selection, for compiled code (numba, ``nopython``), and the step of
an insertion sort that the few values of a column or a flank are sorted with.

numpy's median sorts; inside a compiled loop a selection (``np.partition``, O(n)) of the
order statistic needed is several times faster than numba's sort. The mean of the middle
two is numpy's own arithmetic, so the results are the same to the bit
(tests/test_lines_reference.py, tests/test_kernels_reference.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel, uncounted

FloatArray = npt.NDArray[np.float64]


@uncounted
def insert_sorted(out: npt.NDArray[Any], m: int, value: Any) -> None:
    """``value`` into ``out[:m + 1]``, keeping ``out[:m]`` ascending (one step of an
    insertion sort: the arrays sorted so are a column's few peaks, rows or flank values)."""
    i = m
    while i > 0 and out[i - 1] > value:
        out[i] = out[i - 1]
        i -= 1
    out[i] = value


@kernel()
def kth(values: FloatArray, k: int) -> float:
    """The k-th smallest of ``values`` (0-based)."""
    return float(np.partition(values, k)[k])


@kernel()
def median(values: FloatArray) -> float:
    """``np.median`` of a non-empty array (the mean of the middle two if even). One
    selection: the lower middle value is the greatest of those it puts before the upper
    one."""
    n = values.size
    part = np.partition(values, n // 2)
    upper = part[n // 2]
    if n % 2:
        return float(upper)
    return float((part[:n // 2].max() + upper) / 2)
