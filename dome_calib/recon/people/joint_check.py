"""Which triangulated joints of a person to trust: the skeleton check after the robust triangulation.

A joint seen by few views can triangulate to a consistent-looking point far from its body: two wrong detections (a
left/right swap, a neighbour's limb) that agree with each other, or two right ones from cameras of one panel (a
few degrees apart, so 10 px of detection error move the point along the ray by metres). RANSAC cannot see this
(both views are inliers of the point); the body can. :func:`check_joints`, for all bodies at once:

1. **Reach**: a joint farther than ``max_reach_cm`` from the body's robust centre (per-axis median of its joints)
   is dropped (the ankles of a 2 m tall person are ~1.5 m from it).
2. **Bones**: a bone (:data:`~dome_calib.recon.body_models.BONE_LENGTH_CM`: the joints19 kinematic tree and the
   shoulder and hip cross bones) longer than ``max_bone_ratio`` x its adult length + ``bone_slack_cm`` is
   implausible. While a body has one, its worst joint is dropped: the largest share of implausible bones, then
   the most of them, then the fewest inlier views, then the farthest from the centre (whole cm), then the lowest
   index. A wrong joint stretches all its bones, a right neighbour only the one to it.
3. **Few views need the body's word**: a joint with fewer than ``min_views_alone`` inlier views is kept only if a
   chain of plausible bones links it to a joint with at least that many (or, for a body whose best joint has
   fewer, to one with the body's most): two views always agree with each other, so the body has to agree too.
   Across joints that were not triangulated (a wrist whose elbow nobody saw) the link is the tree path: the
   distance within ratio x the path's nominal length + slack; never across a joint this check dropped.

A dropped joint is missing (``c = -1``): a joint metres away from its body is never right. Cost per call: a few
(B, 20) array operations per dropped joint; bodies without an implausible bone cost one pass.
"""
from __future__ import annotations

import numpy as np

from dome_calib.recon.body_models import BONE_LENGTH_CM, BONES19, JOINTS19
from dome_calib.options import AtLeast, options
from dome_calib.schema import NonNegFinite, PosFinite

_A = np.array([JOINTS19.index(a) for a, _ in BONE_LENGTH_CM])
_B = np.array([JOINTS19.index(b) for _, b in BONE_LENGTH_CM])
_NOMINAL = np.array(list(BONE_LENGTH_CM.values()))
#: (E, 19) bone -> its two joints.
_INCIDENCE = np.zeros((len(_A), 19), dtype=np.int64)
_INCIDENCE[np.arange(len(_A)), _A] = 1
_INCIDENCE[np.arange(len(_A)), _B] = 1


def _tree_paths() -> tuple[np.ndarray, np.ndarray]:
    """Over the joints19 tree (:data:`BONES19`): (19, 19) nominal length of the path between two joints (cm) and
    (19, 19, 19) bool: joint k lies strictly inside the path from i to j."""
    adjacent: dict[int, list[tuple[int, float]]] = {j: [] for j in range(19)}
    for a, b in BONES19:
        i, j = JOINTS19.index(a), JOINTS19.index(b)
        adjacent[i].append((j, BONE_LENGTH_CM[(a, b)]))
        adjacent[j].append((i, BONE_LENGTH_CM[(a, b)]))
    length = np.zeros((19, 19))
    inside = np.zeros((19, 19, 19), dtype=bool)
    for start in range(19):
        stack = [(start, 0.0, [])]
        seen = {start}
        while stack:
            j, d, path = stack.pop()
            length[start, j] = d
            inside[start, j, path[1:]] = True  # path holds start and the joints before j
            for k, bone in adjacent[j]:
                if k not in seen:
                    seen.add(k)
                    stack.append((k, d + bone, path + [j]))
    return length, inside


#: Nominal tree-path length between two joints (cm) and the joints strictly between them.
_PATH_CM, _INSIDE = _tree_paths()


@options
class JointCheckOptions:
    """Options of :func:`check_joints` (cm). max_bone_ratio, bone_slack_cm: a bone longer than ratio x nominal +
    slack is implausible (noise on two joints, taller people); max_reach_cm: farthest a joint may be from the
    body's centre; min_views_alone: joints with fewer inlier views must be linked to the body by plausible bones;
    enabled: False keeps every triangulated joint (ablation)."""

    max_bone_ratio: PosFinite = 1.6
    bone_slack_cm: NonNegFinite = 15.0
    max_reach_cm: PosFinite = 180.0
    min_views_alone: AtLeast(2) = 3
    enabled: bool = True


def body_centres_cm(X: np.ndarray) -> np.ndarray:
    """(B, 19, 3) skeletons (NaN = missing) -> (B, 3) per-axis median of the present joints (NaN if none)."""
    s = np.sort(np.where(np.isfinite(X).all(-1, keepdims=True), X, np.nan), axis=1)  # NaN last
    n = np.isfinite(s[..., 0]).sum(1)[:, None]  # (B, 1)
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0)[..., None], axis=1)[:, 0]
    hi = np.take_along_axis(s, np.maximum(n // 2, 0)[..., None], axis=1)[:, 0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def check_joints(X: np.ndarray, n_inliers: np.ndarray, options: JointCheckOptions | None = None) -> np.ndarray:
    """(B, 19, 3) triangulated skeletons (cm, NaN = missing), (B, 19) inlier views -> (B, 19) bool: keep the
    joint (False for missing joints and for the joints the module docstring's checks drop)."""
    options = options or JointCheckOptions()
    X = np.asarray(X, dtype=float)
    present = np.isfinite(X).all(-1)
    if not options.enabled or len(X) == 0:
        return present
    n_inl = np.asarray(n_inliers, dtype=np.int64)
    dist_cm = np.linalg.norm(X - body_centres_cm(X)[:, None], axis=-1)
    dist_q = np.minimum(np.nan_to_num(dist_cm, nan=0.0), 9999.0).astype(np.int64)  # whole cm: no float ties
    keep = present & (np.nan_to_num(dist_cm, nan=np.inf) <= options.max_reach_cm)
    length = np.linalg.norm(X[:, _A] - X[:, _B], axis=-1)  # (B, E), NaN where a joint is missing
    long = np.nan_to_num(length, nan=0.0) > options.max_bone_ratio * _NOMINAL + options.bone_slack_cm
    rows = np.arange(len(X))
    for _ in range(19):
        both = keep[:, _A] & keep[:, _B]
        bad = long & both
        todo = bad.any(1)
        if not todo.any():
            break
        n_bad = bad.astype(np.int64) @ _INCIDENCE  # (B, 19)
        n_bones = both.astype(np.int64) @ _INCIDENCE  # 1 to 4 bones per joint: 60 / n is exact
        share = (60 * n_bad) // np.maximum(n_bones, 1)
        key = ((share * 10 + n_bad) * 100_000 + (99_999 - np.minimum(n_inl, 99_999))) * 10_000 + dist_q
        worst = np.argmax(np.where(n_bad > 0, key, -1), axis=1)
        keep[rows[todo], worst[todo]] = False
    # few views: linked to the body's well-seen joints by plausible bones; where the joints between two kept ones
    # were not triangulated at all, their distance against the tree path between them is the bone
    need = np.minimum(options.min_views_alone, np.where(keep, n_inl, 0).max(1))[:, None]
    linked = keep & (n_inl >= need)
    ask = np.flatnonzero((keep & ~linked).any(1))
    if len(ask) == 0:
        return keep
    k = keep[ask]
    gap = (present[ask][:, None, None, :] & _INSIDE[None]).any(-1)  # a triangulated joint lies between
    span = np.linalg.norm(X[ask][:, :, None] - X[ask][:, None], axis=-1)
    link = (k[:, :, None] & k[:, None] & ~gap & (_PATH_CM > 0)
            & (np.nan_to_num(span, nan=np.inf) <= options.max_bone_ratio * _PATH_CM + options.bone_slack_cm))
    grown = linked[ask]
    for _ in range(18):
        more = grown | (link & grown[:, None, :]).any(-1)
        if (more == grown).all():
            break
        grown = more
    linked[ask] = grown
    return keep & linked
