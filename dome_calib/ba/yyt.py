"""Y Y^T of the reduced camera system: a compiled (numba) kernel over point-major observation blocks.

For camera a (a row of blocks), every observation i of a point p contributes y_i y_j^T to the block (a, b) for
every observation j of p by a camera b >= a; the lower triangle is the mirror. That is about half the sum over
points of track_length^2 block products (3.4e7 on the full dome, 15 x 3 x 15 each). The y blocks are laid out
point-major, so the j of one point are contiguous and the points of a camera are visited in ascending order
(streaming through memory instead of jumping); each camera's row of blocks is accumulated in a small buffer and
written once. Rows are shared out over threads (the kernel releases the GIL) in interleaved slices, since the
first cameras have the most blocks right of the diagonal.

Why compiled: the products are rank-3 updates of 15 x 15 blocks at scattered places, which no dense or sparse
library kernel at hand does well (scipy's block-sparse product runs generic, unvectorised block loops: 7.4 s
on the full dome on 2 threads against 2.0 s here; dense products over clusters of points waste 8x or more,
because the tent points' camera sets differ too much).
"""
from __future__ import annotations

import numpy as np

from dome_calib.ba.threads import run_in_threads
from dome_calib.jit import njit

LANES = 4  # block width padded to a multiple of this (15 -> 16: aligned SIMD rows)


@njit(nogil=True, boundscheck=False)
def _rows_kernel(S4, ypt, cam_pt, pt_ptr, pos, pt, act_starts, rows, nk):  # pragma: no cover - compiled
    A = S4.shape[0]
    W = ypt.shape[2]
    buf = np.zeros((A, W, W))
    touched = np.zeros(A, dtype=np.bool_)
    for a in rows:
        for i in range(act_starts[a], act_starts[a + 1]):
            p = pt[i]
            first = pos[i]
            while first > pt_ptr[p] and cam_pt[first - 1] == a:  # the same camera may see a point twice
                first -= 1
            yi = ypt[pos[i]]
            for jj in range(first, pt_ptr[p + 1]):  # a point's observations are sorted by camera
                b = cam_pt[jj]
                touched[b] = True
                yj = ypt[jj]
                blk = buf[b]
                for r in range(W):
                    y0 = yi[0, r]
                    y1 = yi[1, r]
                    y2 = yi[2, r]
                    for c in range(W):
                        blk[r, c] += y0 * yj[0, c] + y1 * yj[1, c] + y2 * yj[2, c]
        for b in range(a, A):
            if not touched[b]:
                continue
            blk = buf[b]
            if b == a:  # the upper triangle, mirrored (a point seen twice by a makes blk unsymmetric in the last bit)
                for r in range(nk):
                    for c in range(r, nk):
                        S4[a, r, a, c] -= blk[r, c]
                        if c != r:
                            S4[a, c, a, r] -= blk[r, c]
            else:
                for r in range(nk):
                    for c in range(nk):
                        S4[a, r, b, c] -= blk[r, c]
                        S4[b, c, a, r] -= blk[r, c]
            blk[:, :] = 0.0
            touched[b] = False


def subtract_yyt(S4: np.ndarray, ypt: np.ndarray, st, n_threads: int) -> None:
    """S4 (A, k, A, k) -= Y Y^T, Y given by the active observations' y blocks transposed, in the structure's
    point-major order (Ma_active, 3, W >= k; :func:`dome_calib.ba.blocks.y_blocks`). ``st`` is the
    :class:`dome_calib.ba.schur.Structure`; its point-major order (``pt_ptr``, ``pt_pos``, ``cam_pt``) drives the
    kernel."""
    A, nk = S4.shape[0], S4.shape[1]
    if A == 0 or nk == 0 or len(ypt) == 0:
        return
    n_jobs = max(1, min(A, 8 * n_threads))
    jobs = [np.arange(t, A, n_jobs) for t in range(n_jobs)]
    run_in_threads(lambda rows: _rows_kernel(S4, ypt, st.cam_pt, st.pt_ptr, st.pt_pos, st.pt_act, st.act_starts, rows,
                                             nk), jobs, n_threads)
