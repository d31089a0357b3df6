"""Array shapes that hold for every size, zero included.

numpy cannot infer ``-1`` in ``a.reshape(len(a), -1)`` (N rows, the rest inferred) when ``a`` is empty ("cannot reshape array of size 0 into
shape (0,newaxis)"): a window without a measured bone, a stream without a detected frame or a file without rows
is empty, and every such reshape was a traceback there. Flatten through :func:`per_row` instead.
"""
from __future__ import annotations

import math

import numpy as np


def per_row(a: np.ndarray) -> np.ndarray:
    """(N, ...) -> (N, prod(...)): each row's values flattened, for N = 0 too."""
    a = np.asarray(a)
    return a.reshape(a.shape[0], math.prod(a.shape[1:]))
