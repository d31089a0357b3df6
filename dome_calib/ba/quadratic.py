"""The bundle adjustment as a quadratic model at a solution: what freeing parameters would do, without solving.

At a solution of some problem (a :class:`dome_calib.ba.result.BAResult`), the Gauss-Newton normal equations over a
set of candidate camera parameters, with the points eliminated (Schur complement, :mod:`dome_calib.ba.schur`):
``S step = b``. For any subset of those parameters, one Cholesky factorisation of the matching block gives the
step the fit would take if that subset were free (``S^-1 b``) and, times the pixel noise sigma squared, the
covariance the subset would then have. :mod:`dome_calib.ba.lens_model` judges lens terms with it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from dome_calib.ba.blas import blas_threads
from dome_calib.ba.evaluate import residuals, residuals_and_jacobians
from dome_calib.ba.result import BAResult
from dome_calib.ba.schur import Workspace, buffer, build_structure, free_columns, linearize, point_step, reduced_system, \
    sparse_reduced_system
from dome_calib.ba.sparse import factorise_lower, sparse_layout
from dome_calib.ba.submatrix import submatrix, submatrix_in_place


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
        with blas_threads(self.n_threads):
            if self._factor is not None and self._factor[0] == key:
                _, factor, d = self._factor  # the same matrix as the last step's: its factor, bit for bit
            else:
                self._factor = None  # the old factor's memory goes before the new one is made
                factor, d = self._factorise(idx, damping)
                self._factor = (key, factor, d)
            x = (factor(self.b[idx] / d) if self.sparse
                 else scipy.linalg.cho_solve(factor, self.b[idx] / d, check_finite=False)) / d
            blocks = {}
            if columns_of:
                cols = [(c, [int(pos[c * 15 + j]) for j in js]) for c, js in columns_of.items()]
                flat = [k for _, ks in cols for k in ks]
                # the blocks of S^-1 = (D Ss D)^-1 are those of E^T Ss^-1 E with E the columns' unit vectors / d;
                # with Ss = R^T R (cho_factor's upper R), E^T Ss^-1 E = Z^T Z for Z = R^-T E: one triangular solve
                # (half of cho_solve's two; the full dome's 2,600 distortion columns: 4.6 -> 2.3 s per lens pass)
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
                return scipy.linalg.cho_factor(Ss.T, lower=True, overwrite_a=True, check_finite=False), d
            except scipy.linalg.LinAlgError:
                if ridge == 1e-6:
                    raise
        raise AssertionError("unreachable")
