"""Sums of products over a record, made on the calling thread.

``np.dot`` of two long vectors is OpenBLAS's ``ddot``, which splits a vector longer than
10 000 elements across its worker threads. On a busy machine the woken workers wait for a
core longer than the sum takes (900 000 elements: 4 ms against 0.5), and each then spins for
a while on the other core (a quarter of a second of CPU over an analysis). The analysis is
one thread: its sums over a record are numpy's own loops (``np.einsum``), whose result does
not depend on the number of cores either.

Pure computation on arrays.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def dot(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """``Σ a_i b_i`` of two vectors of one length."""
    return float(np.einsum("i,i->", a, b))


__all__ = ["dot"]
