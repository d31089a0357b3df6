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


@njit(nogil=True, boundscheck=False)
def _pattern_pass(cam_pt, pt_ptr, pt, act_starts, A, row_ptr, cols, fill):  # pragma: no cover - compiled
    """Count (``fill`` False: into ``row_ptr[1:]``) or list (``fill`` True: into ``cols``, ascending per row) the
    cameras b >= a that share a point with each active camera a."""
    mark = np.full(A, -1, dtype=np.int64)
    for a in range(A):
        n = 0
        for i in range(act_starts[a], act_starts[a + 1]):
            p = pt[i]
            for jj in range(pt_ptr[p], pt_ptr[p + 1]):
                b = cam_pt[jj]
                if b >= a and mark[b] != a:
                    mark[b] = a
                    if fill:
                        cols[row_ptr[a] + n] = b
                    n += 1
        if fill:
            cols[row_ptr[a]:row_ptr[a + 1]].sort()
        else:
            row_ptr[a + 1] = n


def block_pattern(st) -> tuple[np.ndarray, np.ndarray]:
    """The upper block pattern of the reduced camera system: (row_ptr (A + 1,), cols (B,)), row a's blocks are the
    cameras ``cols[row_ptr[a]:row_ptr[a + 1]]`` (ascending, the first is a itself) that share a point with a.
    ``st`` is the :class:`dome_calib.ba.schur.Structure`."""
    A = len(st.active_cameras)
    row_ptr = np.zeros(A + 1, dtype=np.int64)
    if A == 0:
        return row_ptr, np.zeros(0, dtype=np.int64)
    _pattern_pass(st.cam_pt, st.pt_ptr, st.pt_act, st.act_starts, A, row_ptr, np.zeros(0, dtype=np.int64), False)
    row_ptr = np.cumsum(row_ptr)
    cols = np.empty(row_ptr[-1], dtype=np.int64)
    _pattern_pass(st.cam_pt, st.pt_ptr, st.pt_act, st.act_starts, A, row_ptr, cols, True)
    return row_ptr, cols


@njit(nogil=True, boundscheck=False)
def _block_rows_kernel(blocks, row_ptr, cols, ypt, cam_pt, pt_ptr, pos, pt, act_starts, rows, nk, A
                       ):  # pragma: no cover - compiled
    """As :func:`_rows_kernel`, into the upper blocks of the pattern (``blocks[k]`` is block (a, cols[k]))."""
    W = ypt.shape[2]
    buf = np.zeros((A, W, W))
    for a in rows:
        for i in range(act_starts[a], act_starts[a + 1]):
            p = pt[i]
            first = pos[i]
            while first > pt_ptr[p] and cam_pt[first - 1] == a:
                first -= 1
            yi = ypt[pos[i]]
            for jj in range(first, pt_ptr[p + 1]):
                b = cam_pt[jj]
                yj = ypt[jj]
                blk = buf[b]
                for r in range(W):
                    y0 = yi[0, r]
                    y1 = yi[1, r]
                    y2 = yi[2, r]
                    for c in range(W):
                        blk[r, c] += y0 * yj[0, c] + y1 * yj[1, c] + y2 * yj[2, c]
        for k in range(row_ptr[a], row_ptr[a + 1]):
            b = cols[k]
            blk = buf[b]
            out = blocks[k]
            if b == a:  # the upper triangle, mirrored, as the dense kernel
                for r in range(nk):
                    for c in range(r, nk):
                        out[r, c] -= blk[r, c]
                        if c != r:
                            out[c, r] -= blk[r, c]
            else:
                for r in range(nk):
                    for c in range(nk):
                        out[r, c] -= blk[r, c]
            blk[:, :] = 0.0


def subtract_yyt_blocks(blocks: np.ndarray, row_ptr: np.ndarray, cols: np.ndarray, ypt: np.ndarray, st,
                        n_threads: int) -> None:
    """blocks (B, k, k) -= the blocks of Y Y^T on the upper block pattern (:func:`block_pattern`); the same sums in
    the same order as :func:`subtract_yyt`, so the same values as the dense matrix's blocks, bit for bit."""
    A, nk = len(row_ptr) - 1, blocks.shape[1]
    if A == 0 or nk == 0 or len(ypt) == 0:
        return
    n_jobs = max(1, min(A, 8 * n_threads))
    jobs = [np.arange(t, A, n_jobs) for t in range(n_jobs)]
    run_in_threads(lambda rows: _block_rows_kernel(blocks, row_ptr, cols, ypt, st.cam_pt, st.pt_ptr, st.pt_pos,
                                                   st.pt_act, st.act_starts, rows, nk, A), jobs, n_threads)
