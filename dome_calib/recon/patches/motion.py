"""The rigid motion of each body part from one reference time to the next, from the patches labelled to it.

Per (person, bone, step t -> t+1), the patches given to that part (:func:`~dome_calib.recon.patches.parts.
label_parts`) alive at both times give 3 point pairs each (centre and two plane points, world cm). Their rigid
motion ``X(t+1) = R X(t) + t_cm`` (SE(3), no scale) is the weighted least-squares fit of Kabsch / Umeyama (the SVD
of the weighted cross-covariance, its sign fixed so that det R = +1), made robust by iterated reweighting:

1. start from the least median of squares: each patch's own triplet is a rigid motion; of up to ``hypotheses`` of
   them, the one whose median patch residual over all the part's patches is least;
2. each patch's residual ``r`` (cm): the RMS over its 3 points of ``|R X(t) + t - X(t+1)|``; the scale ``s`` =
   max(1.4826 x the median residual, ``min_scale_cm``); Cauchy weights ``1 / (1 + (r / s)^2)``; refit
   (``iterations`` times);
3. patches with ``r > reject_k s`` are outliers (a patch that slid, or another part's); the final fit is on the
   others with weight 1.

A motion is given where at least ``min_patches`` inliers remain; it carries ``rms_cm`` (the RMS residual of the
inliers' points), ``n_patches`` (inliers), ``spread_cm`` (the RMS distance of their points at t from their
centroid) and ``centroid_cm``: the motion of a point ``X`` at t is then known to about
``rms / sqrt(3 n) * sqrt(1 + |X - centroid|^2 / spread^2)`` (:func:`point_sigma_cm`: translation error at the
centroid, and rotation error carried over the lever arm).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.options import AtLeast, options
from dome_calib.recon.patches.parts import closest_on_bone
from dome_calib.rotation import rigid_fit
from dome_calib.schema import PosFinite
from dome_calib import ties

#: 1 / the standard normal's median absolute deviation.
MAD_SCALE = 1.4826


@options
class MotionOptions:
    """How a part's motion is fitted (see the module docstring)."""

    # the fewest inlier patches a part's motion is fitted from (an SE(3) needs three points; two patches give six:
    # their centres and the points on their planes). 2 since merge63 (3 before): on the few-camera rig's limb ends,
    # where two patches are often all that is measured, occluded joints within 3 cm 91.1 / 87.8 -> 91.7 / 91.7 %
    # (seeds 1 / 2, choosing), 76.7 / 87.2 -> 85.6 / 94.4 % (seeds 3 / 4, checks), MPJPE lower on every seed and
    # the panel (0.879 / 0.442 -> 0.873 / 0.420 / 80 %) (docs/benchmarks.md, branch seed363)
    min_patches: AtLeast(2) = 2
    hypotheses: AtLeast(1) = 32
    iterations: AtLeast(0) = 3
    min_scale_cm: PosFinite = 0.1
    reject_k: PosFinite = 3.0


@dataclass(frozen=True)
class PartMotions:
    """M rigid motions, one per (person, bone, step) that has one: person (M,) position in the skeleton array the
    patches were labelled with; bone (M,) index in :data:`~dome_calib.recon.patches.parts.BONES`; step (M,) index
    t of the move from times[t] to times[t+1]; R (M, 3, 3), t_cm (M, 3): ``X(t+1) = R X(t) + t_cm`` (world cm);
    rms_cm (M,), n_patches (M,), spread_cm (M,), centroid_cm (M, 3) (at t) as in the module docstring."""

    person: np.ndarray
    bone: np.ndarray
    step: np.ndarray
    R: np.ndarray
    t_cm: np.ndarray
    rms_cm: np.ndarray
    n_patches: np.ndarray
    spread_cm: np.ndarray
    centroid_cm: np.ndarray

    def __len__(self) -> int:
        return len(self.step)


def _patch_residuals(R: np.ndarray, t: np.ndarray, X0: np.ndarray, X1: np.ndarray) -> np.ndarray:
    """(n, 3, 3) patch points at t and t+1 -> (n,) RMS over each patch's points of the fit's residual (cm)."""
    e = X0 @ R.T + t - X1
    return np.sqrt(np.mean(np.sum(e * e, -1), -1))


def fit_part(X0: np.ndarray, X1: np.ndarray, o: MotionOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """One part's step: (n, 3, 3) its patches' points at t and t+1 -> (R, t, inlier mask (n,)), or None (too few
    inliers)."""
    n = len(X0)
    if n < o.min_patches:
        return None
    A, B = X0.reshape(-1, 3), X1.reshape(-1, 3)
    R, t = _least_median(X0, X1, o.hypotheses)
    for _ in range(o.iterations):
        r = _patch_residuals(R, t, X0, X1)
        s = max(MAD_SCALE * float(np.median(r)), o.min_scale_cm)
        w = 1.0 / (1.0 + (r / s) ** 2)
        R, t = rigid_fit(A, B, np.repeat(w, 3))
    r = _patch_residuals(R, t, X0, X1)
    s = max(MAD_SCALE * float(np.median(r)), o.min_scale_cm)
    inl = ties.at_most(r, o.reject_k * s, ties.RESIDUAL_QUANTUM_CM)
    if inl.sum() < o.min_patches:
        return None
    R, t = rigid_fit(X0[inl].reshape(-1, 3), X1[inl].reshape(-1, 3), np.ones(3 * int(inl.sum())))
    return R, t, inl


def _least_median(X0: np.ndarray, X1: np.ndarray, hypotheses: int) -> tuple[np.ndarray, np.ndarray]:
    """The start: each patch's own triplet is a rigid motion (up to ``hypotheses`` of them, evenly spread in patch
    order); the one whose median patch residual over all patches is least (the first of equal ones)."""
    n = len(X0)
    pick = np.unique(np.linspace(0, n - 1, min(n, hypotheses)).round().astype(int))
    A, B = X0[pick], X1[pick]  # (H, 3, 3) each hypothesis' points
    ca, cb = A.mean(1), B.mean(1)
    C = np.einsum("hki,hkj->hij", A - ca[:, None], B - cb[:, None])
    U, _, Vt = np.linalg.svd(C)
    d = np.where(np.linalg.det(np.einsum("hji,hkj->hik", Vt, U)) < 0, -1.0, 1.0)
    D = np.broadcast_to(np.eye(3), C.shape).copy()
    D[:, 2, 2] = d
    R = np.einsum("hji,hjk,hlk->hil", Vt, D, U)  # V D U^T
    t = cb - np.einsum("hij,hj->hi", R, ca)
    e = np.einsum("hij,nkj->hnki", R, X0) + t[:, None, None] - X1[None]
    med = np.median(np.sqrt(np.mean(np.sum(e * e, -1), -1)), axis=1)
    h = ties.argmin_first(med, ties.RESIDUAL_QUANTUM_CM)
    return R[h], t[h]


def part_motions(X_cm: np.ndarray, alive: np.ndarray, person: np.ndarray, bone: np.ndarray,
                 options: MotionOptions | None = None) -> PartMotions:
    """Every labelled part's rigid motion at every step.

    Args:
        X_cm: (N, T, 3, 3) patch centres and plane points at the reference times (NaN where not alive).
        alive: (N, T) bool.
        person, bone: (N,) the patches' labels (-1: none), as :class:`~dome_calib.recon.patches.parts.PartLabels`.
    Returns:
        :class:`PartMotions`, ordered by step, then person, then bone.
    """
    o = options or MotionOptions()
    X_cm = np.asarray(X_cm, dtype=float)
    N, T = alive.shape
    labelled = (np.asarray(person) >= 0) & (np.asarray(bone) >= 0)
    rows: list[tuple] = []
    for k in range(T - 1):
        both = labelled & alive[:, k] & alive[:, k + 1]
        both &= np.isfinite(X_cm[:, k]).all((1, 2)) & np.isfinite(X_cm[:, k + 1]).all((1, 2))
        idx = np.flatnonzero(both)
        if not len(idx):
            continue
        keys = np.stack([person[idx], bone[idx]], 1)
        for p, b in np.unique(keys, axis=0):
            sel = idx[(keys[:, 0] == p) & (keys[:, 1] == b)]
            got = fit_part(X_cm[sel, k], X_cm[sel, k + 1], o)
            if got is None:
                continue
            R, t, inl = got
            X0, X1 = X_cm[sel[inl], k], X_cm[sel[inl], k + 1]
            pts = X0.reshape(-1, 3)
            c = pts.mean(0)
            rms = float(np.sqrt(np.mean(_patch_residuals(R, t, X0, X1) ** 2)))
            spread = float(np.sqrt(np.mean(np.sum((pts - c) ** 2, -1))))
            rows.append((int(p), int(b), k, R, t, rms, int(inl.sum()), spread, c))
    if not rows:
        z = np.zeros(0, np.int64)
        return PartMotions(person=z, bone=z, step=z, R=np.zeros((0, 3, 3)), t_cm=np.zeros((0, 3)),
                           rms_cm=np.zeros(0), n_patches=z, spread_cm=np.zeros(0), centroid_cm=np.zeros((0, 3)))
    cols = list(zip(*rows))
    return PartMotions(person=np.array(cols[0]), bone=np.array(cols[1]), step=np.array(cols[2]),
                       R=np.stack(cols[3]), t_cm=np.stack(cols[4]), rms_cm=np.array(cols[5]),
                       n_patches=np.array(cols[6]), spread_cm=np.array(cols[7]), centroid_cm=np.stack(cols[8]))


def point_sigma_cm(motions: PartMotions, X_cm: np.ndarray, floor_cm: float) -> np.ndarray:
    """(M, 3) points at t -> (M,) how well each motion carries its point to t+1 (cm, per axis): ``floor`` and the
    fit's own error at that point (module docstring) added in quadrature."""
    lever2 = np.sum((np.asarray(X_cm) - motions.centroid_cm) ** 2, -1) / np.maximum(motions.spread_cm, 1e-3) ** 2
    fit2 = motions.rms_cm ** 2 / (3.0 * np.maximum(motions.n_patches, 1)) * (1.0 + lever2)
    return np.sqrt(floor_cm ** 2 + fit2)


def bone_carry(X_cm: np.ndarray, A0: np.ndarray, B0: np.ndarray, A1: np.ndarray, B1: np.ndarray) -> np.ndarray:
    """Points carried by their bone's move, the part's motion as the body over time alone gives it: (n, k, 3)
    points at t, each row's bone (n, 3) from ``A0`` to ``B0`` at t and ``A1`` to ``B1`` at t+1 -> (n, k, 3) at t+1.
    A point at fraction ``s`` along its bone (its closest point ``C``, clamped to the bone) keeps ``s`` and its
    offset from ``C``, turned by the least rotation taking the bone's direction at t to the one at t+1 (the twist
    about the bone is not known from two joints: none). NaN where a bone is missing or has no length."""
    X = np.asarray(X_cm, dtype=float)
    d0, d1 = np.asarray(B0, float) - A0, np.asarray(B1, float) - A1
    L0, L1 = np.linalg.norm(d0, axis=-1), np.linalg.norm(d1, axis=-1)
    ok = (L0 > 1e-9) & (L1 > 1e-9)
    a = d0 / np.where(ok, L0, 1.0)[:, None]
    b = d1 / np.where(ok, L1, 1.0)[:, None]
    _, s, off = closest_on_bone(X - A0[:, None], d0[:, None])
    w = np.cross(a, b)[:, None]  # sin * axis
    c = np.sum(a * b, -1)[:, None, None]  # cos
    turned = off + np.cross(w, off) + np.cross(w, np.cross(w, off)) / np.maximum(1.0 + c, 1e-9)
    out = A1[:, None] + s[..., None] * d1[:, None] + turned
    return np.where(ok[:, None, None], out, np.nan)
