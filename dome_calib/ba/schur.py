"""Normal equations of the bundle adjustment, Schur complement on the points, reduced camera system.

Notation (observation i sees point p with camera a; Jc_i (2, 15), Jp_i (2, 3), IRLS weight w_i, residual r_i):

    U_a = sum_i w Jc^T Jc (15 x 15 per camera)      V_p = sum_i w Jp^T Jp (3 x 3 per point)
    W_i = w Jc^T Jp (15 x 3 per observation)       g_a = sum_i w Jc^T r,  g_p = sum_i w Jp^T r

Damped by lambda * D (D = clamped diagonal, as Ceres' Levenberg-Marquardt), the points are eliminated with
V_p = L_p L_p^T (3 x 3 Cholesky, batched over all points). With y_i = W_i L_p^{-T} (15 x 3):

    S = blockdiag(U + lambda D_c) - Y Y^T,   Y the block-sparse (cameras x 15) x (points x 3) matrix of the y_i,
    S dc = -g_c + sum_i y_i L_p^{-1} g_p,     dp = -L_p^{-T} (L_p^{-1} g_p + sum_i y_i^T dc_a).

Y Y^T is the crux (about half the sum over points of track_length^2 block products, 3.4e7 on the full dome),
done by the compiled kernel of :mod:`dome_calib.ba.yyt` (upper triangle of blocks, in threads); the per-observation
blocks (U, V, g, y, and the back-substitution) by those of :mod:`dome_calib.ba.blocks`. Where the cameras share
few points (the full dome) only the blocks of camera pairs that share one are formed and the system is factorised
sparsely (:mod:`dome_calib.ba.sparse`); otherwise (every camera pair sharing points: the panel) it is formed dense
and solved by a dense LAPACK Cholesky.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from dome_calib.ba.blas import blas_threads, cholesky_threads
from dome_calib.ba.blocks import linearize_blocks, point_step_blocks, y_blocks
from dome_calib.ba.sparse import SparseLayout, solve_sparse, sparse_layout
from dome_calib.ba.submatrix import submatrix
from dome_calib.ba.yyt import LANES, subtract_yyt, subtract_yyt_blocks

logger = logging.getLogger(__name__)

_MIN_DIAG, _MAX_DIAG = 1e-6, 1e32
_PARALLEL_CHOLESKY_MIN = 1500  # unknowns from which the dense Cholesky gets more than one BLAS thread
_MIXED_PRECISION_MIN = 3000  # unknowns from which a float32 factor + CG refinement is tried first


@dataclass(kw_only=True)
class Structure:
    """Sparsity of one set of observations (fixed while the observation set is fixed).

    obs (Ma,): indices into the problem's observations, sorted by (camera, point); cam, pt (Ma,).
    active_cameras (A,): cameras with at least one free parameter; cam_local (Ma,): their local index or -1.
    act (Ma,) bool: observation by an active camera (a contiguous block per camera).
    free_flat (F,): free parameters as indices into the (A * 15) flattened active-camera parameters.
    pt_order (Ma_active,): the active observations stably sorted by point (so by camera within a point);
    pt_ptr (P + 1,): each point's slice of ``pt_order``; pt_pos (Ma_active,): the inverse of ``pt_order``;
    cam_pt (Ma_active,): the active camera (local index) of each observation in ``pt_order``.
    """

    obs: np.ndarray
    cam: np.ndarray
    pt: np.ndarray
    n_points: int
    active_cameras: np.ndarray
    cam_local: np.ndarray
    act: np.ndarray
    act_starts: np.ndarray  # (A + 1,) offsets of each active camera's observations among the active ones
    act_index: np.ndarray  # (Ma_active,) the active observations' positions in ``obs`` order
    pt_act: np.ndarray  # (Ma_active,) the active observations' points
    free: np.ndarray  # (A, 15) bool
    free_flat: np.ndarray
    pt_order: np.ndarray
    pt_ptr: np.ndarray
    pt_pos: np.ndarray
    cam_pt: np.ndarray
    live_points: np.ndarray  # (P,) bool: points with >= 2 observations (the others are not refined)
    #: what is computed once per observation set (the sparse layout)
    cache: dict = field(default_factory=dict, repr=False, compare=False)
    #: the solver's large arrays, allocated once and reused by every reduced system of this set (:func:`buffer`);
    #: shared with other structures when one :class:`Workspace` is handed to several (a whole calibration's solves)
    workspace: Workspace = field(default_factory=lambda: Workspace(), repr=False, compare=False)


class Workspace:
    """The bundle adjustment's large arrays by name, kept and handed out again (:func:`buffer`).

    Each name holds one flat allocation that grows to the largest shape asked of it and is handed out as a view of
    its first elements: the reduced systems of every outlier round, every solve of the lens-model selection, its
    quadratic models and the final uncertainties (each a few hundred MB on the full dome) then share the same pages
    instead of mapping fresh ones (glibc maps an allocation that large anew each time, and the kernel zeroes every
    page of it on first touch: 1.5 M extra page faults and 38 s of system time on the full dome's calibration). An
    array handed out under a name is valid until the next request of that name. Nothing process-wide: the arrays go
    with the workspace.
    """

    def __init__(self) -> None:
        self._flat: dict[tuple[str, np.dtype], np.ndarray] = {}

    def array(self, name: str, shape: tuple[int, ...], *, zero: bool = False, dtype: type = np.float64
              ) -> np.ndarray:
        """A C-ordered array of ``shape`` under ``name`` (its contents left from the last use, or zeros if
        ``zero``)."""
        key = (name, np.dtype(dtype))
        n = int(np.prod(shape, dtype=np.int64))
        flat = self._flat.get(key)
        if flat is None or len(flat) < n:
            self._flat[key] = None  # the old one goes before the new one is made
            flat = self._flat[key] = np.empty(n, dtype=dtype)
        out = flat[:n].reshape(shape)
        if zero:
            out.fill(0)
        return out

    def nbytes(self) -> int:
        """Bytes held."""
        return sum(f.nbytes for f in self._flat.values() if f is not None)


def buffer(st: Structure | None, name: str, shape: tuple[int, ...], *, zero: bool = False,
           dtype: type = np.float64) -> np.ndarray:
    """An array of ``shape`` from ``st``'s :class:`Workspace` (a new one if None) under ``name`` (zeroed if
    ``zero``): the solver's large arrays are allocated once per workspace, not once per iteration. The caller must
    be done with the previous one of that name (one reduced system of a workspace lives at a time)."""
    if st is None:
        return np.zeros(shape, dtype=dtype) if zero else np.empty(shape, dtype=dtype)
    return st.workspace.array(name, shape, zero=zero, dtype=dtype)


def build_structure(camera_index: np.ndarray, point_index: np.ndarray, obs_mask: np.ndarray, free: np.ndarray,
                    n_points: int, workspace: Workspace | None = None) -> Structure:
    """Sort the kept observations, drop points seen fewer than twice, and index the free camera parameters.
    ``workspace``: where its large arrays are kept (default: a new one, the structure's own)."""
    keep = np.flatnonzero(obs_mask)
    counts = np.bincount(point_index[keep], minlength=n_points)
    keep = keep[counts[point_index[keep]] >= 2]
    live = np.bincount(point_index[keep], minlength=n_points) >= 2
    order = np.lexsort((point_index[keep], camera_index[keep]))
    obs = keep[order]
    cam, pt = camera_index[obs], point_index[obs]
    C = free.shape[0]
    n_obs_cam = np.bincount(cam, minlength=C)
    active = np.flatnonzero(free.any(axis=1) & (n_obs_cam > 0))
    local = np.full(C, -1, dtype=np.int64)
    local[active] = np.arange(len(active))
    cam_local = local[cam]
    act = cam_local >= 0
    act_starts = np.concatenate([[0], np.cumsum(n_obs_cam[active])]).astype(np.int64)
    free_a = free[active]
    pt_act = pt[act]
    pt_order = np.argsort(pt_act, kind="stable")
    pt_ptr = np.concatenate([[0], np.cumsum(np.bincount(pt_act, minlength=n_points))]).astype(np.int64)
    pt_pos = np.empty_like(pt_order)
    pt_pos[pt_order] = np.arange(len(pt_order))
    return Structure(obs=obs, cam=cam, pt=pt, n_points=n_points, active_cameras=active, cam_local=cam_local,
                     act=act, act_starts=act_starts, act_index=np.flatnonzero(act), pt_act=pt_act, free=free_a,
                     free_flat=np.flatnonzero(free_a.ravel()),
                     pt_order=pt_order, pt_ptr=pt_ptr, pt_pos=pt_pos,
                     cam_pt=cam_local[act][pt_order], live_points=live,
                     workspace=Workspace() if workspace is None else workspace)


@dataclass(kw_only=True)
class Linearization:
    """Gradient and Gauss-Newton blocks at one point of the parameter space (lambda-independent).

    Jc (2, 15, Ma_active) with fixed columns zeroed; Jp (2, 3, Ma); w (Ma,); U (A, 15, 15); V (P, 3, 3);
    g_c (A, 15); g_p (P, 3); D_c (A, 15), D_p (P, 3) the LM scaling diagonals.
    """

    Jc: np.ndarray
    Jp: np.ndarray
    w: np.ndarray
    U: np.ndarray
    V: np.ndarray
    g_c: np.ndarray
    g_p: np.ndarray
    D_c: np.ndarray
    D_p: np.ndarray


def linearize(st: Structure, res: np.ndarray, Jc: np.ndarray, Jp: np.ndarray, w: np.ndarray, *, n_threads: int = 2
              ) -> Linearization:
    """Blocks of J^T W J and J^T W r from component-major residuals (2, Ma) and Jacobians (2, 15|3, Ma) (``Jc`` is
    modified: its fixed columns are zeroed, in place when every observation's camera is active)."""
    if not st.act.all():
        Jc = Jc[:, :, st.act]
    U, g_c, V, g_p = linearize_blocks(Jc, Jp, res, w, st, n_threads)
    D_c = np.clip(np.einsum("aii->ai", U), _MIN_DIAG, _MAX_DIAG)
    D_p = np.clip(np.einsum("pii->pi", V), _MIN_DIAG, _MAX_DIAG)
    return Linearization(Jc=Jc, Jp=Jp, w=w, U=U, V=V, g_c=g_c, g_p=g_p, D_c=D_c, D_p=D_p)


def chol3_inverse(V: np.ndarray) -> np.ndarray:
    """(P, 3, 3) SPD blocks -> (P, 3, 3) inverse Cholesky factors L^{-1} (lower), V = L L^T, batched.

    Pivots are clamped at 1e-12 x the diagonal so a degenerate point (e.g. two nearly identical rays)
    gets a huge but finite uncertainty instead of a NaN that would poison the reduced system.
    """
    a00, a10, a20, a11, a21, a22 = V[:, 0, 0], V[:, 1, 0], V[:, 2, 0], V[:, 1, 1], V[:, 2, 1], V[:, 2, 2]
    tiny = np.maximum(1e-12 * np.maximum(np.maximum(a00, a11), a22), 1e-100)
    l00 = np.sqrt(np.maximum(a00, tiny))
    l10, l20 = a10 / l00, a20 / l00
    l11 = np.sqrt(np.maximum(a11 - l10 * l10, tiny))
    l21 = (a21 - l20 * l10) / l11
    l22 = np.sqrt(np.maximum(a22 - l20 * l20 - l21 * l21, tiny))
    Li = np.zeros_like(V)
    Li[:, 0, 0], Li[:, 1, 1], Li[:, 2, 2] = 1.0 / l00, 1.0 / l11, 1.0 / l22
    Li[:, 1, 0] = -l10 / (l00 * l11)
    Li[:, 2, 1] = -l21 / (l11 * l22)
    Li[:, 2, 0] = (l10 * l21 - l11 * l20) / (l00 * l11 * l22)
    return Li


def free_columns(st: Structure) -> np.ndarray:
    """The camera-parameter columns (of 15) free in at least one active camera: every other column of every camera
    Jacobian is zero, so the products leave it out (the smallest lens model frees 8 of 15: Y Y^T ~3.5x cheaper)."""
    return np.flatnonzero(st.free.any(axis=0)) if len(st.free) else np.zeros(0, dtype=np.int64)


@dataclass(kw_only=True)
class Step:
    """A solved LM step: dc (A, 15) (zero on fixed parameters), dp (P, 3), and the model's cost decrease."""

    dc: np.ndarray
    dp: np.ndarray
    predicted_decrease: float


def _eliminate(st: Structure, lin: Linearization, lam: float, n_threads: int, reuse: bool
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points eliminated: (L^{-1} (P, 3, 3), rhs (A, 15), y blocks transposed point-major (Ma_active, 3, W),
    free columns, rc (A, k)); ``reuse``: the y blocks in the structure's kept buffer."""
    A = len(st.active_cameras)
    Li = chol3_inverse(lin.V + lam * lin.D_p[:, :, None] * np.eye(3))
    h = np.einsum("pjl,pl->pj", Li, lin.g_p)
    cols = free_columns(st)
    width = -(-len(cols) // LANES) * LANES
    out = buffer(st, "ypt", (int(st.act_starts[-1]) if A else 0, 3, width)) if reuse else None
    ypt, rc = y_blocks(lin.Jc, lin.Jp, lin.w, Li, h, cols, width, st, n_threads, out=out)
    rhs = -lin.g_c
    rhs[:, cols] += rc
    return Li, rhs, ypt, cols, rc


def reduced_system(st: Structure, lin: Linearization, lam: float, *, n_threads: int = 2, reuse: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Damped reduced camera system over ALL active-camera parameters: (S (A*15, A*15), rhs (A*15,), L^{-1}
    (P, 3, 3), y blocks transposed in point-major order (Ma_active, 3, W) over the :func:`free_columns` k, zero
    past k up to W, a multiple of :data:`dome_calib.ba.yyt.LANES`). Fixed parameters have zero rows and columns.
    ``reuse``: S and the y blocks are the structure's kept buffers (:func:`buffer`), valid until the next call."""
    A = len(st.active_cameras)
    Li, rhs, ypt, cols, _ = _eliminate(st, lin, lam, n_threads, reuse)
    S = buffer(st, "S", (A * 15, A * 15), zero=True) if reuse else np.zeros((A * 15, A * 15))
    S4 = S.reshape(A, 15, A, 15)
    if len(cols) == 15:
        subtract_yyt(S4, ypt, st, n_threads)
    elif len(cols):
        shape = (A, len(cols), A, len(cols))
        compact = buffer(st, "compact", shape, zero=True) if reuse else np.zeros(shape)
        subtract_yyt(compact, ypt, st, n_threads)
        S4[np.ix_(np.arange(A), cols, np.arange(A), cols)] = compact
        del compact
    idx = np.arange(A)
    S4[idx, :, idx, :] += lin.U + lam * lin.D_c[:, :, None] * np.eye(15)
    return S, rhs.ravel(), Li, ypt


def sparse_reduced_system(st: Structure, lin: Linearization, lam: float, layout: SparseLayout, *,
                          n_threads: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`reduced_system`, but S as the upper blocks (B, k, k) of ``layout``'s pattern over its free columns
    (:mod:`dome_calib.ba.sparse`), in the structure's kept buffers (valid until the next call)."""
    Li, rhs, ypt, cols, _ = _eliminate(st, lin, lam, n_threads, True)
    k = len(cols)
    blocks = buffer(st, "blocks", (len(layout.cols), k, k), zero=True)
    subtract_yyt_blocks(blocks, layout.row_ptr, layout.cols, ypt, st, n_threads)
    blocks[layout.diag] += (lin.U + lam * lin.D_c[:, :, None] * np.eye(15))[:, cols][:, :, cols]
    return blocks, rhs.ravel(), Li, ypt


def _cholesky_solve(S: np.ndarray, b: np.ndarray, n_threads: int, overwrite: bool = True,
                    st: Structure | None = None) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """Solve S x = b (S SPD; overwritten if ``overwrite``) by dense LAPACK Cholesky.

    Large systems first try a single-precision factor (half the work of double precision) used as the
    preconditioner of a double-precision conjugate-gradient solve on the Jacobi-scaled system, which reaches
    double-precision accuracy in a few iterations when the scaled system is not too ill-conditioned; otherwise
    (factor fails or CG stalls) the double-precision Cholesky is used. ``st``: the single-precision copy in its
    kept buffer. Returns the solution and a solver of ``S x = b'`` for other right-hand sides on the same factor
    (valid while S, the factor's memory and the kept buffers are not reused: :func:`chord_step`).
    """
    n = len(b)
    threads = n_threads if n >= _PARALLEL_CHOLESKY_MIN else 1
    if n >= _MIXED_PRECISION_MIN:
        threads32 = cholesky_threads(n, np.float32, threads)
        with blas_threads(threads32):
            solved = _mixed_precision_solve(S, b, buffer(st, "S32", S.shape, dtype=np.float32))
        if solved is not None:
            x, refined = solved

            def again_refined(rhs: np.ndarray) -> np.ndarray | None:
                with blas_threads(threads32):
                    return refined(rhs)
            return x, again_refined
    threads = cholesky_threads(n, S.dtype, threads)
    with blas_threads(threads):
        factor = scipy.linalg.cho_factor(S.T, lower=False, overwrite_a=overwrite, check_finite=False)

        def again(rhs: np.ndarray) -> np.ndarray:
            with blas_threads(threads):
                return scipy.linalg.cho_solve(factor, rhs, check_finite=False)
        return scipy.linalg.cho_solve(factor, b, check_finite=False), again


def _mixed_precision_solve(S: np.ndarray, b: np.ndarray, S32: np.ndarray, *, rtol: float = 1e-13,
                           max_iterations: int = 30
                           ) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray | None]] | None:
    diag = np.diag(S).copy()
    if np.any(diag <= 0):
        return None
    d = 1.0 / np.sqrt(diag)
    d32 = d.astype(np.float32)
    np.copyto(S32, S, casting="same_kind")
    S32 *= d32[:, None]
    S32 *= d32[None, :]
    try:
        c32, low = scipy.linalg.cho_factor(S32.T, lower=False, overwrite_a=True, check_finite=False)
    except scipy.linalg.LinAlgError:
        return None

    def precond(v: np.ndarray) -> np.ndarray:
        return scipy.linalg.cho_solve((c32, low), v.astype(np.float32), check_finite=False).astype(float)

    def matvec(v: np.ndarray) -> np.ndarray:
        return d * (S @ (d * v))

    def again(rhs: np.ndarray) -> np.ndarray | None:
        return _refined_solve(rhs, d, precond, matvec, rtol, max_iterations)
    x = _refined_solve(b, d, precond, matvec, rtol, max_iterations)
    return None if x is None else (x, again)


def _refined_solve(b: np.ndarray, d: np.ndarray, precond: Callable[[np.ndarray], np.ndarray],
                   matvec: Callable[[np.ndarray], np.ndarray], rtol: float, max_iterations: int) -> np.ndarray | None:
    """Conjugate gradients on the Jacobi-scaled system (``matvec``) preconditioned by its single-precision factor
    (``precond``): x with S x = b, or None when it does not converge."""
    bs = d * b
    b_norm = np.linalg.norm(bs)
    if b_norm == 0:
        return np.zeros_like(b)
    x = precond(bs)
    r = bs - matvec(x)
    z = precond(r)
    p = z.copy()
    rz = r @ z
    for it in range(max_iterations):
        if np.linalg.norm(r) <= rtol * b_norm:
            logger.debug("mixed-precision Cholesky + CG: %d iterations", it)
            return d * x
        q = matvec(p)
        alpha = rz / (p @ q)
        x += alpha * p
        r -= alpha * q
        z = precond(r)
        rz_new = r @ z
        p = z + (rz_new / rz) * p
        rz = rz_new
    logger.debug("mixed-precision CG did not converge (|r|/|b| = %.2g); double-precision Cholesky",
                 np.linalg.norm(r) / b_norm)
    return None


def solve_free(S: np.ndarray, rhs: np.ndarray, free_flat: np.ndarray, *, n_threads: int = 2,
               overwrite: bool = True, st: Structure | None = None, solvers: list | None = None) -> np.ndarray:
    """Solve the reduced system for the free parameters by dense Cholesky; zeros elsewhere.

    Raises numpy.linalg.LinAlgError if the system is not positive definite. ``S`` is overwritten, or with
    ``overwrite`` False only the rows and columns of fixed parameters are (set to the identity's). ``st``: the
    free block and the single-precision copy in its kept buffers. ``solvers``: the solver of the same system for other
    right-hand sides (all parameters in, the free ones out; see :func:`_cholesky_solve`) is appended to it.
    """
    n = len(rhs)
    x = np.zeros(n)
    if len(free_flat) == 0:
        return x
    full = len(free_flat) >= 0.95 * n
    if full:
        fixed = np.setdiff1d(np.arange(n), free_flat)  # few fixed: identity rows keep the matrix in place
        S[fixed, :] = 0.0
        S[:, fixed] = 0.0
        S[fixed, fixed] = 1.0
        b = rhs.copy()
        b[fixed] = 0.0
        Sf = S
    else:
        Sf = submatrix(S, free_flat, n_threads=n_threads,
                       out=buffer(st, "Sf", (len(free_flat), len(free_flat))) if st is not None else None)
        b = rhs[free_flat]
    try:
        sol, again = _cholesky_solve(Sf, b, n_threads, overwrite=overwrite or not full, st=st)
    except scipy.linalg.LinAlgError as exc:
        raise np.linalg.LinAlgError(str(exc)) from None
    x[free_flat] = sol[free_flat] if full else sol
    if solvers is not None:
        def solve_other(other: np.ndarray) -> np.ndarray | None:
            if full:
                b = other.copy()
                b[fixed] = 0.0
            else:
                b = other[free_flat]
            sol = again(b)
            if sol is None:
                return None
            out = np.zeros(n)
            out[free_flat] = sol[free_flat] if full else sol
            return out
        solvers.append(solve_other)
    return x


def point_step(st: Structure, lin: Linearization, Li: np.ndarray, ypt: np.ndarray, dc: np.ndarray) -> np.ndarray:
    """(P, 3) point update that goes with the camera update dc (A, 15) (back-substitution of the Schur
    complement; ``Li``, ``ypt`` from :func:`reduced_system`); zero for points that are not refined."""
    h = np.einsum("pjl,pl->pj", Li, lin.g_p)
    return point_step_blocks(Li, h, ypt, free_columns(st), dc, st)


@dataclass(kw_only=True)
class ReducedSystem:
    """The damped reduced camera system of one linearisation, kept so that a rejected step can be retried with
    more camera damping without eliminating the points again: S (A*15, A*15) and rhs as :func:`reduced_system`,
    built with damping ``lam`` on cameras and points; Li, ypt (the y blocks, point-major) for the back-substitution.
    On the sparse path (``layout`` set) S is None and ``blocks`` holds it (:func:`sparse_reduced_system`), and the
    inner constraints' basis is kept apart (``gauge_basis``, never added to the blocks)."""

    S: np.ndarray | None
    rhs: np.ndarray
    Li: np.ndarray
    ypt: np.ndarray
    lam: float  # the points' damping (and the cameras' as built)
    lam_cameras: float  # the cameras' damping S holds now
    blocks: np.ndarray | None = None
    layout: SparseLayout | None = None
    gauge_basis: np.ndarray | None = None
    #: the LM scaling diagonals the system was damped with (D_c, D_p) and, after :func:`solve_reduced`, the solver
    #: of its last factorisation for other right-hand sides (dense path only; :func:`chord_step`)
    D_c: np.ndarray | None = None
    D_p: np.ndarray | None = None
    solver: Callable[[np.ndarray], np.ndarray | None] | None = None


#: rows of :func:`add_outer_rows`' product at a time
OUTER_ROWS = 1024


def add_outer_rows(S: np.ndarray, B: np.ndarray, st: Structure | None) -> None:
    """S += B B^T (B (n, k), k small: the inner constraints' rank-7 term), in blocks of :data:`OUTER_ROWS` rows
    through one kept buffer of ``st``'s workspace: no (n, n) temporary, and no fresh block per call either (a
    1,024-row block of the full dome's system is 64 MB, past the largest size glibc serves from its heap, so each
    block was a new mapping whose pages the kernel faulted in and zeroed again: 8 per reduced system, 16 of 128 MB
    on a dome twice as large). The same products as ``B[i:j] @ B.T`` block by block, so the same bits."""
    n = len(S)
    rows = buffer(st, "outer_rows", (min(OUTER_ROWS, n), n))
    for i in range(0, n, OUTER_ROWS):
        block = rows[:min(OUTER_ROWS, n - i)]
        np.matmul(B[i:i + OUTER_ROWS], B.T, out=block)
        S[i:i + OUTER_ROWS] += block


def build_reduced_system(st: Structure, lin: Linearization, lam: float, *, n_threads: int = 2,
                         gauge_basis: np.ndarray | None = None) -> ReducedSystem:
    """The damped reduced system; ``gauge_basis`` (A*15, k): S += B B^T (inner constraints, see
    :func:`dome_calib.ba.gauge.inner_constraint_basis`). Sparse or dense as :func:`dome_calib.ba.sparse.sparse_layout`
    decides for the structure; its arrays are the structure's kept buffers (one system of a structure at a time)."""
    layout = sparse_layout(st, free_columns(st))
    if layout is not None:
        blocks, rhs, Li, ypt = sparse_reduced_system(st, lin, lam, layout, n_threads=n_threads)
        return ReducedSystem(S=None, rhs=rhs, Li=Li, ypt=ypt, lam=lam, lam_cameras=lam, blocks=blocks,
                             layout=layout, gauge_basis=gauge_basis)
    S, rhs, Li, ypt = reduced_system(st, lin, lam, n_threads=n_threads, reuse=True)
    if gauge_basis is not None:
        add_outer_rows(S, gauge_basis, st)
    return ReducedSystem(S=S, rhs=rhs, Li=Li, ypt=ypt, lam=lam, lam_cameras=lam, D_c=lin.D_c, D_p=lin.D_p)


def solve_reduced(st: Structure, lin: Linearization, system: ReducedSystem, lam_cameras: float, *,
                  n_threads: int = 2, keep: bool = True, keep_factor: bool = False) -> Step:
    """The step of ``system`` with the cameras damped by ``lam_cameras`` instead of ``system.lam`` (the points
    keep ``system.lam``): the exact solution of (H + Lambda) d = -g with Lambda = blockdiag(lam_cameras D_c,
    system.lam D_p), so the predicted decrease is exact for that damping. ``keep``: ``system.S`` stays usable for
    another retry (its diagonal is moved to ``lam_cameras`` in place, the factorisation works on a copy only
    where the solver needs one: no copy of the 7,800-unknown system on the mixed-precision path). ``keep_factor``
    (with ``keep``): the factorisation's solver is kept in ``system.solver`` for :func:`chord_step`."""
    A = len(st.active_cameras)
    if system.layout is not None:
        dc = np.zeros(A * 15)
        if lam_cameras != system.lam_cameras:
            cols = system.layout.free_cols
            k = np.arange(len(cols))
            system.blocks[system.layout.diag[:, None], k, k] += (lam_cameras - system.lam_cameras) * lin.D_c[:, cols]
            system.lam_cameras = lam_cameras
        f = st.free_flat
        if len(f):
            basis = system.gauge_basis[f] if system.gauge_basis is not None else None
            with blas_threads(n_threads):
                dc[f] = solve_sparse(system.layout, system.blocks, system.rhs[f], basis)
        dc = dc.reshape(A, 15)
    else:
        S = system.S
        if lam_cameras != system.lam_cameras:
            d = np.arange(A * 15)
            S[d, d] += (lam_cameras - system.lam_cameras) * lin.D_c.ravel()
            system.lam_cameras = lam_cameras
        solvers: list = []
        system.solver = None  # the old factor is gone once the system is factorised again
        dc = solve_free(S, system.rhs, st.free_flat, n_threads=n_threads, overwrite=not keep,
                        st=st, solvers=solvers if keep and keep_factor else None).reshape(A, 15)
        system.solver = solvers[0] if solvers else None
        del S
    dp = point_step(st, lin, system.Li, system.ypt, dc)
    g_dot = float(np.sum(lin.g_c * dc) + np.sum(lin.g_p * dp))
    d_dot = float(lam_cameras * np.sum(lin.D_c * dc * dc) + system.lam * np.sum(lin.D_p * dp * dp))
    return Step(dc=dc, dp=dp, predicted_decrease=0.5 * (-g_dot + d_dot))


def chord_step(st: Structure, lin: Linearization, system: ReducedSystem) -> Step | None:
    """The step of a new linearisation ``lin`` (its gradient) on an earlier one's damped system ``system`` and its
    kept factor (the chord method: the points' elimination, y blocks and camera factor of ``system``, only the
    right-hand side new), with the cost decrease that system's quadratic model predicts for it. Near a minimum the
    Hessian barely moves from one iterate to the next, so this is the next Levenberg-Marquardt step to second
    order, for a right-hand side and two triangular solves instead of a new reduced system and factorisation.
    None where ``system`` kept no factor (the sparse path, or a factor that failed)."""
    if system.solver is None or system.S is None:
        return None
    A = len(st.active_cameras)
    cols = free_columns(st)
    h = np.einsum("pjl,pl->pj", system.Li, lin.g_p)
    rhs = -lin.g_c
    if len(cols) and len(system.ypt):
        # each observation's y_i L^-1 g_p, summed per camera (y_blocks' rc, from the kept y blocks)
        points = np.repeat(np.arange(st.n_points), np.diff(st.pt_ptr))
        per_obs = np.einsum("njr,nj->nr", system.ypt[:, :, :len(cols)], h[points])
        rc = np.zeros((A, len(cols)))
        for r in range(len(cols)):
            rc[:, r] = np.bincount(st.cam_pt, weights=per_obs[:, r], minlength=A)
        rhs[:, cols] += rc
    dc = system.solver(rhs.ravel())
    if dc is None or not np.all(np.isfinite(dc)):
        return None
    dc = dc.reshape(A, 15)
    dp = point_step(st, lin, system.Li, system.ypt, dc)
    g_dot = float(np.sum(lin.g_c * dc) + np.sum(lin.g_p * dp))
    d_dot = float(system.lam_cameras * np.sum(system.D_c * dc * dc) + system.lam * np.sum(system.D_p * dp * dp))
    return Step(dc=dc, dp=dp, predicted_decrease=0.5 * (-g_dot + d_dot))


def solve_step(st: Structure, lin: Linearization, lam: float, *, n_threads: int = 2) -> Step:
    """Solve the damped normal equations (H + lam D) d = -g by the Schur complement on the points."""
    return solve_reduced(st, lin, build_reduced_system(st, lin, lam, n_threads=n_threads), lam, n_threads=n_threads,
                         keep=False)
