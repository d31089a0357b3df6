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

from dome_calib.ba.blas import blas_threads
from dome_calib.ba.evaluate import residuals_and_jacobians
from dome_calib.ba.gauge import Gauge, GaugeMode
from dome_calib.ba.problem import ROT, TRANS, BAProblem
from dome_calib.ba.result import CameraUncertainty
from dome_calib.ba.schur import Structure, linearize, reduced_system
from dome_calib.ba.submatrix import submatrix
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


def camera_uncertainty(problem: BAProblem, st: Structure, sigma_px: float, *, gauge: Gauge,
                       n_threads: int = 2) -> CameraUncertainty:
    """Standard deviations of camera parameters (see :class:`dome_calib.ba.result.CameraUncertainty`)."""
    C, A = problem.n_cameras, len(st.active_cameras)
    res, Jc, Jp = residuals_and_jacobians(problem.camera_params, problem.points_cm, st.cam, st.pt,
                                          problem.uv_px[st.obs], n_threads=n_threads)
    lin = linearize(st, res, Jc, Jp, np.ones(len(st.obs)), n_threads=n_threads)
    del res, Jc, Jp
    S, _, _, _ = reduced_system(st, lin, 0.0, n_threads=n_threads)
    del lin
    f = st.free_flat
    Sf = submatrix(S, f, n_threads=n_threads) if len(f) < A * 15 else S
    del S
    diag = np.diag(Sf).copy()
    with blas_threads(n_threads):
        for ridge in (0.0, 1e-12, 1e-9, 1e-6):  # a tiny ridge if some parameter is unobservable
            try:
                c, _ = scipy.linalg.cho_factor(Sf + ridge * np.diag(diag) if ridge else Sf, lower=False,
                                               overwrite_a=not ridge, check_finite=False)
                break
            except scipy.linalg.LinAlgError:
                if ridge == 1e-6:
                    raise
                logger.warning("uncertainty: reduced system singular; adding a ridge of %.0e x diagonal",
                               ridge or 1e-12)
        inv, info = lapack.dpotri(c, lower=0, overwrite_c=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotri failed (info {info})")
    inv = np.triu(inv) + np.triu(inv, 1).T
    inv *= sigma_px ** 2
    pos = np.full(A * 15, -1, dtype=np.int64)
    pos[f] = np.arange(len(f))
    pos = pos.reshape(A, 15)
    blocks = np.zeros((C, 15, 15))
    for a, cam in enumerate(st.active_cameras):
        k = np.flatnonzero(pos[a] >= 0)
        blocks[cam][np.ix_(k, k)] = inv[np.ix_(pos[a, k], pos[a, k])]
    var = np.einsum("cii->ci", blocks)
    Jcen = center_jacobian(problem.camera_params)
    cov_c = Jcen @ blocks[:, 0:6, 0:6] @ np.swapaxes(Jcen, 1, 2)
    centroid = None
    pose_free = st.free[:, 0:6] | gauge.held[st.active_cameras, 0:6]
    if gauge.mode is not GaugeMode.USER and A == C and pose_free.all():
        sel = pos[:, 0:6]  # (C, 6) indices into inv, -1 where held
        cov_pose = np.zeros((C, 6, C, 6))
        ok = sel >= 0
        ia, ja = np.nonzero(ok)
        sub = inv[np.ix_(sel[ok], sel[ok])]
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
