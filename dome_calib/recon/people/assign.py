"""Which detection in which view is whom: each view's detections assigned to the proposals of one time.

1. **Assignment per view.** Every proposal skeleton (:mod:`dome_calib.recon.people.proposals`) is projected into
   every view; a detection's cost against a proposal is the mean over common joints of the pixel distance converted
   to cm at the joint's depth (capped at ``assign_cap_cm``, so a swapped or borrowed limb costs a bounded amount);
   one-to-one per view by :func:`~dome_calib.recon.people.matching.greedy_match` below ``assign_gate_cm``. Cost:
   V x N x proposals x 19.
2. **Residual proposals.** Detections that no proposal took, in the views that have them, propose again over
   pairs of those views only (a person seen by few views has few pairs among the sampled ones: this finds them;
   the views with leftovers are few, so the cost stays small).
3. **Passes.** With ``passes`` = 2 the assigned detections are triangulated linearly (weighted DLT) and assigned
   again against those more complete skeletons (outliers are not removed there: the assignment caps each joint's
   cost).

:func:`associate` runs the three for every time of a batch; the bridging of the tracks' gaps
(:mod:`~dome_calib.recon.people.bridging`) takes the same rules from here: :func:`leftover` (the detections no
person took), :func:`enough_views` (``min_person_views``) and :func:`assign_passes`. :func:`assigned_detections`
lays out what was found for the triangulation (:func:`dome_calib.recon.people.bodies.triangulate_people`).
"""
from __future__ import annotations

import numpy as np

from dome_calib import ties
from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.people.matching import dedupe, greedy_match
from dome_calib.recon.people.proposals import AssociationOptions, propose, residual_pairs, world_rays
from dome_calib.recon.people.compiled import project_into_views
from dome_calib.recon.project import ViewSet
from dome_calib.recon.triangulate import triangulate_dlt, undistort_detections

#: A detection is compared joint by joint only with proposals whose 2D centre is this close (cm at their depth).
CANDIDATE_CM = 80.0


def assign(kernel: CameraKernel, skeletons: np.ndarray, kp: np.ndarray, options: AssociationOptions) -> np.ndarray:
    """Each view's detection of each proposal: (P, 19, 3) skeletons, (V, N, 19, 3) detections -> (V, P) index
    into N or -1."""
    P, V, N = len(skeletons), kp.shape[0], kp.shape[1]
    if P == 0 or N == 0:
        return np.full((V, P), -1, dtype=np.int64)
    X = skeletons.reshape(-1, 3)
    have = np.all(np.isfinite(X), axis=1)
    u, v, zc = project_into_views(np.where(have[:, None], X, 0.0), kernel.table)  # (P*19, V)
    proj = np.stack([u, v], axis=-1).reshape(P, 19, V, 2).transpose(2, 0, 1, 3)  # (V, P, 19, 2)
    cm_per_px = (zc / kernel.table[:, 12]).reshape(P, 19, V).transpose(2, 0, 1)  # (V, P, 19): z / fx
    pvalid = (have.reshape(P, 19)[None] & np.isfinite(proj[..., 0]) & (cm_per_px > 0))
    det = kp[..., 2] > options.min_joint_conf  # (V, N, 19)
    # Candidates first: detection and proposal whose 2D centres (mean of their joints) are within
    # CANDIDATE_CM at the proposal's depth; the full per-joint cost only for those (a few per detection).
    pc = np.where(pvalid[..., None], proj, 0.0).sum(2) / np.maximum(pvalid.sum(2), 1)[..., None]  # (V, P, 2)
    scale = np.where(pvalid, cm_per_px, 0.0).sum(2) / np.maximum(pvalid.sum(2), 1)  # (V, P) cm per px
    dc = np.where(det[..., None], kp[..., :2], 0.0).sum(2) / np.maximum(det.sum(2), 1)[..., None]  # (V, N, 2)
    gap = np.linalg.norm(dc[:, :, None] - pc[:, None], axis=-1) * scale[:, None]  # (V, N, P)
    cand = (gap < CANDIDATE_CM) & (det.sum(2) >= options.min_common_joints)[..., None] & (pvalid.sum(2) > 0)[:, None]
    v, i, p = np.nonzero(cand)
    both = det[v, i] & pvalid[v, p]  # (K, 19)
    diff = kp[v, i, :, :2] - proj[v, p]
    err = np.minimum(np.where(both, np.sqrt((diff * diff).sum(-1)) * cm_per_px[v, p], 0.0), options.assign_cap_cm)
    n = both.sum(-1)
    cost = np.full((V, N, P), np.inf)
    cost[v, i, p] = np.where(n >= options.min_common_joints, err.sum(-1) / np.maximum(n, 1), np.inf)
    match = greedy_match(cost, options.assign_gate_cm, ties.SKELETON_DISTANCE_QUANTUM_CM)  # (V, N) -> proposal
    out = np.full((V, P), -1, dtype=np.int64)
    v, i = np.nonzero(match >= 0)
    out[v, match[v, i]] = i
    return out



def leftover(kp: np.ndarray, A: np.ndarray, options: AssociationOptions) -> np.ndarray:
    """The leftover rule: (V, N, 19, 3) detections at one time and the (V, P) assignment of its people -> (V, N)
    bool: the detections no person took that hold ``min_common_joints`` joints above ``min_joint_conf`` (the
    residual proposals' and the bridging's evidence)."""
    V, N = kp.shape[:2]
    taken = np.zeros((V, N), bool)
    v, p = np.nonzero(A >= 0)
    taken[v, A[v, p]] = True
    return ~taken & ((kp[..., 2] > options.min_joint_conf).sum(-1) >= options.min_common_joints)


def enough_views(A: np.ndarray, options: AssociationOptions) -> np.ndarray:
    """(P,) bool: the people of a (V, P) assignment with at least ``min_person_views`` views."""
    return (A >= 0).sum(0) >= options.min_person_views


def residual_proposals(views: ViewSet, kernel: CameraKernel, kp: np.ndarray, skeletons: np.ndarray, A: np.ndarray,
                       options: AssociationOptions, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Proposals from the detections that no proposal took (step 2): (V, P) assignment -> (V, P + P_new) and the
    (P + P_new, 19, 3) skeletons."""
    left = leftover(kp, A, options)
    has_left = left.any(1)
    if has_left.sum() < options.min_person_views:
        return A, skeletons
    kp_left = np.where(left[..., None, None], kp, 0.0)
    new = propose(views, kernel, kp_left, residual_pairs(views, has_left, options.max_pairs), options, rays)
    if len(new) == 0:
        return A, skeletons
    B = assign(kernel, new, kp_left, options)
    keep = enough_views(B, options)
    return np.concatenate([A, B[:, keep]], axis=1), np.concatenate([skeletons, new[keep]])


def assigned_detections(kp: np.ndarray, assigned: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The assigned detections of every person of every time: kp (T, V, N, 19, 3), assigned[t] (V, P_t) ->
    uv_px (sum P_t * 19, V, 2) (NaN = none) and conf (sum P_t * 19, V) clipped to [0, 1] (OpenPose's heatmap peaks
    reach a little above 1: a weight, not a probability)."""
    uvs, confs = [], []
    V = kp.shape[1]
    for t, A in enumerate(assigned):
        det = kp[t][np.arange(V)[:, None], np.maximum(A, 0)]  # (V, P, 19, 3)
        det = np.where((A >= 0)[..., None, None], det, 0.0)
        uvs.append(det[..., :2].transpose(1, 2, 0, 3))  # (P, 19, V, 2)
        confs.append(det[..., 2].transpose(1, 2, 0))
    uv = np.concatenate(uvs).reshape(-1, V, 2) if uvs else np.zeros((0, V, 2))
    conf = np.concatenate(confs).reshape(-1, V).astype(float) if confs else np.zeros((0, V))
    return np.where((conf > 0)[..., None], uv, np.nan), np.clip(conf, 0, 1)


def linear_skeletons(views: ViewSet, kernel: CameraKernel, kp: np.ndarray, assigned: list[np.ndarray]
                     ) -> np.ndarray:
    """Weighted linear (DLT) triangulation of the assigned detections: (sum P, 19, 3) cm, for assigning again
    (outliers are not removed here: the assignment caps each joint's cost)."""
    uv, conf = assigned_detections(kp, assigned)
    valid = conf > 0
    xn = undistort_detections(kernel, np.nan_to_num(uv), valid)
    return triangulate_dlt(views, xn, np.where(valid, conf, 0.0)).reshape(-1, 19, 3)


def associate(views: ViewSet, kernel: CameraKernel, pairs: np.ndarray, kp: np.ndarray, options: AssociationOptions,
              *, min_body_joints: int) -> list[np.ndarray]:
    """(T, V, N, 19, 3) people at T times -> per time the (V, P_t) assignment of its people (index into N or -1),
    every person with at least ``min_person_views`` views. pairs: :func:`~.proposals.select_pairs` of ``views``;
    min_body_joints: a linear skeleton of the second pass needs this many joints to be assigned against."""
    a = options
    T = kp.shape[0]
    rays = [world_rays(views, kernel, kp[t]) for t in range(T)]
    skeletons = [propose(views, kernel, kp[t], pairs, a, rays[t]) for t in range(T)]
    skeletons = [S[dedupe(S, np.isfinite(S).all(-1), a.duplicate_cm)] for S in skeletons]
    assigned = []
    for t in range(T):
        A = assign(kernel, skeletons[t], kp[t], a)
        A, skeletons[t] = residual_proposals(views, kernel, kp[t], skeletons[t], A, a, rays[t])
        assigned.append(A[:, enough_views(A, a)])
    return assign_passes(views, kernel, kp, assigned, a, min_body_joints=min_body_joints)


def assign_passes(views: ViewSet, kernel: CameraKernel, kp: np.ndarray, assigned: list[np.ndarray],
                  options: AssociationOptions, *, min_body_joints: int) -> list[np.ndarray]:
    """The passes after the first (step 3): ``passes - 1`` rounds, each assigning the detections kp (T, V, N, 19, 3)
    again against the linear triangulations of each time's assigned ones (skeletons of ``min_body_joints`` joints
    or more, de-duplicated) -> per time the (V, P_t) assignment, ``min_person_views`` views each. One linear
    triangulation call for the T times of a round."""
    a = options
    for _ in range(a.passes - 1):  # assign again against linear triangulations of the assigned detections
        X = linear_skeletons(views, kernel, kp, assigned)
        sizes = np.cumsum([0] + [A.shape[1] for A in assigned])
        for t in range(len(assigned)):
            S = X[sizes[t]: sizes[t + 1]]
            S = S[np.isfinite(S).all(-1).sum(1) >= min_body_joints]
            S = S[dedupe(S, np.isfinite(S).all(-1), a.duplicate_cm)]
            A = assign(kernel, S, kp[t], a)
            assigned[t] = A[:, enough_views(A, a)]
    return assigned
