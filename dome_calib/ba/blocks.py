"""Compiled (numba) per-observation loops of the normal equations: linearisation, point elimination, back-substitution.

What numpy did here in a dozen passes over the observations with (observations x 15 x 3) temporaries, one thread,
these kernels do in one pass each, in threads over contiguous ranges of cameras (numba releases the GIL), writing
the elimination's y blocks straight in the point-major order the Y Y^T kernel (:mod:`dome_calib.ba.yyt`) reads.
Measured on the panel dome's SfM problem (179,242 observations, 59 free cameras, 2 threads, one LM iteration):
linearisation 84 -> 32 ms, the reduced system without Y Y^T 115 -> 20 ms (Y Y^T itself ~145 ms, and no longer
a point-major copy of the y blocks first), back-substitution and Cholesky 26 -> 11 ms; the panel's whole bundle
adjustment stage (3 solves, 24 reduced systems) 11.5 -> 6.5 s.

Every output element is written by one thread, and every sum runs over the observations in the structure's
(camera, point) order, so the results do not depend on the number of threads, on the ranges, or on the machine
(no BLAS call, no fast-math reassociation).
"""
from __future__ import annotations

import numpy as np

from dome_calib.ba.threads import run_in_threads
from dome_calib.jit import njit


def camera_ranges(act_starts: np.ndarray, n_jobs: int) -> list[tuple[int, int]]:
    """Contiguous ranges of active cameras with about equal observation counts (at most ``n_jobs``, none empty)."""
    A = len(act_starts) - 1
    if A <= 0:
        return []
    targets = np.linspace(0, act_starts[-1], max(1, min(n_jobs, A)) + 1)[1:-1]
    cuts = np.unique(np.concatenate([[0], np.searchsorted(act_starts, targets), [A]]))
    return [(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


@njit(nogil=True, boundscheck=False)
def _camera_blocks(Jc, wr, w, act_index, free, act_starts, a_lo, a_hi, U, g_c):  # pragma: no cover - compiled
    """Cameras a_lo..a_hi-1: zero the fixed columns of their Jacobians (in place), U_a = sum w Jc^T Jc,
    g_a = sum Jc^T w r."""
    for a in range(a_lo, a_hi):
        for i in range(act_starts[a], act_starts[a + 1]):
            g = act_index[i]
            wi = w[g]
            r0 = wr[0, g]
            r1 = wr[1, g]
            for c in range(15):
                if not free[a, c]:
                    Jc[0, c, i] = 0.0
                    Jc[1, c, i] = 0.0
            for c in range(15):
                x0 = Jc[0, c, i]
                x1 = Jc[1, c, i]
                g_c[a, c] += x0 * r0 + x1 * r1
                if x0 == 0.0 and x1 == 0.0:
                    continue
                u0 = wi * x0
                u1 = wi * x1
                for d in range(c, 15):
                    U[a, c, d] += u0 * Jc[0, d, i] + u1 * Jc[1, d, i]
        for c in range(15):
            for d in range(c + 1, 15):
                U[a, d, c] = U[a, c, d]


@njit(nogil=True, boundscheck=False)
def _point_blocks(Jp, wr, w, pt, V, g_p):  # pragma: no cover - compiled
    """Every point: V_p = sum w Jp^T Jp, g_p = sum Jp^T w r (all observations, fixed cameras' too)."""
    for i in range(len(pt)):
        p = pt[i]
        wi = w[i]
        for j in range(3):
            a0 = Jp[0, j, i]
            a1 = Jp[1, j, i]
            g_p[p, j] += a0 * wr[0, i] + a1 * wr[1, i]
            for l in range(j, 3):
                V[p, j, l] += wi * (a0 * Jp[0, l, i] + a1 * Jp[1, l, i])
    for p in range(V.shape[0]):
        for j in range(3):
            for l in range(j + 1, 3):
                V[p, l, j] = V[p, j, l]


def linearize_blocks(Jc: np.ndarray, Jp: np.ndarray, res: np.ndarray, w: np.ndarray, st, n_threads: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(U (A, 15, 15), g_c (A, 15), V (P, 3, 3), g_p (P, 3)); ``Jc`` (2, 15, Ma_active) gets its fixed columns
    zeroed in place. ``st`` is the :class:`dome_calib.ba.schur.Structure`."""
    A, P = len(st.active_cameras), st.n_points
    wr = np.ascontiguousarray(res * w)
    U, g_c = np.zeros((A, 15, 15)), np.zeros((A, 15))
    V, g_p = np.zeros((P, 3, 3)), np.zeros((P, 3))
    free = np.ascontiguousarray(st.free)
    pt = np.ascontiguousarray(st.pt)
    jobs = [("c", lo, hi) for lo, hi in camera_ranges(st.act_starts, 2 * n_threads)] + [("p", 0, 0)]

    def run(job: tuple[str, int, int]) -> None:
        if job[0] == "c":
            _camera_blocks(Jc, wr, w, st.act_index, free, st.act_starts, job[1], job[2], U, g_c)
        else:
            _point_blocks(Jp, wr, w, pt, V, g_p)

    run_in_threads(run, jobs, n_threads)
    return U, g_c, V, g_p


@njit(nogil=True, boundscheck=False)
def _y_rows(Jc, Jp, w, act_index, pt_act, pt_pos, Li, h, cols, act_starts, a_lo, a_hi, ypt, rc
            ):  # pragma: no cover - compiled
    """Cameras a_lo..a_hi-1: for each of their observations i of point p, y_i = Jc_i^T w Jp_i L_p^-T (k x 3,
    the free columns ``cols``), stored transposed at its point-major place ``ypt[pt_pos[i]]`` (3, W; the columns
    past k zero), and rc_a += y_i L_p^-1 g_p (``h[p]``)."""
    k = len(cols)
    W = ypt.shape[2]
    for a in range(a_lo, a_hi):
        for i in range(act_starts[a], act_starts[a + 1]):
            g = act_index[i]
            p = pt_act[i]
            wi = w[g]
            # m = w Jp L^-T (2 x 3): m[c, j] = w sum_{l <= j} Jp[c, l] Li[j, l]
            m00 = wi * (Jp[0, 0, g] * Li[p, 0, 0])
            m01 = wi * (Jp[0, 0, g] * Li[p, 1, 0] + Jp[0, 1, g] * Li[p, 1, 1])
            m02 = wi * (Jp[0, 0, g] * Li[p, 2, 0] + Jp[0, 1, g] * Li[p, 2, 1] + Jp[0, 2, g] * Li[p, 2, 2])
            m10 = wi * (Jp[1, 0, g] * Li[p, 0, 0])
            m11 = wi * (Jp[1, 0, g] * Li[p, 1, 0] + Jp[1, 1, g] * Li[p, 1, 1])
            m12 = wi * (Jp[1, 0, g] * Li[p, 2, 0] + Jp[1, 1, g] * Li[p, 2, 1] + Jp[1, 2, g] * Li[p, 2, 2])
            h0 = h[p, 0]
            h1 = h[p, 1]
            h2 = h[p, 2]
            jj = pt_pos[i]
            for r in range(k):
                c = cols[r]
                x0 = Jc[0, c, i]
                x1 = Jc[1, c, i]
                y0 = x0 * m00 + x1 * m10
                y1 = x0 * m01 + x1 * m11
                y2 = x0 * m02 + x1 * m12
                ypt[jj, 0, r] = y0
                ypt[jj, 1, r] = y1
                ypt[jj, 2, r] = y2
                rc[a, r] += y0 * h0 + y1 * h1 + y2 * h2
            for r in range(k, W):
                ypt[jj, 0, r] = 0.0
                ypt[jj, 1, r] = 0.0
                ypt[jj, 2, r] = 0.0


def y_blocks(Jc: np.ndarray, Jp: np.ndarray, w: np.ndarray, Li: np.ndarray, h: np.ndarray, cols: np.ndarray,
             width: int, st, n_threads: int, out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(ypt (Ma_active, 3, width): the y blocks transposed in point-major order, rc (A, k): each camera's sum of
    y_i L^-1 g_p over its observations), for the free columns ``cols`` (k <= width). ``out``: an array of ypt's
    shape to write into (every element is written)."""
    A = len(st.active_cameras)
    n = int(st.act_starts[-1]) if A else 0
    ypt = np.empty((n, 3, width)) if out is None else out
    rc = np.zeros((A, len(cols)))
    cols = np.ascontiguousarray(cols, dtype=np.int64)
    run_in_threads(lambda rng: _y_rows(Jc, Jp, w, st.act_index, st.pt_act, st.pt_pos, Li, h, cols, st.act_starts,
                                       rng[0], rng[1], ypt, rc), camera_ranges(st.act_starts, 2 * n_threads), n_threads)
    return ypt, rc


@njit(nogil=True, boundscheck=False)
def _point_step(Li, h, ypt, cam_pt, pt_ptr, cols, dc, live, dp):  # pragma: no cover - compiled
    """dp_p = -L_p^-T (L_p^-1 g_p + sum_i y_i^T dc_a) for every point (zero if not refined)."""
    k = len(cols)
    for p in range(len(dp)):
        if not live[p]:
            dp[p, 0] = 0.0
            dp[p, 1] = 0.0
            dp[p, 2] = 0.0
            continue
        q0 = h[p, 0]
        q1 = h[p, 1]
        q2 = h[p, 2]
        for jj in range(pt_ptr[p], pt_ptr[p + 1]):
            a = cam_pt[jj]
            t0 = 0.0
            t1 = 0.0
            t2 = 0.0
            for r in range(k):
                d = dc[a, cols[r]]
                t0 += ypt[jj, 0, r] * d
                t1 += ypt[jj, 1, r] * d
                t2 += ypt[jj, 2, r] * d
            q0 += t0
            q1 += t1
            q2 += t2
        dp[p, 0] = -(Li[p, 0, 0] * q0 + Li[p, 1, 0] * q1 + Li[p, 2, 0] * q2)
        dp[p, 1] = -(Li[p, 1, 1] * q1 + Li[p, 2, 1] * q2)
        dp[p, 2] = -(Li[p, 2, 2] * q2)


def point_step_blocks(Li: np.ndarray, h: np.ndarray, ypt: np.ndarray, cols: np.ndarray, dc: np.ndarray, st
                      ) -> np.ndarray:
    """(P, 3) back-substituted point step for the camera step dc (A, 15)."""
    dp = np.empty((st.n_points, 3))
    _point_step(Li, h, ypt, st.cam_pt, st.pt_ptr, np.ascontiguousarray(cols, dtype=np.int64),
                np.ascontiguousarray(dc), st.live_points, dp)
    return dp
