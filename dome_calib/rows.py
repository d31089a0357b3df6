"""Products whose rows are items (points, times, patches): each row's terms added in a fixed order, without BLAS.

The toolkit promises that a result does not depend on how the work is cut (batches of times, chunks, tasks,
patches per task, windows). A BLAS product ``A @ B`` whose rows (or columns) are the items being cut breaks that
promise: OpenBLAS picks its kernel by the product's size (one row goes to gemv, a few rows to the tail of the gemm
kernel, many rows are cut among its threads), and each path adds a row's terms in another order. Measured on this
machine (AMD EPYC, OpenBLAS 0.3.31 as numpy 2 bundles it, Haswell and Zen kernels, 1 or 2 threads): the rows of
``(P, 3) @ (3, 3 V)`` computed one by one differ in their last bits from the same rows in a product of 64 to 4,000
rows (74 of 192 values at P = 64), and ``(P, 31) @ (31, 16)`` (the DLT's normal matrices) differs between batches of
7, 33 and all (123, 24 of 1,024 values); with SkylakeX's kernels other sizes differ. The thread count alone did not
change a row here; the size did (``tests/test_rows_rule.py`` holds both).

:func:`rows_product` computes such a product row by row in the order k = 0, 1, ... of the short inner dimension,
with numpy's elementwise operations (no contraction, no reordering): a row is the same bits alone, in any batch, on
any thread count and on any CPU. Use it where a product's rows are per-item results a cut may separate and its
inner dimension is short (3 coordinates, a camera's views): the DLT's normal matrices
(:func:`dome_calib.recon.triangulate.triangulate_dlt`); the camera transform of
:mod:`dome_calib.recon.project` is the same order in a compiled loop. A product that never spans the items of a
cut may stay a BLAS product: a stacked one is one product per item, of the item's own shape whatever their number
(each point's ``(6, V) @ (V, 6)`` normal equations, a patch's ``(3, 3) @ (3, 3)``); a whole depth frame's pixels;
an image's corners or keypoints turned into rays, all in the one seed task of their camera and cloud.
"""
from __future__ import annotations

import numpy as np


def rows_product(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for (P, K) ``A`` and (K, N) or (K,) ``B`` -> (P, N) or (P,), or each row by its own matrix, (P, K,
    N) ``B`` -> (P, N): ``sum_k A[:, k] B[k]`` added in the order k = 0, 1, ..., K - 1 (the first term, then each
    next one added to it), each row the same bits however many rows are computed together."""
    A, B = np.asarray(A), np.asarray(B)
    own = B.ndim == 3
    if A.ndim != 2 or B.ndim not in (1, 2, 3) or B.shape[own] != A.shape[1] or (own and len(B) != len(A)):
        raise ValueError(f"rows_product of shapes {A.shape} and {B.shape}")
    col = (lambda k: A[:, k, None]) if B.ndim >= 2 else (lambda k: A[:, k])  # noqa: E731
    row = (lambda k: B[:, k]) if own else (lambda k: B[k])  # noqa: E731
    if A.shape[1] == 0:
        return np.zeros((A.shape[0],) + B.shape[1 + own:], np.result_type(A, B))
    out = col(0) * row(0)
    term = np.empty_like(out)  # one buffer for every next term (a new array per term cost as much as the sums)
    for k in range(1, A.shape[1]):
        np.multiply(col(k), row(k), out=term)
        out += term
    return out
