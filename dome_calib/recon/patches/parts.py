"""Body parts that move with the patches: each patch trajectory labelled with the bone it moves rigidly with.

The CVPR 2014 / Panoptic rule: a part trajectory (a bone of a person over time) takes the patch trajectories that
move rigidly with it and whose normal points away from it (the vector from the closest point on the bone to the
patch centre has a positive inner product with the patch normal).

Per patch and candidate bone, over the times the patch is alive (at least ``min_frames``):

- **away**: the share of times with ``(X - closest point on the bone) . normal > 0`` must reach ``min_away``, and
  the median distance to the bone must be within ``max_distance_cm`` (a patch whose normal points into its own
  part, a flipped sign, is left unlabelled rather than given to a far bone that it happens to face away from);
- **rigid**: a point moving with a bone keeps its distance to the bone's axis ``r`` and its position along it
  ``z`` (both free of the bone's unknown twist); the cost is the RMS of ``r(t) - median r`` and ``z(t) - median z``
  (cm), each series first averaged over ``2 rigidity_half_window_frames + 1`` consecutive reference times (a
  body moves smoothly, the skeleton's per-frame errors do not: against a skeleton with 1.5 cm of independent
  noise per joint and frame, the unaveraged RMS is that noise, larger on short bones whatever the patch does), plus ``distance_weight`` x the median distance to the bone (cm) and ``alignment_weight`` x (1 - the median
  cosine between the normal and the way out of the bone): of two bones that move alike (people standing still),
  the one the patch sits on, whose surface it is (a torso patch next to the shoulders points out of the torso's
  axis, not out of the shoulder line).

- **thickness** (a second pass): a patch lies on its part's surface, at the part's radius from its bone. Where two
  bones meet at a joint (hips and thigh, upper arm and forearm), the closest point on both is that joint, so
  distance, alignment and (people standing) rigidity cannot tell them apart; the parts' thicknesses can (the hips
  are wider than the thigh). Each part's radius is measured from the first pass's labels: per person and bone,
  the median distance of its patches whose closest point lies inside the bone (not beyond either joint; at least
  ``min_radius_patches``, else no radius for that part); in the second pass, for a part with a radius, the
  patch's distance from the part's surface, ``radius_weight`` x ``|median distance - radius|`` (cm), takes the
  place of ``distance_weight`` x its distance from the bone (which, at a crease, favours the thinner part: a
  patch where the torso meets the hips is nearer the hips' bone whichever surface it is on). Nothing is assumed
  of a body's shape: the radii are each capture's and person's own.

- **creases** (``crease_cm`` > 0): a patch that lies within ``crease_cm`` of two parts' surfaces (the thickness
  term, ``|median distance - radius|``, both parts' radii measured) and is rigid with both within ``crease_cm``
  (the rigidity RMS), both passing, is left unlabelled: its place and motion fit either part within what they are
  known to, so only its estimated normal (the alignment, made across both surfaces at a crease) would pick one.
  The ties (:mod:`.body`) lose nothing by it: such a patch moves with both parts alike.

- **joint caps** (``joint_cap_cm`` > 0): a patch labelled an upper arm or a thigh that lies on the cap of the joint
  where it meets the trunk's part (its closest point on its bone within ``joint_cap_cm`` of the shoulder or hip,
  and as near the shoulders' or hips' bone, within ``joint_cap_near_cm``) is left unlabelled: it moves with the
  trunk, and in the limb's motion it would make the limb follow the trunk (:func:`leave_joint_caps`).

The label is the bone of least cost among those that pass (costs quantised to 1e-4 cm, ties by person then bone
order); -1 where none passes. Bones are segments between joints19 joints (:data:`BONES`), one per body part of
the synthetic body volume (the head: neck to the ears' midpoint).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from dome_calib.options import AtLeast, UnitInterval, options
from dome_calib.schema import NonNegFinite, PosFinite
from dome_calib import ties

#: Body parts as (name, joint a, joint b) of joints19; -1 as joint b: the midpoint of the ears (16, 18).
BONES = [("torso", 2, 0), ("head", 0, -1), ("shoulders", 3, 9), ("hips", 6, 12), ("l_upper_arm", 3, 4),
         ("r_upper_arm", 9, 10), ("l_forearm", 4, 5), ("r_forearm", 10, 11), ("l_thigh", 6, 7), ("r_thigh", 12, 13),
         ("l_shin", 7, 8), ("r_shin", 13, 14)]
_QUANTUM = ties.LENGTH_QUANTUM_CM
_CHUNK = 128


@options
class PartOptions:
    """How patches are given to parts."""

    min_frames: AtLeast(2) = 5
    min_away: UnitInterval = 0.8
    distance_weight: NonNegFinite = 0.1
    alignment_weight: NonNegFinite = 10.0
    radius_weight: NonNegFinite = 1.0
    max_distance_cm: PosFinite = 30.0
    min_radius_patches: AtLeast(1) = 5
    rigidity_half_window_frames: AtLeast(0) = 2
    # a patch within this of two parts' surfaces and rigid with both within it is left unlabelled (0: off); 0.5 cm:
    # what a tracked patch's place is known to (the stream's centre error, median 2.9 mm after 1 frame and 4.7-4.9
    # mm after 10 on bench/patches.py's scenes)
    crease_cm: NonNegFinite = 0.5
    # joint caps (0: off): a patch labelled a limb that hangs from the trunk (an upper arm, a thigh) whose closest
    # point on its bone lies within this of the joint it shares with the trunk's part (the shoulders, the hips), and
    # whose distance to that part's bone is within joint_cap_near_cm of its distance to its own, is left unlabelled
    # (:func:`leave_joint_caps`): it sits on the joint's cap, where the nearest point of both bones is the joint, and
    # moves with the trunk, so in the limb's motion it makes the limb follow the trunk (the few-camera rig's seed 3:
    # 21 of the 48 patches labelled an upper arm). 5 cm when on: the upper arm's radius (occlusion.PART_RADIUS_CM),
    # a capsule's round end reaching one radius past its joint. On scene 1 96.94 % of the labels right (95.83), the
    # few-camera rig's MPJPE ratio 0.818 -> 0.817, 0.798 -> 0.786, 0.841 -> 0.816, but its occluded joints within 3 cm
    # 87.2, 87.2, 68.3 -> 66.1, 83.3 -> 82.8 % and the panel's accel ratio 0.378 -> 0.416 (docs/benchmarks.md,
    # hidden63). 5 by default since merge63: with its other defaults every label it removes on scenes 1, 2 and unseen was wrong
    # (right 96.06 -> 96.93, 94.58 -> 96.86, 94.49 -> 95.20 %, 10 frames), the few-camera seeds 1 / 2 0.808 / 0.347 ->
    # 0.801 / 0.340, 0.778 / 0.323 -> 0.777 / 0.322 (91.1, 87.8 % either way); seeds 3 / 4 (checks) 78.3 -> 76.7 %,
    # 87.8 -> 87.2 %; the panel 0.874 / 0.406 -> 0.879 / 0.442 / 80 %
    joint_cap_cm: NonNegFinite = 5.0
    # "about as near": what a tracked patch's place is known to (the stream's centre error, as crease_cm)
    joint_cap_near_cm: NonNegFinite = 0.5


@dataclass(frozen=True)
class PartLabels:
    """person (N,) position of the person in the skeleton array (-1: none); bone (N,) index in :data:`BONES`
    (-1: none); cost (N,) cm."""

    person: np.ndarray
    bone: np.ndarray
    cost: np.ndarray


def bone_segments(joints_cm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, P, 19, 3) joints -> (A, B) (T, P, 12, 3) bone end points, world cm."""
    J = np.asarray(joints_cm, dtype=float)
    a = np.array([b[1] for b in BONES])
    A = J[..., a, :]
    B = np.stack([0.5 * (J[..., 16, :] + J[..., 18, :]) if j < 0 else J[..., j, :] for _, _, j in BONES], -2)
    return A, B


def closest_on_bone(rel: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The closest point on a bone, the one formula of the labels (:func:`label_parts`), the tracking's parts
    (:func:`nearest_part`) and the bone's carry (:func:`~.motion.bone_carry`): ``rel`` (..., 3) a point less the
    bone's first end ``A``, ``d`` (..., 3) the bone ``B - A`` (broadcast) -> (``s_raw`` (...) the fraction along the
    bone of the point's foot on its line, ``rel . d / |d|^2`` (0 on a bone of no length: its closest point is
    ``A``); ``s`` (...) that fraction clamped to [0, 1], the closest point being ``A + s d``; (..., 3) the point less
    its closest point). NaN where the bone or the point is."""
    L2 = np.sum(d * d, -1)
    s_raw = np.sum(rel * d, -1) / np.where(L2 > 0, L2, 1.0)
    s = np.clip(s_raw, 0.0, 1.0)
    return s_raw, s, rel - s[..., None] * d


def label_parts(X_cm: np.ndarray, normal: np.ndarray, alive: np.ndarray, joints_cm: np.ndarray,
                options: PartOptions | None = None) -> PartLabels:
    """Label N patch trajectories with a bone.

    Args:
        X_cm: (N, T, 3) patch centres at the reference times (NaN where not alive).
        normal: (N, T, 3) unit normals.
        alive: (N, T) bool.
        joints_cm: (T, P, 19, 3) the people's joints at the same times (NaN where a person is absent).
    """
    o = options or PartOptions()
    A, B = bone_segments(joints_cm)  # (T, P, K, 3)
    P, K = A.shape[1:3]
    parts = [_components(X_cm[i:i + _CHUNK], normal[i:i + _CHUNK], alive[i:i + _CHUNK], A, B, o)
             for i in range(0, len(X_cm), _CHUNK)]
    if not parts:
        return PartLabels(person=np.zeros(0, np.int64), bone=np.zeros(0, np.int64), cost=np.zeros(0))
    c = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    shape = c["dev"] + o.alignment_weight * (1.0 - c["align"])
    first = _choose(shape + o.distance_weight * c["dist"], c["passes"])
    if o.radius_weight == 0:
        return first
    radius = part_radii(first, c["dist"], c["interior"], P, K, o.min_radius_patches)
    mismatch = np.abs(c["dist"] - radius[None])
    on_part = np.where(np.isfinite(mismatch), o.radius_weight * mismatch, o.distance_weight * c["dist"])
    labels = _choose(shape + on_part, c["passes"])
    if o.crease_cm > 0:
        labels = leave_creases(labels, mismatch, c["dev"], c["passes"], o.crease_cm)
    if o.joint_cap_cm > 0:
        labels = leave_joint_caps(labels, c["dist"], c["foot"], o.joint_cap_cm, o.joint_cap_near_cm)
    return labels


#: The parts of the trunk a limb hangs from (:data:`BONES` index): the shoulders and the hips.
TRUNK_PARTS = tuple(k for k, (name, _, _) in enumerate(BONES) if name in ("shoulders", "hips"))


def _shared_joints() -> list[tuple[int, int, int]]:
    """(a limb's bone, its end 0 / 1, the trunk's bone it meets there) for every limb that hangs from the trunk's
    parts (:data:`TRUNK_PARTS`): the upper arms at the shoulders, the thighs at the hips."""
    ends = [(a, b) for _, a, b in BONES]
    return [(k, e, m) for m in TRUNK_PARTS for k, pair in enumerate(ends) if k not in TRUNK_PARTS
            for e, j in enumerate(pair) if j >= 0 and j in ends[m]]


#: :func:`_shared_joints`, once.
SHARED_JOINTS = _shared_joints()


def leave_joint_caps(labels: PartLabels, dist: np.ndarray, foot: np.ndarray, cap_cm: float,
                     near_cm: float) -> PartLabels:
    """Labels -> the same with the patches on the cap of a joint where a limb meets the trunk unlabelled (kept out
    of the limb's motion): a patch labelled a limb's bone k (an upper arm, a thigh: :func:`_shared_joints`) of
    person p whose closest point on k lies within ``cap_cm`` of the end of k where it meets the trunk's bone m (the
    shoulders, the hips) (``foot`` (N, P, K, 2): the median distance along the bone from each end, end a then end b,
    of the clamped closest point), and whose median distance to m is within ``near_cm`` of its distance to k
    (``dist`` (N, P, K), NaN: m not passed through, never near); compared after quantising to 1e-4 cm. A patch
    labelled the trunk's part keeps its label (it moves with the trunk there)."""
    n = np.flatnonzero(labels.bone >= 0)
    p, k = labels.person[n], labels.bone[n]
    cap = np.zeros(len(labels.bone), bool)
    for b, e, m in SHARED_JOINTS:
        on = k == b
        i, q = n[on], p[on]
        gap = np.abs(dist[i, q, m] - dist[i, q, b])
        at_end = ties.at_most(foot[i, q, b, e], cap_cm, _QUANTUM)
        cap[i] |= at_end & np.isfinite(gap) & ties.at_most(np.where(np.isfinite(gap), gap, 0.0), near_cm, _QUANTUM)
    return PartLabels(person=np.where(cap, -1, labels.person), bone=np.where(cap, -1, labels.bone),
                      cost=np.where(cap, np.nan, labels.cost))


def leave_creases(labels: PartLabels, mismatch: np.ndarray, dev: np.ndarray, passes: np.ndarray,
                  crease_cm: float) -> PartLabels:
    """Labels -> the same with the patches at a crease unlabelled: those whose own person has at least two bones,
    the labelled one among them, that pass with the patch within ``crease_cm`` of the part's surface
    (``mismatch``, NaN: no radius measured, never near) and rigid with it within ``crease_cm`` (``dev``); all
    (N, P, K), compared after quantising to 1e-4 cm."""
    near = passes & ties.at_most(mismatch, crease_cm, _QUANTUM) & ties.at_most(dev, crease_cm, _QUANTUM)
    n = np.flatnonzero(labels.bone >= 0)
    own = near[n, labels.person[n]]  # (n, K)
    crease = np.zeros(len(labels.bone), bool)
    crease[n] = own[np.arange(len(n)), labels.bone[n]] & (own.sum(1) >= 2)
    return PartLabels(person=np.where(crease, -1, labels.person), bone=np.where(crease, -1, labels.bone),
                      cost=np.where(crease, np.nan, labels.cost))


def part_radii(labels: PartLabels, dist: np.ndarray, interior: np.ndarray, P: int, K: int,
               min_patches: int) -> np.ndarray:
    """(P, K) each part's thickness (cm): the median distance to its bone of the patches labelled to it whose
    closest point on the bone lies inside it (not beyond either joint), from at least ``min_patches`` of them (NaN:
    fewer, no radius term for that part). dist, interior (N, P, K)."""
    out = np.full((P, K), np.nan)
    n = np.arange(len(labels.bone))
    got = labels.bone >= 0
    d = dist[n[got], labels.person[got], labels.bone[got]]
    inside = interior[n[got], labels.person[got], labels.bone[got]]
    key = labels.person[got] * K + labels.bone[got]
    for k in np.unique(key[inside]):
        sel = inside & (key == k)
        if sel.sum() >= min_patches:
            out.flat[k] = np.round(np.median(d[sel]) / _QUANTUM) * _QUANTUM
    return out


def _choose(cost: np.ndarray, passes: np.ndarray) -> PartLabels:
    """(N, P, K) costs and which pass -> the least per patch (quantised, ties by person then bone order)."""
    N, P, K = cost.shape
    flat = cost.reshape(N, P * K)
    # the first of equal quantised costs: person, then bone order
    best, found = ties.argmin_where(flat, (passes & np.isfinite(cost)).reshape(N, P * K), _QUANTUM)
    least = ties.quantize(np.where(found, flat[np.arange(N), best], 0.0), _QUANTUM)
    return PartLabels(person=np.where(found, best // K, -1), bone=np.where(found, best % K, -1),
                      cost=np.where(found, least * _QUANTUM, np.nan))


def windowed_mean(v: np.ndarray, ok: np.ndarray, half: int) -> np.ndarray:
    """(N, T, ...) values and where they count -> each counted value replaced by the mean of the counted values
    within ``half`` times of it (axis 1; 0: unchanged); NaN where not counted."""
    w = np.where(ok, v, 0.0)
    if half > 0:
        n = ok.astype(float)
        cw = np.concatenate([np.zeros_like(w[:, :1]), np.cumsum(w, axis=1)], axis=1)
        cn = np.concatenate([np.zeros_like(n[:, :1]), np.cumsum(n, axis=1)], axis=1)
        T = v.shape[1]
        lo, hi = np.maximum(np.arange(T) - half, 0), np.minimum(np.arange(T) + half + 1, T)
        w = (cw[:, hi] - cw[:, lo]) / np.maximum(cn[:, hi] - cn[:, lo], 1.0)
    return np.where(ok, w, np.nan)


def _components(X_cm: np.ndarray, normal: np.ndarray, alive: np.ndarray, A: np.ndarray, B: np.ndarray,
                o: PartOptions) -> dict[str, np.ndarray]:
    """Per patch, person and bone (N, P, K): the rigidity ``dev`` (cm), the median distance ``dist`` (cm) and
    alignment ``align``, ``interior`` (the median closest point lies inside the bone, not at a joint),
    ``passes`` (enough times, normal away from the bone) and, with ``joint_cap_cm``, ``foot`` (N, P, K, 2) the
    median distance along the bone of the clamped closest point from each end (absent without)."""
    d = B - A
    L = np.linalg.norm(d, axis=-1)
    axis = d / np.maximum(L, 1e-9)[..., None]
    X = np.where(alive[..., None], X_cm, 0.0)[:, :, None, None]  # (N, T, 1, 1, 3)
    rel = X - A[None]  # (N, T, P, K, 3)
    z = np.sum(rel * axis[None], -1)  # (N, T, P, K)
    radial = rel - z[..., None] * axis[None]
    r = np.linalg.norm(radial, axis=-1)
    s_raw, s, out = closest_on_bone(rel, d[None])
    dist = np.linalg.norm(out, axis=-1)
    along = np.sum(out * np.where(alive[..., None], normal, 0.0)[:, :, None, None], -1)
    away = along > 0
    align = along / np.maximum(dist, 1e-9)  # cosine between the normal and the way out of the bone
    ok_t = alive[:, :, None, None] & np.isfinite(z) & np.isfinite(r)
    n_t = ok_t.sum(1)  # (N, P, K)
    zs, rs = (windowed_mean(v, ok_t, o.rigidity_half_window_frames) for v in (z, r))
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a bone of an absent person: all-NaN medians, refused below
        zm = np.nanmedian(np.where(ok_t, zs, np.nan), axis=1)
        rm = np.nanmedian(np.where(ok_t, rs, np.nan), axis=1)
        dm = np.nanmedian(np.where(ok_t, dist, np.nan), axis=1)
        am = np.nanmedian(np.where(ok_t, align, np.nan), axis=1)
        sm = np.nanmedian(np.where(ok_t, s_raw, np.nan), axis=1)
        foot = (np.stack([np.nanmedian(np.where(ok_t, f * L[None], np.nan), axis=1) for f in (s, 1.0 - s)], -1)
                if o.joint_cap_cm > 0 else None)  # only the joint caps' rule reads it
        dev = np.where(ok_t, (zs - zm[:, None]) ** 2 + (rs - rm[:, None]) ** 2, 0.0).sum(1) / np.maximum(n_t, 1)
        share_away = np.where(ok_t, away, False).sum(1) / np.maximum(n_t, 1)
    return {"dev": np.sqrt(dev), "dist": dm, "align": am, "interior": (sm > 0.0) & (sm < 1.0),
            "passes": (n_t >= o.min_frames) & ties.at_least(share_away, o.min_away, ties.UNIT_QUANTUM)
            & ties.at_most(dm, o.max_distance_cm, _QUANTUM)} | ({} if foot is None else {"foot": foot})


def nearest_part(X_cm: np.ndarray, joints_cm: np.ndarray, radius_cm: np.ndarray, reach_cm: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The part each point lies on at one time, before any trajectory is labelled (the tracking's use: a patch's
    part while its trajectory is being made): (N, 3) points, (P, 19, 3) the people's joints (NaN: missing), (K,)
    each part's radius (a capsule round each bone of :data:`BONES`) -> (person (N,), bone (N,)): the capsule whose
    surface is nearest the point (``| distance to the bone - radius |``, quantised to 1e-4 cm; ties by person then
    bone order), if within ``reach_cm``; -1 where none is (or a part's ends are missing)."""
    X = np.asarray(X_cm, dtype=float).reshape(-1, 3)
    J = np.asarray(joints_cm, dtype=float).reshape(-1, 19, 3)
    N, P = len(X), len(J)
    if N == 0 or P == 0:
        return np.full(N, -1), np.full(N, -1)
    A, B = bone_segments(J)  # (P, K, 3)
    d = B - A
    L2 = np.sum(d * d, -1)
    _, _, out = closest_on_bone(X[:, None, None] - A[None], d[None])  # (N, P, K, 3)
    gap = np.abs(np.linalg.norm(out, axis=-1) - np.asarray(radius_cm, float)[None, None])
    known = np.isfinite(gap) & (L2 > 0)[None] & np.isfinite(X).all(-1)[:, None, None]
    near = known & ties.at_most(np.where(known, gap, 0.0), reach_cm, _QUANTUM)
    K = A.shape[1]
    best, found = ties.argmin_where(np.where(near, gap, 0.0).reshape(N, P * K), near.reshape(N, P * K), _QUANTUM)
    return np.where(found, best // K, -1), np.where(found, best % K, -1)
