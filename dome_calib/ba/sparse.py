"""The reduced camera system where cameras share points: block-sparse storage and a sparse Cholesky (CHOLMOD).

On the full dome most camera pairs share no point (the tent is seen by one side of the dome at a time), yet a
dense reduced camera system costs (15 A)^3 / 3 flops to factorise and (15 A)^2 doubles to hold. Here only the
upper blocks of camera pairs that share a point are formed (:func:`dome_calib.ba.yyt.block_pattern`; the same
Y Y^T sums as the dense kernel, in the same order), gathered into the lower triangle of a CSC matrix over the free
parameters by a fixed map (computed once per observation set), and factorised by CHOLMOD's supernodal Cholesky
(scikit-sparse) with a METIS nested-dissection ordering, analysed once per observation set and reused by every
numeric factorisation of it: the same ordering, so the same bits on every rerun.

scikit-sparse is an optional extra (``pip install dome-calib[sparse]``; it builds against the system's SuiteSparse):
without it every system takes the dense path. Which path a system takes is decided once per observation set, from
integers only: the sparse one when the
factor, counted in camera blocks under CHOLMOD's ordering, holds at most :data:`SPARSE_MAX_FILL` of the dense
triangle's blocks and the system has at
least :data:`SPARSE_MIN_UNKNOWNS` unknowns (below that LAPACK's dense Cholesky is as fast and needs no
analysis; the panel dome's 60 cameras all share points, so its system is dense anyway).

Inner constraints (:func:`dome_calib.ba.gauge.inner_constraint_basis`) add ``B B^T`` (rank 7, dense over every
camera's pose): it is not formed. The system ``(S + B B^T) x = b`` is solved by conjugate gradients on the
Jacobi-scaled operator, preconditioned by the exact inverse from the Woodbury identity over the sparse factor of
S (with a ridge of :data:`_GAUGE_RIDGE` on the scaled diagonal, for the preconditioner only: S alone is singular
up to the damping along the 7 gauge directions), to the same relative residual as the dense mixed-precision path.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

try:  # the optional extra `sparse` (pyproject.toml): without it every system takes the dense path
    import sksparse.cholmod as cholmod
except ImportError:  # pragma: no cover - depends on the installation
    cholmod = None

from dome_calib.ba.yyt import block_pattern

logger = logging.getLogger(__name__)

#: the sparse path when the factor's camera blocks are at most this share of the dense lower triangle's
SPARSE_MAX_FILL = 0.5
#: and the system has at least this many free unknowns (100 cameras of 15)
SPARSE_MIN_UNKNOWNS = 1500
#: ORDERING of CHOLMOD's analysis: METIS nested dissection (fixed seed: the same permutation every run)
ORDERING = "metis"
_GAUGE_RIDGE = 1e-10
_CG_RTOL = 1e-13
_CG_MAX_ITERATIONS = 60


@dataclass(kw_only=True)
class SparseLayout:
    """The block pattern of one observation set and its map to a CSC matrix over the free parameters.

    row_ptr (A + 1,), cols (B,): upper block pattern (:func:`dome_calib.ba.yyt.block_pattern`), diag (A,): each
    camera's diagonal block among them; blocks hold the ``k`` free columns ``free_cols`` of 15. The lower triangle
    of the free system, CSC: ``data = blocks.ravel()[perm]``, ``indices``, ``indptr``; ``col`` (nnz,) the column
    of each entry; ``factor``: CHOLMOD's symbolic analysis."""

    row_ptr: np.ndarray
    cols: np.ndarray
    diag: np.ndarray
    free_cols: np.ndarray
    n_free: int
    perm: np.ndarray
    indices: np.ndarray
    indptr: np.ndarray
    col: np.ndarray
    factor: object  # sksparse.cholmod.Factor

    def matrix(self, blocks: np.ndarray) -> sp.csc_matrix:
        """The lower triangle of the free system (F, F) from the upper blocks (B, k, k) (a new CSC matrix)."""
        F = self.n_free
        return sp.csc_matrix((np.asarray(blocks).reshape(-1)[self.perm], self.indices, self.indptr), shape=(F, F))


def sparse_layout(st, free_cols: np.ndarray) -> SparseLayout | None:
    """The layout of ``st`` (a :class:`dome_calib.ba.schur.Structure`) if its system takes the sparse path (module
    docstring), else None. Cached on the structure."""
    key = ("sparse_layout", free_cols.tobytes())
    if key in st.cache:
        return st.cache[key]
    layout = None
    F = len(st.free_flat)
    if F >= SPARSE_MIN_UNKNOWNS and cholmod is not None:
        A = len(st.active_cameras)
        dense = A * (A + 1) // 2
        row_ptr, cols = block_pattern(st)
        # the factor holds at least the pattern's blocks: a pattern already past the limit (the full dome's 62 %)
        # is dense without the CSC map and CHOLMOD's analysis (seconds per observation set at the full dome)
        if len(cols) <= SPARSE_MAX_FILL * dense:
            layout = _layout(st, free_cols, row_ptr, cols)
            # integers only: the same decision on every machine
            pos = np.empty(F, dtype=np.int64)
            pos[layout.factor.P()] = np.arange(F)
            first = np.full(A, F, dtype=np.int64)  # each camera's first place in CHOLMOD's order
            np.minimum.at(first, st.free_flat // 15, pos)
            fill = block_factor_fill(layout.row_ptr, layout.cols, np.argsort(first, kind="stable"))
            logger.debug("reduced system: %d of %d camera blocks, factor %d", len(layout.cols), dense, fill)
            if fill > SPARSE_MAX_FILL * dense:
                layout = None
    st.cache[key] = layout
    return layout


def block_factor_fill(row_ptr: np.ndarray, cols: np.ndarray, order: np.ndarray) -> int:
    """Camera blocks of the Cholesky factor of the block pattern (row_ptr, cols) eliminated in ``order`` (a
    symbolic elimination on the camera graph: blocks, not entries, so a few hundred cameras cost milliseconds)."""
    return int(block_factor_counts(row_ptr, cols, order).sum())


def block_factor_counts(row_ptr: np.ndarray, cols: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Camera blocks in each block column of the Cholesky factor of the block pattern (row_ptr, cols) eliminated in
    ``order`` (A,), the diagonal block included, in elimination order: its sum is the factor's blocks, the sum of
    (count - 1)^2 its block flops up to a constant (the dense factor's: sum of k^2 for k < A)."""
    A = len(row_ptr) - 1
    rank = np.empty(A, dtype=np.int64)
    rank[order] = np.arange(A)
    a_of = np.repeat(np.arange(A), np.diff(row_ptr))
    M = np.zeros((A, A), dtype=bool)
    M[rank[a_of], rank[cols]] = True
    M[rank[cols], rank[a_of]] = True
    counts = np.empty(A, dtype=np.int64)
    for k in range(A):
        nz = k + 1 + np.flatnonzero(M[k, k + 1:])
        counts[k] = len(nz) + 1
        M[np.ix_(nz, nz)] = True
    return counts


def _layout(st, free_cols: np.ndarray, row_ptr: np.ndarray, cols: np.ndarray) -> SparseLayout:
    A, k = len(row_ptr) - 1, len(free_cols)
    pos = np.full(A * 15, -1, dtype=np.int64)
    pos[st.free_flat] = np.arange(len(st.free_flat))
    a_of = np.repeat(np.arange(A), np.diff(row_ptr))  # each block's row camera
    # every entry (r, c) of every block: its row and column among the free parameters (-1: not free)
    gi = pos[(a_of[:, None] * 15 + free_cols[None, :])[:, :, None].repeat(k, axis=2)]
    gj = pos[(cols[:, None] * 15 + free_cols[None, :])[:, None, :].repeat(k, axis=1)]
    keep = (gi >= 0) & (gj >= 0) & (gi <= gj)  # the upper triangle of the free system (its blocks are upper)
    flat = np.flatnonzero(keep.ravel())
    upper_row, upper_col = gi.ravel()[flat], gj.ravel()[flat]
    # the lower triangle in CSC is the upper one in CSR: column = the upper entry's row
    order = np.lexsort((upper_col, upper_row))
    perm, indices, col = flat[order], upper_col[order], upper_row[order]
    F = len(st.free_flat)
    indptr = np.concatenate([[0], np.cumsum(np.bincount(col, minlength=F))])
    diag = row_ptr[:-1].copy()  # the first block of each row is its own
    layout = SparseLayout(row_ptr=row_ptr, cols=cols, diag=diag, free_cols=free_cols, n_free=F, perm=perm,
                          indices=indices.astype(np.int32), indptr=indptr.astype(np.int32), col=col,
                          factor=None)
    layout.factor = cholmod.analyze(layout.matrix(np.ones(len(cols) * k * k)), mode="supernodal",
                                    ordering_method=ORDERING)
    return layout


def factorise_lower(lower: sp.csc_matrix, shift: float, *, ridges: tuple[float, ...] = (0.0,)):
    """CHOLMOD's factor of the symmetric matrix whose lower triangle is ``lower`` (CSC, its diagonal present) plus
    ``shift + ridge`` on the diagonal, for the first of ``ridges`` that gives a positive definite matrix (analysed
    here with :data:`ORDERING`). Raises numpy.linalg.LinAlgError if none does."""
    n = lower.shape[0]
    factor = cholmod.analyze(lower, mode="supernodal", ordering_method=ORDERING)
    for ridge in ridges:  # a tiny ridge if some direction is not observable at all
        m = lower + sp.identity(n, format="csc") * (shift + ridge) if shift + ridge else lower
        try:
            return factor.cholesky(m.tocsc())
        except cholmod.CholmodNotPositiveDefiniteError:
            continue
    raise np.linalg.LinAlgError("reduced camera system not positive definite")


def solve_sparse(layout: SparseLayout, blocks: np.ndarray, rhs_free: np.ndarray,
                 gauge_basis_free: np.ndarray | None = None) -> np.ndarray:
    """Solve the free system held in ``blocks`` (the upper blocks of ``layout``) for ``rhs_free`` (F,); with
    ``gauge_basis_free`` (F, 7) the system is ``S + B B^T`` (module docstring). Raises numpy.linalg.LinAlgError
    if S is not positive definite (with no gauge term) or conjugate gradients do not converge."""
    S = layout.matrix(blocks)  # lower triangle
    diag = S.diagonal()
    if np.any(diag <= 0):
        raise np.linalg.LinAlgError("reduced camera system: a non-positive diagonal entry")
    d = 1.0 / np.sqrt(diag)
    S.data *= d[S.indices] * d[layout.col]  # Jacobi scaling: lens and pose columns differ by many decades
    b = d * rhs_free
    if gauge_basis_free is not None:
        S = S + sp.identity(layout.n_free, format="csc") * _GAUGE_RIDGE  # the same pattern (diagonal present)
        S.sort_indices()
    try:
        factor = layout.factor.cholesky(S)
    except cholmod.CholmodNotPositiveDefiniteError as exc:
        raise np.linalg.LinAlgError(f"reduced camera system not positive definite ({exc})") from None
    if gauge_basis_free is None:
        return d * factor(b)
    Bs = d[:, None] * gauge_basis_free
    Z = factor(Bs)  # (F, 7)
    cap = np.linalg.inv(np.eye(Bs.shape[1]) + Bs.T @ Z)

    def precond(v: np.ndarray) -> np.ndarray:  # (S_ridge + B B^T)^-1 by Woodbury
        u = factor(v)
        return u - Z @ (cap @ (Bs.T @ u))

    lower, upper, diag_r = S, S.T.tocsc(), S.diagonal()

    def matvec(v: np.ndarray) -> np.ndarray:  # (S + B B^T) v from S's lower triangle (its ridge taken off)
        return lower @ v + upper @ v - (diag_r + _GAUGE_RIDGE) * v + Bs @ (Bs.T @ v)

    b_norm = float(np.linalg.norm(b))
    if b_norm == 0.0:
        return np.zeros_like(b)
    x = precond(b)
    r = b - matvec(x)
    z = precond(r)
    p = z.copy()
    rz = float(r @ z)
    for it in range(_CG_MAX_ITERATIONS):
        if np.linalg.norm(r) <= _CG_RTOL * b_norm:
            logger.debug("sparse reduced system with inner constraints: %d CG iterations", it)
            return d * x
        q = matvec(p)
        alpha = rz / float(p @ q)
        x += alpha * p
        r -= alpha * q
        z = precond(r)
        rz_new = float(r @ z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    raise np.linalg.LinAlgError(f"conjugate gradients did not converge (|r|/|b| = {np.linalg.norm(r) / b_norm:.2g})")
