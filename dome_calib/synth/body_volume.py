"""The volume of synthetic bodies, so that each camera knows which joints a body hides: capsules (a segment and a
radius) around the torso, head, shoulders, hips, upper and lower arms and legs of each person (12 per person).

A joint is hidden in a view if the segment from the camera centre to the joint (stopped :data:`RAY_STOP_CM` short
of it) passes through a capsule of any present person, the person itself included (self-occlusion), except the
person's own capsules the joint sits in (a shoulder in its upper arm, a hip in the torso). Face joints (nose, eyes,
ears) are also hidden when they face away from the camera: their direction from the head centre makes more than
~95 deg (nose, eyes) / ~110 deg (ears) with the direction to the camera.

Each person's upper and lower body is tested first as a bounding sphere (views x joints x people), then only the
rays that meet a sphere are tested against its capsules; all of it vectorised with numpy.
"""
from __future__ import annotations

import numpy as np

#: (12, 2) joints19 end points of each capsule, (12,) radii (cm); the head capsule is built from the ears and neck.
CAPSULE_NAMES = ["torso", "head", "shoulders", "hips", "l_upper_arm", "r_upper_arm", "l_forearm", "r_forearm",
                 "l_thigh", "r_thigh", "l_shin", "r_shin"]
_ENDS = np.array([[2, 0], [-1, -1], [3, 9], [6, 12], [3, 4], [9, 10], [4, 5], [10, 11], [6, 7], [12, 13], [7, 8],
                  [13, 14]])
CAPSULE_RADIUS_CM = np.array([13.0, 9.0, 6.0, 10.0, 5.0, 5.0, 4.0, 4.0, 7.0, 7.0, 5.0, 5.0])
RAY_STOP_CM = 3.0
#: Containment margin: a joint within radius + this of a capsule's axis is "in" it (that capsule does not hide it).
INSIDE_MARGIN_CM = 1.0
_FACE = np.array([1, 15, 17, 16, 18])  # nose, eyes, ears
_FACE_MIN_COS = np.array([-0.1, -0.1, -0.1, -0.35, -0.35])
_CHUNK = 200_000
_GROUPS = [np.array([0, 1, 2, 4, 5, 6, 7]), np.array([3, 8, 9, 10, 11])]  # upper body, lower body


def head_centre_cm(X: np.ndarray) -> np.ndarray:
    """(..., 19, 3) joints -> (..., 3) centre of the head (midpoint of the ears)."""
    return 0.5 * (X[..., 16, :] + X[..., 18, :])


def capsules_cm(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P, 19, 3) joints (cm) -> (A (P, 12, 3), B (P, 12, 3), radius (P, 12)) capsule axes and radii, cm."""
    X = np.asarray(X, dtype=float)
    A, B = X[:, _ENDS[:, 0]].copy(), X[:, _ENDS[:, 1]].copy()
    h, neck = head_centre_cm(X), X[:, 0]
    A[:, 1] = h + 0.3 * (neck - h)
    B[:, 1] = h - 0.25 * (neck - h)
    return A, B, np.broadcast_to(CAPSULE_RADIUS_CM, A.shape[:2]).copy()


def segment_distance2(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Squared distance between segments [p1, q1] and [p2, q2] (each (N, 3), non-degenerate), (N,)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    b = np.einsum("ij,ij->i", d1, d2)
    c = np.einsum("ij,ij->i", d1, r)
    f = np.einsum("ij,ij->i", d2, r)
    denom = a * e - b * b
    parallel = denom <= 1e-12 * a * e
    s = np.clip((b * f - c * e) / np.where(parallel, 1.0, denom), 0.0, 1.0)
    s = np.where(parallel, 0.0, s)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    diff = r + d1 * s[:, None] - d2 * t[:, None]
    return np.einsum("ij,ij->i", diff, diff)


def _capsule_hit(d1: tuple[np.ndarray, ...], a: np.ndarray, r: tuple[np.ndarray, ...], rr: np.ndarray, f: np.ndarray,
                 d2: tuple[np.ndarray, ...], e: np.ndarray, rad2: np.ndarray) -> np.ndarray:
    """Segments p1 + s d1 (s in [0, 1]; d1 = (x, y, z) components (n,), a = |d1|^2 (n,)) against capsules
    A + t d2 (t in [0, 1]; r = p1 - A as components (n, K), rr = |r|^2, f = d2.r; d2 components, e = |d2|^2,
    rad2 = radius^2 (n, K)): (n, K) bool, the segment comes closer to the axis than the radius (Ericson's closest
    points of two segments, with the products precomputed; components keep every array contiguous)."""
    b = d2[0] * d1[0][:, None] + d2[1] * d1[1][:, None] + d2[2] * d1[2][:, None]
    c = r[0] * d1[0][:, None] + r[1] * d1[1][:, None] + r[2] * d1[2][:, None]
    a = a[:, None]
    denom = a * e - b * b
    parallel = denom <= 1e-12 * a * e
    s = np.where(parallel, 0.0, np.clip((b * f - c * e) / np.where(parallel, 1.0, denom), 0.0, 1.0))
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # |r + s d1 - t d2|^2 expanded
    d2min = rr + a * s * s + e * t * t + 2.0 * s * c - 2.0 * t * f - 2.0 * s * t * b
    return d2min < rad2


def point_segment_distance2(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3) points, (..., 3) segment ends -> (...) squared distances."""
    d = b - a
    t = np.clip(np.sum((x - a) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-12), 0.0, 1.0)
    diff = x - a - d * t[..., None]
    return np.sum(diff * diff, -1)


def occluded_joints(cam_centres_cm: np.ndarray, X: np.ndarray, present: np.ndarray | None = None) -> np.ndarray:
    """Which joints each view cannot see because a body (another one, or the person's own) is in the way.

    Args:
        cam_centres_cm: (V, 3) camera centres, world cm.
        X: (P, 19, 3) joints of every person at one time, world cm.
        present: (P,) bool, people in the dome (absent people neither hide nor are tested); default all.
    Returns:
        (V, P, 19) bool, True = hidden (always False for absent people).
    """
    by_self, by_others = occluders(cam_centres_cm, X, present)
    return by_self | by_others


def occluders(cam_centres_cm: np.ndarray, X: np.ndarray, present: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`occluded_joints` told apart by who hides the joint: ((V, P, 19) by the person's own body, its face
    turned away included; (V, P, 19) by another person). A joint may be hidden by both."""
    C = np.asarray(cam_centres_cm, dtype=float).reshape(-1, 3)
    X = np.asarray(X, dtype=float)
    V, P = len(C), len(X)
    present = np.ones(P, dtype=bool) if present is None else np.asarray(present, dtype=bool)
    out = np.zeros((2, V, P, 19), dtype=bool)
    idx = np.flatnonzero(present)
    if len(idx) == 0 or V == 0:
        return out[0], out[1]
    Xp = X[idx]  # (Q, 19, 3)
    Q = len(idx)
    A, B, rad = capsules_cm(Xp)
    joints = Xp.reshape(-1, 3)  # (M, 3), M = Q * 19
    M = len(joints)
    # The person's own capsules a joint sits in do not hide it.
    own = (point_segment_distance2(Xp[:, :, None], A[:, None], B[:, None])
           < (rad[:, None] + INSIDE_MARGIN_CM) ** 2)  # (Q, 19, 12)
    inside = np.zeros((Q, 19, Q, A.shape[1]), dtype=bool)
    inside[np.arange(Q), :, np.arange(Q)] = own
    inside = inside.reshape(M, Q, -1)
    # Rays camera -> joint, stopped short of the joint.
    ray = joints[None] - C[:, None]  # (V, M, 3)
    length = np.linalg.norm(ray, axis=-1)
    end = C[:, None] + ray * (1.0 - RAY_STOP_CM / np.maximum(length, RAY_STOP_CM + 1e-9))[..., None]
    d1_all = end - C[:, None]  # (V, M, 3)
    a_all = np.maximum(np.sum(d1_all * d1_all, -1), 1e-12)  # (V, M)
    d1c = tuple(np.ascontiguousarray(d1_all[..., i]).ravel() for i in range(3))  # (V * M,) each
    a_flat = a_all.ravel()
    hidden = np.zeros((2, V * M), dtype=bool)  # by the person's own body, by another's
    for group in _GROUPS:  # upper and lower body: two tighter bounding spheres than one per person
        Ag, Bg, rad2 = A[:, group], B[:, group], rad[:, group] ** 2  # (Q, K, 3), (Q, K)
        K = len(group)
        pts = np.concatenate([Ag, Bg], axis=1)
        centre = pts.mean(axis=1)  # (Q, 3)
        R = np.max(np.linalg.norm(pts - centre[:, None], axis=-1) + np.sqrt(np.concatenate([rad2, rad2], 1)), 1)
        w = centre[None] - C[:, None]  # (V, Q, 3)
        dw = np.matmul(d1_all, w.transpose(0, 2, 1))  # (V, M, Q)
        s = np.clip(dw / a_all[..., None], 0.0, 1.0)
        dist2 = np.sum(w * w, -1)[:, None] - 2 * s * dw + s * s * a_all[..., None]
        v_i, m_i, q_i = np.nonzero(dist2 < (R ** 2)[None, None])
        # Per (view, capsule): r = C - A by component, its squared norm and its dot with the axis.
        d2 = Bg - Ag  # (Q, K, 3)
        e = np.sum(d2 * d2, -1)  # (Q, K)
        r = C[:, None, None] - Ag[None]  # (V, Q, K, 3)
        f = np.einsum("vqkc,qkc->vqk", r, d2).reshape(V * Q, K)
        rr = np.sum(r * r, -1).reshape(V * Q, K)
        rc = tuple(np.ascontiguousarray(r[..., i]).reshape(V * Q, K) for i in range(3))
        d2c = tuple(np.ascontiguousarray(d2[..., i]) for i in range(3))
        skip = inside[:, :, group].reshape(M * Q, K)
        step = max(_CHUNK // K, 1)
        for lo in range(0, len(v_i), step):
            v, m, q = (x[lo:lo + step] for x in (v_i, m_i, q_i))
            vm, vq = v * M + m, v * Q + q
            hit = _capsule_hit(tuple(x[vm] for x in d1c), a_flat[vm], tuple(x[vq] for x in rc), rr[vq], f[vq],
                               tuple(x[q] for x in d2c), e[q], rad2[q])
            hit &= ~skip[m * Q + q]
            any_hit = np.any(hit, axis=1)
            own = m // 19 == q
            hidden[0, vm[any_hit & own]] = True
            hidden[1, vm[any_hit & ~own]] = True
    hidden = hidden.reshape(2, V, Q, 19)
    # Face joints facing away.
    h = head_centre_cm(Xp)  # (Q, 3)
    normal = Xp[:, _FACE] - h[:, None]  # (Q, 5, 3)
    to_cam = C[:, None, None] - Xp[None, :, _FACE]  # (V, Q, 5, 3)
    cos = np.sum(normal[None] * to_cam, -1) / (np.linalg.norm(normal, axis=-1)[None]
                                               * np.linalg.norm(to_cam, axis=-1) + 1e-12)
    by_self = hidden[0]  # a view: the face turned away hides its own joints
    by_self[:, :, _FACE] |= cos < _FACE_MIN_COS
    out[:, :, idx] = hidden
    return out[0], out[1]
