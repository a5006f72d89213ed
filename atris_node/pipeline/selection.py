"""Order statistics by selection, for compiled code (numba, ``nopython``).

numpy's median sorts; inside a compiled loop a selection (``np.partition``, O(n)) of the
one or two order statistics needed is several times faster than numba's sort. The mean of
the middle two is numpy's own arithmetic, so the results are the same to the bit
(tests/test_lines_reference.py).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from atris_node.jit import kernel

FloatArray = npt.NDArray[np.float64]


@kernel()
def kth(values: FloatArray, k: int) -> float:
    """The k-th smallest of ``values`` (0-based)."""
    return float(np.partition(values, k)[k])


@kernel()
def median(values: FloatArray) -> float:
    """``np.median`` of a non-empty array (the mean of the middle two if even)."""
    n = values.size
    if n % 2:
        return kth(values, n // 2)
    return float((kth(values, n // 2 - 1) + kth(values, n // 2)) / 2)
