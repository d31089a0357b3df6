"""Camera parameter uncertainties from the reduced camera system at the solution.

With points eliminated, the covariance of the free camera parameters is ``sigma^2 S^{-1}`` where S is the
undamped reduced camera system (least-squares weights) and sigma the estimated pixel noise. S^{-1} is
computed from its Cholesky factor (LAPACK potri). Camera centres ``c = -R^T t`` are propagated with their
analytic Jacobian. The covariance is in the gauge of the solve (reference camera pose and one translation
component held, see :mod:`dome_calib.ba.gauge`); for centres it is also transformed (an S-transformation,
projection along the 7 similarity directions) to the gauge that fixes the centroid, mean orientation and
mean radius of the camera centres, which is what the normalisation to the world frame does.
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.linalg
from scipy.linalg import lapack

from dome_calib.ba.blas import blas_threads, cholesky_threads
from dome_calib.ba.evaluate import residuals_and_jacobians
from dome_calib.ba.gauge import Gauge, GaugeMode
from dome_calib.ba.problem import ROT, TRANS, BAProblem
from dome_calib.ba.result import CameraUncertainty
from dome_calib.ba.schur import Structure, buffer, linearize, reduced_system
from dome_calib.ba.submatrix import submatrix_in_place
from dome_calib.rotation import d_rotate_d_rotvec, rotvec_to_matrix, skew

logger = logging.getLogger(__name__)


def center_jacobian(camera_params: np.ndarray) -> np.ndarray:
    """(C, 3, 6) derivative of the camera centre c = -R(r)^T t (cm) with respect to [r, t]."""
    r, t = camera_params[:, ROT], camera_params[:, TRANS]
    Rt = np.swapaxes(rotvec_to_matrix(r), 1, 2)
    J = np.empty((len(r), 3, 6))
    J[:, :, 0:3] = d_rotate_d_rotvec(-r, Rt, t)  # c = -R(-r) t, d(-r)/dr = -1
    J[:, :, 3:6] = -Rt
    return J


def _similarity_directions(centers_cm: np.ndarray) -> np.ndarray:
    """(3C, 7) infinitesimal motions of camera centres under rotation, translation and scale."""
    c = centers_cm - centers_cm.mean(axis=0)
    C = len(c)
    G = np.zeros((C, 3, 7))
    G[:, :, 0:3] = -skew(c)  # omega x c
    G[:, :, 3:6] = np.eye(3)
    G[:, :, 6] = c
    return G.reshape(3 * C, 7)


def _symmetric_block(upper: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The block ``X[np.ix_(idx, idx)]`` of a symmetric X of which ``upper`` holds the upper triangle (``idx``
    ascending), mirrored in place a band of rows at a time (no full-size temporaries: the full dome's pose block is
    3,120 x 3,120)."""
    sub = upper[np.ix_(idx, idx)]
    k = len(idx)
    for i in range(0, k, 256):
        j = min(i + 256, k)
        diagonal = sub[i:j, i:j]
        diagonal[...] = np.triu(diagonal) + np.triu(diagonal, 1).T
        sub[j:, i:j] = sub[i:j, j:].T
    return sub


def camera_uncertainty(problem: BAProblem, st: Structure, sigma_px: float, *, gauge: Gauge,
                       n_threads: int = 2) -> CameraUncertainty:
    """Standard deviations of camera parameters (see :class:`dome_calib.ba.result.CameraUncertainty`)."""
    C, A = problem.n_cameras, len(st.active_cameras)
    M = len(st.obs)  # the large arrays in the structure's workspace (dome_calib.ba.schur.Workspace)
    res, Jc, Jp = residuals_and_jacobians(problem.camera_params, problem.points_cm, st.cam, st.pt,
                                          problem.uv_px[st.obs], n_threads=n_threads,
                                          out=(buffer(st, "res", (2, M)), buffer(st, "Jc", (2, 15, M)),
                                               buffer(st, "Jp", (2, 3, M))))
    lin = linearize(st, res, Jc, Jp, np.ones(M), n_threads=n_threads)
    del res, Jc, Jp
    f = st.free_flat

    def free_system() -> np.ndarray:
        S, _, _, _ = reduced_system(st, lin, 0.0, n_threads=n_threads, reuse=True)
        return submatrix_in_place(S, f) if len(f) < A * 15 else S  # the free block in S's own memory

    Sf = free_system()
    with blas_threads(cholesky_threads(len(f), np.float64, n_threads)):  # past the bound OpenBLAS's threads overrun
        for ridge in (0.0, 1e-12, 1e-9, 1e-6):  # a tiny ridge if some parameter is unobservable
            try:
                if ridge:  # the failed factorisation overwrote the system: built again (a rare path)
                    Sf = free_system()
                    Sf[np.diag_indices_from(Sf)] *= 1.0 + ridge
                # factorised in place: Sf is symmetric, so its transpose is the Fortran-ordered matrix LAPACK takes
                # without a copy (the inverse then overwrites the factor)
                c, _ = scipy.linalg.cho_factor(Sf.T, lower=False, overwrite_a=True, check_finite=False)
                break
            except scipy.linalg.LinAlgError:
                if ridge == 1e-6:
                    raise
                logger.warning("uncertainty: reduced system singular; adding a ridge of %.0e x diagonal",
                               ridge or 1e-12)
        del lin
        inv, info = lapack.dpotri(c, lower=0, overwrite_c=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotri failed (info {info})")
    # inv's upper triangle holds the inverse (the lower one is left over): only the blocks used are read from it
    sigma2 = sigma_px ** 2
    pos = np.full(A * 15, -1, dtype=np.int64)
    pos[f] = np.arange(len(f))
    pos = pos.reshape(A, 15)
    blocks = np.zeros((C, 15, 15))
    for a, cam in enumerate(st.active_cameras):
        k = np.flatnonzero(pos[a] >= 0)
        blocks[cam][np.ix_(k, k)] = sigma2 * _symmetric_block(inv, pos[a, k])
    var = np.einsum("cii->ci", blocks)
    Jcen = center_jacobian(problem.camera_params)
    cov_c = Jcen @ blocks[:, 0:6, 0:6] @ np.swapaxes(Jcen, 1, 2)
    centroid = None
    pose_free = st.free[:, 0:6] | gauge.held[st.active_cameras, 0:6]
    if gauge.mode is not GaugeMode.USER and A == C and pose_free.all():
        sel = pos[:, 0:6]  # (C, 6) indices into inv, -1 where held
        ok = sel >= 0
        sub = _symmetric_block(inv, sel[ok])
        sub *= sigma2
        if ok.all():  # every pose parameter free (the inner constraints' case): the block as it is
            cov_pose = sub.reshape(C, 6, C, 6)
        else:
            cov_pose = np.zeros((C, 6, C, 6))
            ia, ja = np.nonzero(ok)
            cov_pose[ia[:, None], ja[:, None], ia[None, :], ja[None, :]] = sub
        cov_all = np.einsum("aij,ajbk,blk->aibl", Jcen, cov_pose, Jcen).reshape(3 * C, 3 * C)
        R = rotvec_to_matrix(problem.camera_params[:, ROT])
        centers = -np.einsum("cji,cj->ci", R, problem.camera_params[:, TRANS])
        G = _similarity_directions(centers)
        Pm = np.eye(3 * C) - G @ np.linalg.pinv(G)
        cov_in = Pm @ cov_all @ Pm.T
        centroid = np.sqrt(np.maximum(np.diag(cov_in), 0.0)).reshape(C, 3)
    return CameraUncertainty(
        sigma_intr_px=np.sqrt(np.maximum(var[:, 6:10], 0.0)), sigma_dist=np.sqrt(np.maximum(var[:, 10:15], 0.0)),
        sigma_rot_deg=np.degrees(np.sqrt(np.maximum(var[:, 0:3], 0.0))),
        sigma_center_cm=np.sqrt(np.maximum(np.einsum("cii->ci", cov_c), 0.0)), sigma_center_centroid_cm=centroid)
