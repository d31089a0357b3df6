"""Residuals and Jacobians of all observations at once (vectorised over observations, no Python loops).

Residual of observation i: ``r_i = project(camera cam_i, point pt_i) - uv_i`` (px, OpenCV convention).

With ``n_threads`` > 1 and many observations, contiguous slices of the observations are evaluated in threads
(numpy's elementwise kernels release the GIL; every observation is computed alone, so the result is
bit-identical to one thread's).
"""
from __future__ import annotations

import numpy as np

from dome_calib.ba.problem import DIST, INTR, ROT, TRANS
from dome_calib.ba.threads import run_in_threads
from dome_calib.camera import MIN_DEPTH, distort
from dome_calib.rotation import right_jacobian, rotvec_to_matrix


def project_observations(camera_params: np.ndarray, points_cm: np.ndarray, cam: np.ndarray, pt: np.ndarray
                         ) -> np.ndarray:
    """(M, 2) predicted pixels of observations (camera index ``cam``, point index ``pt``); NaN behind a camera."""
    R = rotvec_to_matrix(camera_params[:, ROT])
    X = np.einsum("mij,mj->mi", R[cam], points_cm[pt]) + camera_params[cam, TRANS]
    z = X[:, 2]
    z = np.where(z > MIN_DEPTH, z, np.nan)
    xn = X[:, :2] / z[:, None]
    p = camera_params[cam]
    return distort(xn, p[:, DIST]) * p[:, 6:8] + p[:, 8:10]


#: observations from which the evaluation is split across threads (below, the threads' overhead is not repaid)
THREADED_MIN_OBSERVATIONS = 100_000
#: observations evaluated at a time: each of the ~70 elementwise temporaries is then 64 kB, served from the heap and
#: reused chunk after chunk, where one slice per thread made each of them M / 2 doubles (4 MB on the full dome,
#: 8 MB at twice its size) that glibc mapped afresh and gave back to the kernel on every call (55 k page faults per
#: Jacobian evaluation on the full dome)
CHUNK_OBSERVATIONS = 8192


def _slices(M: int) -> list[slice]:
    """Contiguous slices of at most :data:`CHUNK_OBSERVATIONS` observations, the jobs the threads take in turn (as
    many whatever the thread count)."""
    cuts = np.arange(0, M + CHUNK_OBSERVATIONS, CHUNK_OBSERVATIONS).clip(max=M)
    return [slice(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def _threads(M: int, n_threads: int) -> int:
    """Threads for M observations: ``n_threads`` from :data:`THREADED_MIN_OBSERVATIONS`, one below."""
    return n_threads if M >= THREADED_MIN_OBSERVATIONS else 1


def residuals(camera_params: np.ndarray, points_cm: np.ndarray, cam: np.ndarray, pt: np.ndarray,
              uv_px: np.ndarray, *, n_threads: int = 1) -> np.ndarray:
    """(M, 2) reprojection residuals in px, the solver's sign: projected - observed (reports use observed - projected,
    :mod:`dome_calib.residuals`)."""
    out = np.empty((len(cam), 2))

    def job(sl: slice) -> None:
        out[sl] = project_observations(camera_params, points_cm, cam[sl], pt[sl]) - uv_px[sl]

    run_in_threads(job, _slices(len(cam)), _threads(len(cam), n_threads))
    return out


def residuals_and_jacobians(camera_params: np.ndarray, points_cm: np.ndarray, cam: np.ndarray, pt: np.ndarray,
                            uv_px: np.ndarray, *, n_threads: int = 1,
                            out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals, camera and point Jacobians of M observations, component-major for speed (into ``out``, arrays
    of the three shapes below, when given: every element is written).

    Returns:
        res (2, M) px (predicted - observed); Jc (2, 15, M) d res / d camera parameters (columns as
        :data:`dome_calib.ba.problem.CAMERA_PARAMS`); Jp (2, 3, M) d res / d point. NaN behind a camera.
    The rotation columns are with respect to the rotation vector (additive update r + dr): the same quantities
    as :func:`dome_calib.camera.project_with_jacobians` (tested equal), computed with per-camera factors and
    contiguous elementwise arithmetic (~10x faster at a million observations), using
    d(R X)/dr = -[R X]_x (R J_r(r)).
    """
    rv = camera_params[:, ROT]
    R = rotvec_to_matrix(rv)
    B = R @ right_jacobian(rv)  # (C, 3, 3) per camera
    M = len(cam)
    res, Jc, Jp = out if out is not None else (np.empty((2, M)), np.empty((2, 15, M)), np.empty((2, 3, M)))

    def job(sl: slice) -> None:
        _residuals_and_jacobians_into(camera_params, points_cm, cam[sl], pt[sl], uv_px[sl], R, B, res[:, sl],
                                      Jc[:, :, sl], Jp[:, :, sl])

    run_in_threads(job, _slices(M), _threads(M, n_threads))
    return res, Jc, Jp


def _residuals_and_jacobians_into(camera_params: np.ndarray, points_cm: np.ndarray, cam: np.ndarray, pt: np.ndarray,
                                  uv_px: np.ndarray, R: np.ndarray, B: np.ndarray, res: np.ndarray, Jc: np.ndarray,
                                  Jp: np.ndarray) -> None:
    Rg = [[np.ascontiguousarray(R[:, i, j])[cam] for j in range(3)] for i in range(3)]
    Bg = [[np.ascontiguousarray(B[:, i, j])[cam] for j in range(3)] for i in range(3)]
    Xw = [np.ascontiguousarray(points_cm[:, j])[pt] for j in range(3)]
    pc = [np.ascontiguousarray(camera_params[:, k])[cam] for k in range(15)]
    Xr = [Rg[i][0] * Xw[0] + Rg[i][1] * Xw[1] + Rg[i][2] * Xw[2] for i in range(3)]
    z = Xr[2] + pc[5]
    iz = 1.0 / np.where(z > MIN_DEPTH, z, np.nan)
    x, y = (Xr[0] + pc[3]) * iz, (Xr[1] + pc[4]) * iz
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = pc[6:15]
    r2 = x * x + y * y
    r4 = r2 * r2
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    d_radial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    j00 = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
    j01 = xy2 * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    j11 = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
    res[0] = fx * xd + cx - uv_px[:, 0]
    res[1] = fy * yd + cy - uv_px[:, 1]
    fiz, giz = fx * iz, fy * iz
    Jt = Jc[:, 3:6]  # d res / d t = d res / d X_cam
    Jt[0, 0], Jt[0, 1], Jt[0, 2] = fiz * j00, fiz * j01, -fiz * (j00 * x + j01 * y)
    Jt[1, 0], Jt[1, 1], Jt[1, 2] = giz * j01, giz * j11, -giz * (j01 * x + j11 * y)
    for k in range(2):
        a = Jt[k]
        q = (Xr[1] * a[2] - Xr[2] * a[1], Xr[2] * a[0] - Xr[0] * a[2], Xr[0] * a[1] - Xr[1] * a[0])  # X_r x a
        for j in range(3):
            Jp[k, j] = a[0] * Rg[0][j] + a[1] * Rg[1][j] + a[2] * Rg[2][j]
            Jc[k, j] = q[0] * Bg[0][j] + q[1] * Bg[1][j] + q[2] * Bg[2][j]
    Jc[0, 6], Jc[1, 6], Jc[0, 7], Jc[1, 7] = xd, 0.0, 0.0, yd
    Jc[0, 8], Jc[1, 8], Jc[0, 9], Jc[1, 9] = 1.0, 0.0, 0.0, 1.0
    Jc[0, 10], Jc[1, 10] = fx * x * r2, fy * y * r2
    Jc[0, 11], Jc[1, 11] = fx * x * r4, fy * y * r4
    Jc[0, 12], Jc[1, 12] = fx * xy2, fy * (r2 + 2.0 * y * y)
    Jc[0, 13], Jc[1, 13] = fx * (r2 + 2.0 * x * x), fy * xy2
    Jc[0, 14], Jc[1, 14] = fx * x * r4 * r2, fy * y * r4 * r2
