"""Matching people to people: the small pieces every stage of the group shares.

:func:`greedy_match` pairs detections across two frames (resampling) and detections with proposals (assignment);
:func:`skeleton_distance_cm` compares skeletons (de-duplication, tracking); :func:`dedupe` keeps
one of skeletons that are the same person; :func:`nan_median` is a fast median that skips missing joints. No choice
here rests on the last bits of a float: costs are quantised and ties go by order.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from dome_calib import ties

#: An assignment's cost of a pair outside its gate, in steps of :data:`~dome_calib.ties.SKELETON_DISTANCE_QUANTUM_CM`
#: (1e6 cm): far above any sum of gated costs, so the assignment takes as many gated pairs as it can.
NO_MATCH = 10**9


def gated_assignment(cost: np.ndarray, inside: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The optimal one-to-one assignment (Hungarian) of an (A, B) cost among the pairs ``inside`` their gate, costs
    quantised to ``step`` (:mod:`dome_calib.ties`; a pair outside costs :data:`NO_MATCH` and is never read) ->
    (rows, cols) of the gated pairs taken, rows ascending."""
    r, c = linear_sum_assignment(ties.quantize_where(cost, inside, step, NO_MATCH))
    keep = inside[r, c]
    return r[keep], c[keep]


def greedy_match(cost: np.ndarray, gate: np.ndarray | float, step: float) -> np.ndarray:
    """Vectorised greedy one-to-one matching: (..., A, B) costs -> (..., A) index into B or -1.

    Repeatedly takes the smallest cost below ``gate`` (broadcast to cost) over all rows of a batch element. Costs
    and gate are quantised to ``step`` (:mod:`dome_calib.ties`, in the cost's unit) before comparison and ties go
    to the lowest (a, b), so the result does not rest on the last bits of a float. For the few people per view here
    it equals the optimal assignment except when two people are nearly equally close to two others.
    """
    none = np.iinfo(np.int64).max
    c = ties.quantize_where(cost, ties.below(cost, gate, step), step, none)
    batch, (A, B) = c.shape[:-2], c.shape[-2:]
    if A == 0 or B == 0:
        return np.full((*batch, A), -1, dtype=np.int64)
    c = c.reshape(-1, A * B).copy()
    out = np.full((c.shape[0], A), -1, dtype=np.int64)
    rows = np.arange(c.shape[0])
    for _ in range(min(A, B)):
        k = np.argmin(c, axis=1)
        ok = c[rows, k] != none
        if not ok.any():
            break
        a, b = k // B, k % B
        out[rows[ok], a[ok]] = b[ok]
        view = c.reshape(-1, A, B)
        view[rows[ok], a[ok], :] = none
        view[rows[ok], :, b[ok]] = none
    return out.reshape(*batch, A)


def nan_median(a: np.ndarray, axis: int) -> np.ndarray:
    """Median along ``axis`` ignoring NaN (NaN where all are NaN); a sort, without numpy's slow masked path."""
    a = np.moveaxis(np.asarray(a), axis, -1)
    s = np.sort(a, axis=-1)  # NaN last
    n = np.isfinite(s).sum(-1)
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0)[..., None], axis=-1)[..., 0]
    hi = np.take_along_axis(s, np.maximum(n // 2, 0)[..., None], axis=-1)[..., 0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def skeleton_distance_cm(A: np.ndarray, B: np.ndarray, min_common: int = 3) -> np.ndarray:
    """Median distance over common joints of (P, 19, 3) and (Q, 19, 3) skeletons -> (P, Q) cm (inf if fewer than
    ``min_common`` joints are in both). The median: one wrong joint (a swapped or borrowed limb) does not move it."""
    d = np.linalg.norm(A[:, None] - B[None], axis=-1)  # (P, Q, 19), NaN where either lacks the joint
    n = np.isfinite(d).sum(-1)
    s = np.sort(d, axis=-1)  # NaN last
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0)[..., None], axis=-1)[..., 0]
    hi = np.take_along_axis(s, np.maximum(n // 2, 0)[..., None], axis=-1)[..., 0]
    return np.where(n >= min_common, 0.5 * (lo + hi), np.inf)


def dedupe(X: np.ndarray, support: np.ndarray, duplicate_cm: float) -> np.ndarray:
    """(P,) keep mask: of (P, 19, 3) skeletons closer than ``duplicate_cm`` (median joint distance) the best
    supported stays (largest ``support`` (P, 19) summed over joints: inlier views, or joints for proposals; ties by
    order)."""
    P = len(X)
    keep = np.ones(P, bool)
    if P < 2:
        return keep
    d = skeleton_distance_cm(X, X)
    for i in np.lexsort((np.arange(P), -support.sum(1))):
        if keep[i]:
            dup = d[i] < duplicate_cm
            dup[i] = False
            keep &= ~dup
    return keep
