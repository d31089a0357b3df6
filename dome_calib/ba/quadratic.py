"""The bundle adjustment as a quadratic model at a solution: what freeing parameters would do, without solving.

At a solution of some problem (a :class:`dome_calib.ba.result.BAResult`), the Gauss-Newton normal equations over a
set of candidate camera parameters, with the points eliminated (Schur complement, :mod:`dome_calib.ba.schur`):
``S step = b``. For any subset of those parameters, one Cholesky factorisation of the matching block gives the
step the fit would take if that subset were free (``S^-1 b``) and, times the pixel noise sigma squared, the
covariance the subset would then have. :mod:`dome_calib.ba.lens_model` judges lens terms with it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np
import scipy.linalg
import scipy.linalg.blas
import scipy.sparse as sp

from dome_calib.ba.blas import blas_threads, cholesky_threads
from dome_calib.ba.evaluate import residuals, residuals_and_jacobians
from dome_calib.ba.result import BAResult
from dome_calib.ba.schur import Workspace, buffer, build_structure, free_columns, linearize, point_step, \
    reduced_system, sparse_reduced_system
from dome_calib.ba.sparse import factorise_lower, sparse_layout
from dome_calib.ba.submatrix import rectangle, submatrix, submatrix_in_place


#: the columns 0..7 of a camera (pose, fx, fy) are its core, never judged by the lens model; 8..14 its lens terms
CAMERA_PARAMS_CORE = 8


@dataclass(kw_only=True)
class _PartitionedFactor:
    """The Jacobi-scaled, damped block Ss over some parameters, ordered as [cores P, lens terms L]:
    Ss = [[A, B], [B^T, C]] with A = L_P L_P^T, V = L_P^-1 B and the Schur complement C - V^T V = L_T L_T^T; positions
    ``core_local``, ``lens_local`` in the block's own order (V: the columns ``lens_kept`` of the one over all lens
    terms). Solves as block elimination; the inverse's lens block is (L_T L_T^T)^-1."""

    core_local: np.ndarray
    lens_local: np.ndarray
    LP: np.ndarray
    V: np.ndarray  # over every lens term; the block's are its columns ``lens_kept`` (not copied)
    lens_kept: np.ndarray
    LT: np.ndarray

    def solve(self, r: np.ndarray) -> np.ndarray:
        tri = partial(scipy.linalg.solve_triangular, lower=True, check_finite=False)
        y = tri(self.LP, r[self.core_local])
        x = np.empty_like(r)
        rhs = r[self.lens_local] - (self.V.T @ y)[self.lens_kept]
        x[self.lens_local] = xl = scipy.linalg.cho_solve((self.LT, True), rhs, check_finite=False)
        spread = np.zeros(self.V.shape[1])
        spread[self.lens_kept] = xl
        x[self.core_local] = tri(self.LP, y - self.V @ spread, trans="T")
        return x

    def root_solve(self, positions: list[int], scale: np.ndarray) -> np.ndarray:
        """Z with Z^T Z = E^T Ss^-1 E, E the unit columns at ``positions`` (lens terms only) times ``scale``."""
        where = np.searchsorted(self.lens_local, positions)
        E = np.zeros((len(self.lens_local), len(positions)), order="F")
        E[where, np.arange(len(positions))] = scale
        return scipy.linalg.solve_triangular(self.LT, E, lower=True, overwrite_b=True, check_finite=False)


@dataclass(kw_only=True)
class QuadraticModel:
    """The bundle adjustment linearised at a solution, over the candidate free parameters (points eliminated):
    S (F, F) reduced normal matrix (dense, or its lower triangle as a CSC matrix where the structure takes the
    sparse path of :mod:`dome_calib.ba.sparse`), b (F,) right-hand side (S step = b), ``index`` (C, 15) position of each
    camera parameter in S or -1, ``noise_px``: pixel sigma predicted for the model with every candidate free.
    The dense S and the factors live in ``workspace`` (:class:`dome_calib.ba.schur.Workspace`): valid until the
    workspace's next solve."""

    S: np.ndarray | sp.csc_matrix
    b: np.ndarray
    index: np.ndarray
    noise_px: float
    n_threads: int = 2
    #: the last step's Cholesky factor, kept for a next step over the same parameters with the same damping (the
    #: lens model judges the principal points, then k3, over the same free set: one factorisation of the full
    #: dome's 7,808 unknowns instead of two); key: (selected positions, damping), value: (key, factor, scale)
    _factor: tuple | None = field(default=None, repr=False, compare=False)
    workspace: Workspace = field(default_factory=Workspace, repr=False, compare=False)
    #: the cores eliminated for one damping (:meth:`_core`): (damping, kept) or None
    _core_cache: tuple | None = field(default=None, repr=False, compare=False)

    @classmethod
    def at(cls, result: BAResult, candidate_free: np.ndarray, n_threads: int = 2,
           noise_floor_px: float = 0.0, workspace: Workspace | None = None) -> QuadraticModel:
        """Linearise the problem of ``result`` at its solution over the ``candidate_free`` parameters (C, 15).

        The noise sigma is the one the fit with every candidate free would leave: the residual cost after a
        Gauss-Newton or Levenberg-Marquardt step of that model (the lowest of four dampings, none first; evaluated,
        not predicted, so never below that model's optimum: an undamped step that overshoots along weak directions
        only loses to a damped one), over its degrees of freedom, and at least ``noise_floor_px``. If no step lowers
        the cost, the predicted decrease is used. The dampings are tried from the smallest and the others skipped once
        a step's noise is at most the floor (the lowest is then below it too: the same sigma). The undamped step
        first: its factor is the one :func:`dome_calib.ba.lens_model.select_lens_model`'s steps over the same parameters reuse (full dome: one
        factorisation of 7,808 unknowns a lens pass instead of two).

        ``workspace``: where the large arrays are kept (the solves' own: the Jacobians, the reduced system, compacted
        to the candidates in its own memory, and the factors reuse their pages; default a new one).
        """
        p = result.problem
        workspace = Workspace() if workspace is None else workspace
        st = build_structure(p.camera_index, p.point_index, result.inlier, candidate_free & ~result.gauge.held,
                             p.n_points, workspace)
        M = len(st.obs)
        res, Jc, Jp = residuals_and_jacobians(p.camera_params, p.points_cm, st.cam, st.pt, p.uv_px[st.obs],
                                              n_threads=n_threads,
                                              out=(buffer(st, "res", (2, M)), buffer(st, "Jc", (2, 15, M)),
                                                   buffer(st, "Jp", (2, 3, M))))
        cost = 0.5 * float(np.sum(res * res))
        lin = linearize(st, res, Jc, Jp, np.ones(len(st.obs)), n_threads=n_threads)
        del res, Jc, Jp
        f = st.free_flat
        layout = sparse_layout(st, free_columns(st))
        if layout is not None:
            blocks, b, Li, ypt = sparse_reduced_system(st, lin, 0.0, layout, n_threads=n_threads)
            S, b = layout.matrix(blocks), b[f]
            del blocks
        else:
            S, b, Li, ypt = reduced_system(st, lin, 0.0, n_threads=n_threads, reuse=True)
            S, b = submatrix_in_place(S, f), b[f]
        index = np.full((p.n_cameras, 15), -1, dtype=np.int64)
        local = np.full(len(st.active_cameras) * 15, -1, dtype=np.int64)
        local[f] = np.arange(len(f))
        index[st.active_cameras] = local.reshape(-1, 15)
        model = cls(S=S, b=b, index=index, noise_px=0.0, n_threads=n_threads, workspace=workspace)
        everything = index >= 0
        dof = max(2 * len(st.obs) - len(f) - 3 * int(st.live_points.sum()), 1)
        evaluated = []
        for damping in (0.0, 1e-6, 1e-4, 1e-2):  # undamped, then Levenberg-Marquardt: the undamped can overshoot
            step = model.step(everything, damping=damping)[0]
            dp = point_step(st, lin, Li, ypt, step[st.active_cameras])
            r = residuals(p.camera_params + step, p.points_cm + dp, st.cam, st.pt, p.uv_px[st.obs], n_threads=n_threads)
            evaluated.append(0.5 * float(np.sum(r * r)))
            if evaluated[-1] < cost and np.sqrt(2.0 * evaluated[-1] / dof) <= noise_floor_px:
                break  # the floor is the sigma whatever the other dampings give
        cost_fit = min(evaluated, default=np.inf)
        if not cost_fit < cost:  # no step lowered the cost: fall back on the predicted decrease
            cost_fit = cost - 0.5 * float(b[index[everything]] @ model.step(everything)[0][everything])
        model.noise_px = max(float(np.sqrt(max(2.0 * cost_fit, 1e-24) / dof)), noise_floor_px)
        return model

    def step(self, free: np.ndarray, columns_of: dict[int, list[int]] | None = None, *, damping: float = 0.0
             ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """Gauss-Newton step (C, 15) over the parameters marked ``free`` (C, 15) (zero elsewhere), and for each
        camera in ``columns_of`` the (k, k) block of the inverse of their normal matrix for its listed columns.
        ``damping``: Levenberg-Marquardt, times the diagonal."""
        sel = np.flatnonzero(free.ravel() & (self.index.ravel() >= 0))
        idx = self.index.ravel()[sel]
        pos = np.full(self.index.size, -1, dtype=np.int64)
        pos[sel] = np.arange(len(sel))
        key = (idx.tobytes(), float(damping))
        cols = [(c, [int(pos[c * 15 + j]) for j in js]) for c, js in (columns_of or {}).items()]
        flat = [k for _, ks in cols for k in ks]
        # the factor through the cores gives the inverse's lens blocks only: a core column's block takes the whole one
        lens_only = all(CAMERA_PARAMS_CORE <= j for js in (columns_of or {}).values() for j in js)
        with blas_threads(self.n_threads):
            if (self._factor is not None and self._factor[0] == key
                    and (lens_only or not isinstance(self._factor[1], _PartitionedFactor))):
                _, factor, d = self._factor  # the same matrix as the last step's: its factor, bit for bit
            else:
                self._factor = None  # the old factor's memory goes before the new one is made
                factor, d = (self._partitioned(idx, damping) if lens_only else None) or self._factorise(idx, damping)
                self._factor = (key, factor, d)
            if isinstance(factor, _PartitionedFactor):
                x = factor.solve(self.b[idx] / d) / d
            else:
                x = (factor(self.b[idx] / d) if self.sparse
                     else scipy.linalg.cho_solve(factor, self.b[idx] / d, check_finite=False)) / d
            blocks = {}
            if columns_of:
                # the blocks of S^-1 = (D Ss D)^-1 are those of E^T Ss^-1 E with E the columns' unit vectors / d;
                # with Ss = R^T R (cho_factor's upper R), E^T Ss^-1 E = Z^T Z for Z = R^-T E: one triangular solve
                # (half of cho_solve's two; the full dome's 2,600 distortion columns: 4.6 -> 2.3 s per lens pass)
                if isinstance(factor, _PartitionedFactor):
                    Z = factor.root_solve(flat, 1.0 / d[flat])
                else:
                    # Fortran-ordered (the transpose of a kept buffer): the triangular solve overwrites it, no copy
                    E = (np.zeros((len(d), len(flat))) if self.sparse
                         else self.workspace.array("E", (len(flat), len(d)), zero=True).T)
                    E[flat, np.arange(len(flat))] = 1.0 / d[flat]
                    if self.sparse:  # CHOLMOD: S[p, p] = L L^T, so Z = L^-1 P E
                        Z = factor.solve_L(factor.apply_P(E), use_LDLt_decomposition=False)
                    else:
                        R, lower = factor
                        Z = scipy.linalg.solve_triangular(R, E, trans="N" if lower else "T", lower=lower,
                                                          overwrite_b=True, check_finite=False)
                start = 0
                for c, ks in cols:
                    Zc = Z[:, start:start + len(ks)]
                    blocks[c] = Zc.T @ Zc
                    start += len(ks)
        full = np.zeros(self.index.size)
        full[sel] = x
        return full.reshape(self.index.shape), blocks

    @property
    def sparse(self) -> bool:
        """Whether S is held sparse (its lower triangle) and factorised by CHOLMOD."""
        return sp.issparse(self.S)

    def _core(self, damping: float) -> tuple | None:
        """The camera cores (pose, fx, fy: never judged) eliminated from the whole Jacobi-scaled, damped system, kept
        per damping: (core positions, lens positions, the cores' Cholesky factor L_P (lower), V = L_P^-1 S_PL,
        the lenses' Schur complement T = S_LL - V^T V, its upper triangle), or None when the cores' block is not
        positive definite."""
        if self._core_cache is not None and self._core_cache[0] == damping:
            return self._core_cache[1]
        self._core_cache = None
        kind = np.arange(self.index.size).reshape(self.index.shape) % 15
        flat = self.index.ravel()
        core = np.sort(flat[(flat >= 0) & (kind.ravel() < CAMERA_PARAMS_CORE)])
        lens = np.sort(flat[(flat >= 0) & (kind.ravel() >= CAMERA_PARAMS_CORE)])
        d = np.sqrt(np.maximum(self.S.diagonal(), 1e-300))
        ws = self.workspace
        A = submatrix(self.S, core, n_threads=self.n_threads, out=ws.array("core", (len(core), len(core))))
        A /= d[core][:, None]
        A /= d[core][None, :]
        A[np.diag_indices_from(A)] += damping
        try:  # A's transpose: Fortran-ordered, factorised in place (its lower triangle is A's upper one)
            with blas_threads(cholesky_threads(len(core), A.dtype, self.n_threads)):
                LP = scipy.linalg.cholesky(A.T, lower=True, overwrite_a=True, check_finite=False)
        except scipy.linalg.LinAlgError:
            return None
        # S_PL as the transpose of S_LP gathered by rows (S is symmetric): Fortran-ordered, solved in place
        B = rectangle(self.S, lens, core, out=ws.array("lens_core", (len(lens), len(core))), n_threads=self.n_threads).T
        B /= d[core][:, None]
        B /= d[lens][None, :]
        V = scipy.linalg.solve_triangular(LP, B, lower=True, overwrite_b=True, check_finite=False)
        T = submatrix(self.S, lens, n_threads=self.n_threads, out=ws.array("lens", (len(lens), len(lens))))
        T /= d[lens][:, None]
        T /= d[lens][None, :]
        T[np.diag_indices_from(T)] += damping
        # T -= V^T V on T's upper triangle, in place (BLAS syrk on T's transpose, Fortran-ordered, lower: half a
        # product's work, no temporary); T's lower triangle is left as it was, and never read (the factorisations
        # below read the upper triangle of T's blocks)
        scipy.linalg.blas.dsyrk(-1.0, V, beta=1.0, c=T.T, trans=1, lower=1, overwrite_c=1)
        self._core_cache = (damping, (core, lens, LP, V, T))
        return self._core_cache[1]

    def _partitioned(self, idx: np.ndarray, damping: float) -> tuple[_PartitionedFactor, np.ndarray] | None:
        """The factor of the block over ``idx`` through the kept elimination of the cores (:meth:`_core`): only the
        selected lens terms' block of T is factorised (the full dome: at most 3,640 unknowns, not 7,815, for each
        of the walk's free sets). None when ``idx`` leaves out a core (or on the sparse path): the whole block then."""
        if self.sparse or len(idx) == 0:
            return None
        kept = self._core(damping)
        if kept is None:
            return None
        core, lens, LP, V, T = kept
        core_local = np.searchsorted(idx, core)
        if len(core) > len(idx) or not np.array_equal(idx[np.minimum(core_local, len(idx) - 1)], core):
            return None
        lens_local = np.setdiff1d(np.arange(len(idx)), core_local, assume_unique=True)
        ls = np.searchsorted(lens, idx[lens_local])
        for ridge in (0.0, 1e-12, 1e-9, 1e-6):  # a tiny ridge if some direction is not observable at all
            Ts = T[np.ix_(ls, ls)]
            Ts[np.diag_indices_from(Ts)] += ridge
            try:  # Ts's transpose, Fortran-ordered: factorised in place
                LT = scipy.linalg.cholesky(Ts.T, lower=True, overwrite_a=True, check_finite=False)
                break
            except scipy.linalg.LinAlgError:
                if ridge == 1e-6:
                    raise
        d = np.sqrt(np.maximum(self.S.diagonal()[idx], 1e-300))
        return _PartitionedFactor(core_local=core_local, lens_local=lens_local, LP=LP, V=V, lens_kept=ls, LT=LT), d

    def _factorise(self, idx: np.ndarray, damping: float) -> tuple[object, np.ndarray]:
        """Cholesky factor of the Jacobi-scaled, damped block of S over ``idx``, and the scale d."""
        d = np.sqrt(np.maximum(self.S.diagonal()[idx], 1e-300))
        if self.sparse:
            sub = self.S[idx][:, idx].tocsc()  # idx ascending: the lower triangle of the block
            sub.data *= (1.0 / d)[sub.indices] * np.repeat(1.0 / d, np.diff(sub.indptr))
            return factorise_lower(sub, damping, ridges=(0.0, 1e-12, 1e-9, 1e-6)), d
        for ridge in (0.0, 1e-12, 1e-9, 1e-6):  # a tiny ridge if some direction is not observable at all
            Ss = submatrix(self.S, idx, n_threads=self.n_threads, out=self.workspace.array("Sf", (len(idx), len(idx))))
            Ss /= d[:, None]
            Ss /= d[None, :]  # Jacobi scaling: lens and pose columns differ by many decades
            Ss[np.diag_indices_from(Ss)] += damping + ridge
            # factorised in place: Ss's transpose is the Fortran-ordered matrix LAPACK takes without a copy, and its
            # lower triangle is Ss's upper one, the triangle a factorisation of Ss itself reads
            try:
                with blas_threads(cholesky_threads(len(idx), Ss.dtype, self.n_threads)):
                    return scipy.linalg.cho_factor(Ss.T, lower=True, overwrite_a=True, check_finite=False), d
            except scipy.linalg.LinAlgError:
                if ridge == 1e-6:
                    raise
        raise AssertionError("unreachable")
