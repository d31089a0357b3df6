"""Who might be there: 3D proposals of people at one universal time, from unlabelled 2D detections.

Method (linear in views; see docs/reconstruct.md for the measurements behind the choices):

1. **Proposals from a bounded set of view pairs.** :func:`select_pairs` picks at most ``max_pairs`` pairs of views
   whose optical axes are far from parallel and anti-parallel (score |angle - 90 deg|, each view used a bounded
   number of times, ties by name). For every pair and every pair of people in it, all common joints are
   triangulated at once (midpoint of the two rays); the person pair is a 3D hypothesis if the median ray gap is
   below ``max_ray_gap_cm`` over at least ``min_common_joints`` joints and its bones are a person's
   (:func:`plausible_bones`). Cost: pairs x N^2 x 19, not V^2.
2. **Clustering in 3D.** Hypothesis centres (mean of the torso joints, else median of all; compared in steps of
   0.01 mm, :data:`~dome_calib.ties.HYPOTHESIS_CENTRE_QUANTUM_CM`) are clustered greedily around the densest one
   (weight = common joints), radius ``cluster_radius_cm``; each cluster is a proposal whose skeleton is the
   per-joint median of its hypotheses.

Each view's detections are then assigned to the proposals (:mod:`dome_calib.recon.people.assign`, which also
proposes again from the detections no proposal took, over :func:`residual_pairs`).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from dome_calib import ties
from dome_calib.recon.body_models import BONE_LENGTH_CM, JOINTS19
from dome_calib.options import AtLeast, UnitInterval, options, require
from dome_calib.schema import NonNegFinite, PosFinite
from dome_calib.recon.kernel import F32, CameraKernel
from dome_calib.recon.people.matching import nan_median
from dome_calib.recon.project import ViewSet


@options
class AssociationOptions:
    """Options of the association (lengths in cm of world, confidences in [0, 1]).

    max_pairs: view pairs that propose people at each time (bounds the cost on the full dome).
    min_joint_conf: joints with lower detection confidence are ignored by association (not by triangulation).
    min_common_joints: joints two detections must share to form a hypothesis / to be compared with a proposal.
    max_ray_gap_cm: median closest-approach distance of a pair hypothesis's rays.
    cluster_radius_cm: hypotheses within this distance of a cluster centre belong to it.
    assign_gate_cm, assign_cap_cm: a detection joins a proposal if its mean capped error (cm at the person's depth)
        is below the gate.
    min_cluster_weight, relative_cluster_weight: a proposal needs hypotheses whose common joints add up to this, and
        to this share of the densest cluster's (ghosts of crossing rays scatter into small clusters; a person seen
        by few views who falls below is found by the residual proposals).
    bone_ratio: a hypothesis's median bone length / nominal adult length must lie in this range.
    min_person_views: a person needs this many assigned views (2 views always agree with each other).
    passes: assignment rounds (the second assigns against linear triangulations of the first's detections; the
        robust triangulation runs once, at the end).
    duplicate_cm: two people whose median joint distance is below this are one (the one with more views stays);
        people's centres are >= ~50 cm apart.
    """

    max_pairs: AtLeast(1) = 48
    min_joint_conf: UnitInterval = 0.05
    min_common_joints: AtLeast(2) = 4
    max_ray_gap_cm: PosFinite = 10.0
    cluster_radius_cm: PosFinite = 30.0
    assign_gate_cm: PosFinite = 12.0
    assign_cap_cm: PosFinite = 40.0
    min_person_views: AtLeast(2) = 3
    passes: AtLeast(1) = 2
    min_cluster_weight: NonNegFinite = 15.0
    relative_cluster_weight: UnitInterval = 0.1
    bone_ratio: tuple[PosFinite, PosFinite] = (0.6, 1.5)
    duplicate_cm: NonNegFinite = 25.0

    _ordered = require(lambda o: o.bone_ratio[0] <= o.bone_ratio[1], "bone_ratio {o.bone_ratio}: expected (low, high) with low <= high")


#: Joints whose mean is a hypothesis's centre (when at least two are there): the torso, rarely occluded all at once.
_TORSO = [JOINTS19.index(n) for n in ("neck", "body_center", "l_shoulder", "r_shoulder", "l_hip", "r_hip")]


#: Bones that a ghost (two people's rays crossing) stretches or shrinks, with their nominal lengths
#: (:data:`~dome_calib.recon.body_models.BONE_LENGTH_CM`): torso, shoulders, hips, upper arms, forearms, thighs, shins.
_BONES = [(JOINTS19.index(a), JOINTS19.index(b), BONE_LENGTH_CM[(a, b)]) for a, b in (
    ("neck", "body_center"), ("l_shoulder", "r_shoulder"), ("l_hip", "r_hip"), ("l_shoulder", "l_elbow"),
    ("r_shoulder", "r_elbow"), ("l_elbow", "l_wrist"), ("r_elbow", "r_wrist"), ("l_hip", "l_knee"),
    ("r_hip", "r_knee"), ("l_knee", "l_ankle"), ("r_knee", "r_ankle"))]


def plausible_bones(X: np.ndarray, ratio: tuple[float, float]) -> np.ndarray:
    """(M, 19, 3) skeletons -> (M,) bool: the median of (bone length / nominal) over the bones present lies within
    ``ratio`` (True if fewer than 2 bones are present). A ghost at another depth than its people is scaled by the
    depth ratio and fails."""
    a, b, nominal = (np.array(v) for v in zip(*_BONES))
    length = np.linalg.norm(X[:, a] - X[:, b], axis=-1) / nominal  # (M, B), NaN where a joint is missing
    med = nan_median(length, axis=-1)
    n = np.isfinite(length).sum(-1)
    return (n < 2) | ((med >= ratio[0]) & (med <= ratio[1]))


def select_pairs(views: ViewSet, max_pairs: int) -> np.ndarray:
    """(Q, 2) view index pairs, Q <= max_pairs: axes closest to perpendicular first, each view in at most
    ceil(2 max_pairs / V) + 1 pairs, ties by view names. Pairs with axes within 3 deg of (anti)parallel are never
    taken (a panel's own cameras, 5-15 deg apart, still pair up when nothing better is there)."""
    return _take_pairs(_ranked_pairs(tuple(views.names), views.R[:, 2, :].tobytes()), len(views.names), max_pairs)


@lru_cache(maxsize=4)
def _ranked_pairs(names: tuple[str, ...], axes: bytes) -> np.ndarray:
    """(K, 2) every pair of views whose optical axes (V x 3 float64, as bytes: a cache key) are not within 3 deg of
    (anti)parallel, best first: |angle - 90 deg| (0.1 deg steps), then the names. Made once per camera set: the
    residual proposals of every time take their pairs from it."""
    V = len(names)
    axis = np.frombuffer(axes, dtype=np.float64).reshape(V, 3)
    a, b = np.triu_indices(V, 1)
    cos = np.clip((axis[a] * axis[b]).sum(-1), -1, 1)
    step = ties.AXIS_ANGLE_QUANTUM_DEG
    score = ties.quantize(np.abs(np.degrees(np.arccos(cos)) - 90.0), step)
    name_rank = np.argsort(np.argsort(np.array(names)))
    order = np.lexsort((name_rank[b], name_rank[a], score))
    order = order[score[order] <= ties.quantize(87.0, step)]  # not within 3 deg of (anti)parallel: no depth
    out = np.stack([a[order], b[order]], axis=1)
    out.flags.writeable = False
    return out


def _take_pairs(ranked: np.ndarray, n_views: int, max_pairs: int) -> np.ndarray:
    """The first ``max_pairs`` of ranked pairs, each of the ``n_views`` views in at most ceil(2 max_pairs /
    n_views) + 1 of them."""
    if n_views < 2:
        return np.zeros((0, 2), dtype=np.int64)
    if len(ranked) <= max_pairs:
        return ranked.copy()
    limit = int(np.ceil(2 * max_pairs / n_views)) + 1
    used = np.zeros(int(ranked.max()) + 1, dtype=np.int64)
    keep = []
    for k, (a, b) in enumerate(ranked):
        if used[a] < limit and used[b] < limit:
            keep.append(k)
            used[a] += 1
            used[b] += 1
            if len(keep) == max_pairs:
                break
    return ranked[np.array(keep, dtype=np.int64)]


def residual_pairs(views: ViewSet, has_left: np.ndarray, max_pairs: int) -> np.ndarray:
    """View pairs (indices into ``views``) among the views whose ``has_left`` (V,) is set: the views that kept
    detections no proposal took (:func:`select_pairs` on them, twice ``max_pairs``: they hold few detections; the
    ranking of all the views' pairs is made once and filtered)."""
    if has_left.sum() < 2:
        return np.zeros((0, 2), dtype=np.int64)
    ranked = _ranked_pairs(tuple(views.names), views.R[:, 2, :].tobytes())
    return _take_pairs(ranked[has_left[ranked[:, 0]] & has_left[ranked[:, 1]]], int(has_left.sum()), 2 * max_pairs)


def world_rays(views: ViewSet, kernel: CameraKernel, kp: np.ndarray) -> np.ndarray:
    """(V, N, 19, 3) detections -> (V, N, 19, 3) world ray directions R^T [x, y, 1] (undistorted)."""
    V, N = kp.shape[:2]
    u = kp[..., 0].transpose(1, 2, 0).reshape(-1, V)
    v = kp[..., 1].transpose(1, 2, 0).reshape(-1, V)
    x, y = kernel.undistort(u, v)
    xh = np.stack([x, y, np.ones_like(x)], axis=-1).reshape(N, 19, V, 3).transpose(2, 0, 1, 3)
    return np.einsum("vji,vnkj->vnki", views.R.astype(F32), xh)


def pair_hypotheses(views: ViewSet, rays: np.ndarray, kp: np.ndarray, pairs: np.ndarray,
                    options: AssociationOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3D hypotheses from detection pairs of the view pairs.

    Returns centres (M, 3) cm, joints (M, 19, 3) cm (NaN where not triangulated) and weights (M,) (common joints).
    """
    if len(pairs) == 0:
        return np.zeros((0, 3)), np.zeros((0, 19, 3)), np.zeros(0)
    C = views.center_cm.astype(F32)
    va, vb = pairs[:, 0], pairs[:, 1]
    da, db = rays[va][:, :, None], rays[vb][:, None]  # (Q, N, 1, 19, 3), (Q, 1, N, 19, 3)
    ok = (kp[va][:, :, None, :, 2] > options.min_joint_conf) & (kp[vb][:, None, :, :, 2] > options.min_joint_conf)
    w0 = (C[va] - C[vb])[:, None, None, None, :]
    a, b, c = (da * da).sum(-1), (da * db).sum(-1), (db * db).sum(-1)
    d, e = (da * w0).sum(-1), (db * w0).sum(-1)
    den = a * c - b * b
    ok &= den > 1e-3 * a * c
    den = np.where(ok, den, 1.0)
    s, t = (b * e - c * d) / den, (a * e - b * d) / den
    ok &= (s > 0) & (t > 0)
    pa = C[va][:, None, None, None, :] + s[..., None] * da
    pb = C[vb][:, None, None, None, :] + t[..., None] * db
    diff = pa - pb
    gap = np.sqrt((diff * diff).sum(-1))
    n = ok.sum(-1)
    gap_med = nan_median(np.where(ok, gap, np.nan), axis=-1)
    good = (n >= options.min_common_joints) & (np.nan_to_num(gap_med, nan=np.inf) < options.max_ray_gap_cm)
    q, i, j = np.nonzero(good)
    X = np.where(ok[q, i, j][..., None], 0.5 * (pa[q, i, j] + pb[q, i, j]), np.nan).astype(float)
    plausible = plausible_bones(X, options.bone_ratio)
    X, q, i, j = X[plausible], q[plausible], i[plausible], j[plausible]
    torso = X[:, _TORSO]
    n_torso = np.isfinite(torso[..., 0]).sum(1)
    centres = np.where((n_torso >= 2)[:, None], np.nanmean(np.where(n_torso[:, None, None] >= 2, torso, 0.0), axis=1)
                       if len(X) else np.zeros((0, 3)), nan_median(X, axis=1))
    return centres, X, n[q, i, j].astype(float)


def cluster_hypotheses(centres: np.ndarray, joints: np.ndarray, weights: np.ndarray,
                       options: AssociationOptions) -> np.ndarray:
    """Greedy density clustering of hypothesis centres -> (P, 19, 3) proposal skeletons (per-joint medians).

    Every choice here is exact: the centres are quantised to :data:`~dome_calib.ties.HYPOTHESIS_CENTRE_QUANTUM_CM`
    (integers), their squared distances and the radius's square compared exactly (in steps squared), a cluster's
    centre is the median rounded to a step (half to even), and densities (sums of common joints) are compared
    through :mod:`dome_calib.ties`; the densest first, the first hypothesis among equals."""
    M = len(centres)
    if M == 0:
        return np.zeros((0, 19, 3))
    step = ties.HYPOTHESIS_CENTRE_QUANTUM_CM
    q = ties.quantize(centres, step)  # (M, 3) steps
    r2 = int(ties.quantize(options.cluster_radius_cm ** 2, step * step))

    def within(centre: np.ndarray) -> np.ndarray:
        """Squared distances of the centres to ``centre`` (steps, broadcast) below the radius's: exact (integer
        differences, in float64 exact up to 2^53 steps squared; farther ones are far outside the radius anyway)."""
        d2 = np.zeros(np.broadcast_shapes(q.shape[:-1], np.shape(centre)[:-1]))
        for k in range(3):
            d = (q[..., k] - centre[..., k]).astype(float)
            d2 += d * d
        return d2 < r2

    near = within(q[:, None])
    left = np.ones(M, bool)
    density = np.where(near, weights[None], 0.0).sum(1)
    out = []
    floor = max(options.min_cluster_weight, options.relative_cluster_weight * float(density.max()))
    while left.any():
        seed = int(ties.argmax_where(density, left, ties.CLUSTER_WEIGHT_QUANTUM)[0])
        if ties.below(density[seed], floor, ties.CLUSTER_WEIGHT_QUANTUM):
            break
        members = left & near[seed]
        centre = ties.quantize(np.median(q[members], axis=0), 1.0)  # steps: a median of integers, exact
        members = left & within(centre)
        members[seed] = True
        out.append(nan_median(joints[members], axis=0))
        left &= ~members
        density -= np.where(near[:, members], weights[members][None], 0.0).sum(1)
    if not out:
        return np.zeros((0, 19, 3))
    return np.stack(out)


def propose(views: ViewSet, kernel: CameraKernel, kp: np.ndarray, pairs: np.ndarray,
            options: AssociationOptions, rays: np.ndarray | None = None) -> np.ndarray:
    """(V, N, 19, 3) detections at one time -> (P, 19, 3) proposal skeletons (cm, NaN joints possible).
    ``rays``: :func:`world_rays` of these detections if already computed."""
    rays = world_rays(views, kernel, kp) if rays is None else rays
    centres, joints, weights = pair_hypotheses(views, rays, kp, pairs, options)
    return cluster_hypotheses(centres, joints, weights, options)
