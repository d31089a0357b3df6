"""The square block ``S[np.ix_(idx, idx)]`` of a large dense matrix, gathered by a compiled (numba) kernel in threads.

The bundle adjustment takes the free parameters' block of the reduced camera system before each factorisation
(lens terms held, the lens model's candidate sets). numpy's fancy indexing with two index arrays walks a generic
broadcast of index pairs: 1.08 s for 7,370 of the full dome's 7,815 unknowns on this machine, as long as the
single-precision Cholesky factorisation that follows (1.16 s), 13.6 s of a 147 s bundle adjustment. Gathering a row
at a time from the rows ``idx`` names is a plain memory stream: the same values, bit for bit.
"""
from __future__ import annotations

import numpy as np

from dome_calib.ba.threads import run_in_threads
from dome_calib.jit import njit

#: Below this many entries numpy's fancy indexing is as fast and needs no compiled kernel.
_COMPILED_MIN = 256 * 256


def submatrix(S: np.ndarray, idx: np.ndarray, *, n_threads: int = 2, out: np.ndarray | None = None) -> np.ndarray:
    """A C-ordered float64 array equal to ``S[np.ix_(idx, idx)]`` (``S`` 2-D float64, ``idx`` integer indices
    within its rows and columns; not checked when compiled, as numpy would): new, or ``out`` (k, k) filled."""
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    k = len(idx)
    if k * k < _COMPILED_MIN or S.dtype != np.float64 or not S.flags.c_contiguous:
        if out is None:
            return S[np.ix_(idx, idx)]
        out[...] = S[np.ix_(idx, idx)]
        return out
    if k and (idx.min() < 0 or idx.max() >= min(S.shape)):
        raise IndexError(f"index out of range for a {S.shape[0]} x {S.shape[1]} matrix")
    return rectangle(S, idx, idx, out=np.empty((k, k)) if out is None else out, n_threads=n_threads)


@njit(nogil=True, boundscheck=False)
def _gather_in_place(flat, n, idx):  # pragma: no cover - compiled
    k = idx.shape[0]
    row = np.empty(k)
    for r in range(k):
        src = idx[r] * n
        for c in range(k):
            row[c] = flat[src + idx[c]]
        dst = r * k
        for c in range(k):
            flat[dst + c] = row[c]


def submatrix_in_place(S: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``S[np.ix_(idx, idx)]`` written over the start of ``S``'s own memory (``S`` square, C-ordered float64;
    ``idx`` strictly ascending): a (k, k) view of it, and ``S`` is spent. No second matrix: row r of the block goes
    where rows before ``idx[r]`` of ``S`` were, which no later row of the block reads (``idx[r'] >= r' > r``)."""
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    n, k = S.shape[0], len(idx)
    if S.shape != (n, n) or S.dtype != np.float64 or not S.flags.c_contiguous:
        raise ValueError("submatrix_in_place needs a square C-ordered float64 matrix")
    if k and (np.any(np.diff(idx) <= 0) or idx[0] < 0 or idx[-1] >= n):
        raise IndexError("submatrix_in_place needs strictly ascending indices within the matrix")
    flat = S.reshape(-1)
    _gather_in_place(flat, n, idx)
    return flat[:k * k].reshape(k, k)


@njit(nogil=True, boundscheck=False)
def _gather_rect(S, rows, cols, out, lo, hi):  # pragma: no cover - compiled
    k = cols.shape[0]
    for r in range(lo, hi):
        src = S[rows[r]]
        dst = out[r]
        for c in range(k):
            dst[c] = src[cols[c]]


def rectangle(S: np.ndarray, rows: np.ndarray, cols: np.ndarray, *, out: np.ndarray, n_threads: int = 2
              ) -> np.ndarray:
    """``out`` (len(rows), len(cols)) filled with ``S[np.ix_(rows, cols)]`` (``S`` C-ordered float64, indices within
    it, not checked), by rows in threads."""
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    cols = np.ascontiguousarray(cols, dtype=np.int64)
    k = len(rows)
    if k == 0:
        return out
    step = -(-k // max(1, 4 * n_threads))
    run_in_threads(lambda lo: _gather_rect(S, rows, cols, out, lo, min(lo + step, k)), range(0, k, step), n_threads)
    return out
