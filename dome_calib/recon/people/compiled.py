"""The people stage's compiled (numba) loops: the association's projection of every proposal into every view
(:func:`project_into_views`); the body over time's reading of its detections (:func:`assigned_records`), each
detection's robust reprojection term summed into its joint's Gauss-Newton block (:func:`robust_blocks`), and each
detection's offset from the fitted joint (:func:`residuals_px`, :func:`distances_px`).

numpy did these in tens of passes over the points with a temporary per pass; these loops do one pass (the body over
time's terms: 60 ns a detection against 315 ns). The camera model is :mod:`dome_calib.camera`'s (OpenCV pinhole, 5
distortion terms; a point behind the camera or outside the lens's valid radius has no projection), in float64. Every
sum runs over the detections in the order given, in one thread: the result does not depend on the machine's
threads.
"""
from __future__ import annotations

import numpy as np

from dome_calib import ties
from dome_calib.camera import MIN_DEPTH
from dome_calib.jit import njit

#: Confidence keys of :func:`_fill_records` per unit of confidence: steps of :data:`dome_calib.ties.CONFIDENCE_QUANTUM`
#: (a numba kernel cannot call ties; multiplying by this exact whole number keeps the keys it always made).
_STEPS_PER_CONFIDENCE = float(round(1.0 / ties.CONFIDENCE_QUANTUM))


@njit(nogil=True, boundscheck=False)
def _project(cam, v, X0, X1, X2, jacobian, J):  # pragma: no cover - compiled
    """Pixel (u, v) of a world point in view v, and (if ``jacobian``) d(u, v)/dX into J (2, 3); ok False behind the
    camera or outside the lens."""
    xc = cam[v, 0] * X0 + cam[v, 1] * X1 + cam[v, 2] * X2 + cam[v, 9]
    yc = cam[v, 3] * X0 + cam[v, 4] * X1 + cam[v, 5] * X2 + cam[v, 10]
    zc = cam[v, 6] * X0 + cam[v, 7] * X1 + cam[v, 8] * X2 + cam[v, 11]
    if not zc > MIN_DEPTH:
        return False, 0.0, 0.0
    x = xc / zc
    y = yc / zc
    fx, fy, cx, cy = cam[v, 12], cam[v, 13], cam[v, 14], cam[v, 15]
    k1, k2, p1, p2, k3 = cam[v, 16], cam[v, 17], cam[v, 18], cam[v, 19], cam[v, 20]
    xx, yy, xy = x * x, y * y, x * y
    r2 = xx + yy
    if r2 > cam[v, 21]:
        return False, 0.0, 0.0
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx)
    yd = y * radial + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy
    if jacobian:
        two_dr = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))
        b = xy * two_dr + 2.0 * p1 * x + 2.0 * p2 * y
        a = radial + xx * two_dr + 2.0 * p1 * y + 6.0 * p2 * x
        d = radial + yy * two_dr + 6.0 * p1 * y + 2.0 * p2 * x
        su = fx / zc
        sv = fy / zc
        eu = -(a * x + b * y)
        ev = -(b * x + d * y)
        for k in range(3):
            J[0, k] = su * (a * cam[v, k] + b * cam[v, 3 + k] + eu * cam[v, 6 + k])
            J[1, k] = sv * (b * cam[v, k] + d * cam[v, 3 + k] + ev * cam[v, 6 + k])
    return True, xd * fx + cx, yd * fy + cy


@njit(nogil=True, boundscheck=False)
def _robust_blocks(P, var, view, uv_px, conf, sigma_v, use, cam, robust_k, H, g):  # pragma: no cover - compiled
    J = np.empty((2, 3))
    for m in range(len(var)):
        i = var[m]
        if i < 0 or not use[m]:
            continue
        ok, u, w = _project(cam, view[m], P[i, 0], P[i, 1], P[i, 2], True, J)
        if not ok:
            continue
        ru = u - uv_px[m, 0]
        rv = w - uv_px[m, 1]
        s = sigma_v[view[m]]
        ks = robust_k * s
        q = 1.0 + (ru * ru + rv * rv) / (ks * ks)
        weight = conf[m] / (q * q) / (s * s)
        for a in range(3):
            g[i, a] += weight * (J[0, a] * ru + J[1, a] * rv)
            for b in range(a, 3):
                H[i, a, b] += weight * (J[0, a] * J[0, b] + J[1, a] * J[1, b])
    for i in range(len(H)):
        for a in range(3):
            for b in range(a + 1, 3):
                H[i, b, a] = H[i, a, b]


def robust_blocks(P: np.ndarray, var: np.ndarray, view: np.ndarray, uv_px: np.ndarray, conf: np.ndarray,
                  sigma_v: np.ndarray, cam: np.ndarray, robust_k: float, use: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton blocks of M detections at the points P (n, 3) world cm: H (n, 3, 3) = sum w J^T J and
    g (n, 3) = sum w J^T r, with the Geman-McClure weight ``w = c / (1 + (r / k sigma)^2)^2 / sigma^2`` (none behind
    the camera or outside the lens); var (M,) point of each detection (-1: none), view (M,) its row of ``cam``
    (:func:`~dome_calib.recon.kernel.camera_table`), uv_px (M, 2), conf (M,); sigma_v (V,) each camera's noise;
    use (M,) the detections taken (default all)."""
    H = np.zeros((len(P), 3, 3))
    g = np.zeros((len(P), 3))
    use = np.ones(len(var), bool) if use is None else use
    _robust_blocks(np.ascontiguousarray(P, dtype=np.float64), _ints(var), _ints(view), _pixels(uv_px),
                   np.asarray(conf, dtype=np.float32), np.asarray(sigma_v, dtype=np.float64), use, cam,
                   float(robust_k), H, g)
    return H, g


@njit(nogil=True, boundscheck=False)
def _residuals(P, var, view, uv_px, cam, out):  # pragma: no cover - compiled
    J = np.empty((2, 3))
    for m in range(len(var)):
        i = var[m]
        ok = False
        if i >= 0:
            ok, u, w = _project(cam, view[m], P[i, 0], P[i, 1], P[i, 2], False, J)
        out[m, 0] = uv_px[m, 0] - u if ok else np.nan
        out[m, 1] = uv_px[m, 1] - w if ok else np.nan


def residuals_px(P: np.ndarray, var: np.ndarray, view: np.ndarray, uv_px: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """(M, 2) each detection minus its point's projection (px; NaN: no point (var -1), behind the camera or outside
    the lens)."""
    out = np.empty((len(var), 2))
    _residuals(np.ascontiguousarray(P, dtype=np.float64), _ints(var), _ints(view), _pixels(uv_px), cam, out)
    return out


def distances_px(P: np.ndarray, var: np.ndarray, view: np.ndarray, uv_px: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """(M,) each detection's distance (px) to its point's projection (NaN where :func:`residuals_px` is)."""
    r = residuals_px(P, var, view, uv_px, cam)
    return np.hypot(r[:, 0], r[:, 1])


def _ints(a: np.ndarray) -> np.ndarray:
    """Indices as given when they are 32-bit (or narrower: no copy of a window's millions), else as int64."""
    a = np.asarray(a)
    return np.ascontiguousarray(a if a.dtype in (np.int16, np.int32) else a.astype(np.int64))


def _pixels(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


@njit(nogil=True, boundscheck=False)
def _project_into_views(X, cam, u, v, z):  # pragma: no cover - compiled
    J = np.empty((2, 3))
    for m in range(len(X)):
        for k in range(len(cam)):
            c = cam[k]
            z[m, k] = c[6] * X[m, 0] + c[7] * X[m, 1] + c[8] * X[m, 2] + c[11]
            ok, uu, vv = _project(cam, k, X[m, 0], X[m, 1], X[m, 2], False, J)
            u[m, k] = uu if ok else np.nan
            v[m, k] = vv if ok else np.nan


def project_into_views(X_cm: np.ndarray, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, 3) world points into every view of ``cam`` (:func:`~dome_calib.recon.kernel.camera_table`) -> u, v (M, V)
    px (NaN behind the camera or outside the lens) and z (M, V) camera-frame depth (cm)."""
    M, V = len(X_cm), len(cam)
    u, v, z = np.empty((M, V)), np.empty((M, V)), np.empty((M, V))
    _project_into_views(np.ascontiguousarray(X_cm, dtype=np.float64), cam, u, v, z)
    return u, v, z


@njit(nogil=True, boundscheck=False)
def _count_records(kp, time_of, A, counts):  # pragma: no cover - compiled
    for b in range(A.shape[0]):
        t = time_of[b]
        for v in range(A.shape[1]):
            a = A[b, v]
            if a < 0:
                continue
            for j in range(19):
                if kp[t, v, a, j, 2] > 0:
                    counts[b] += 1


@njit(nogil=True, boundscheck=False)
def _fill_records(kp, time_of, A, starts, strongest, row, view, joint, uv, conf, strong):  # pragma: no cover
    V = A.shape[1]
    keys = np.empty((19, V), np.int64)
    where = np.empty((19, V), np.int64)
    n = np.empty(19, np.int64)
    for b in range(A.shape[0]):
        t = time_of[b]
        m = starts[b]
        n[:] = 0
        for v in range(V):
            a = A[b, v]
            if a < 0:
                continue
            for j in range(19):
                c = kp[t, v, a, j, 2]
                if c > 0:
                    c = min(c, 1.0)
                    row[m], view[m], joint[m] = b, v, j
                    uv[m, 0], uv[m, 1], conf[m] = kp[t, v, a, j, 0], kp[t, v, a, j, 1], c
                    keys[j, n[j]] = np.int64(np.round(np.float64(c) * _STEPS_PER_CONFIDENCE)) * V + (V - 1 - v)
                    where[j, n[j]] = m
                    n[j] += 1
                    m += 1
        for j in range(19):
            k = n[j]
            threshold = np.int64(-1)
            if k > strongest:
                threshold = np.partition(keys[j, :k].copy(), k - strongest)[k - strongest]
            for i in range(k):
                strong[where[j, i]] = keys[j, i] >= threshold


def assigned_records(kp: np.ndarray, time_of: np.ndarray, assigned: np.ndarray, strongest: int) -> tuple:
    """The detections assigned to B bodies, one record per (body, view, joint) with a detection, in that order:
    kp (T, V, N, 19, 3), time_of (B,) each body's time, assigned (B, V) its detection per view (-1: none) ->
    body (M,) int32, view (M,) int16, joint (M,) int8, uv_px (M, 2) float32, conf (M,) float32 clipped to 1,
    strong (M,) bool: among its (body, joint)'s ``strongest`` most confident (confidence in steps of
    :data:`~dome_calib.ties.CONFIDENCE_QUANTUM`, ties: the lower view)."""
    kp = np.ascontiguousarray(kp, dtype=np.float32)
    time_of, A = _ints(time_of), np.ascontiguousarray(assigned)
    counts = np.zeros(len(A), np.int64)
    _count_records(kp, time_of, A, counts)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    M = int(starts[-1])
    out = (np.empty(M, np.int32), np.empty(M, np.int16), np.empty(M, np.int8), np.empty((M, 2), np.float32),
           np.empty(M, np.float32), np.empty(M, bool))
    _fill_records(kp, time_of, A, starts, int(strongest), *out)
    return out
