"""The people as occluders of the patches' views: a geometric-consistency term of the visibility from the body.

The patch stage runs after the people (``reconstruct --images``): the body over time is known at every reference
time. A camera cannot see a patch if the ray from the camera centre to the patch centre passes through a body
part's volume before it reaches the patch. The visibility's own geometric term is only the cosine between the
patch's normal and the direction to the camera; a normal 30-40 deg wrong near a silhouette lets cameras *behind*
the surface in, and a view of the surface's back is exactly a ray that crosses the patch's own limb first. Other
people standing between the camera and the patch, and a person's own arm in front of its torso, are the same test.

The rule, per patch and camera (:func:`occluded_views`):

- **the body as capsules**: each part of :data:`~.parts.BONES` at the camera's frame time (the body over time
  interpolated linearly between its times, :meth:`BodyPrior.between`), a capsule round the bone of the part's
  radius (:data:`PART_RADIUS_CM`, a generic adult) **less** ``occluder_margin_cm`` (3 cm): the skeleton is noisy
  (the bench's 1.5 cm per joint coordinate is 2.6 cm per joint), a real part is not round (a chest is flatter than
  its capsule) and a patch that has drifted a little inside its surface must not lose its true views. A part whose
  shrunk radius is not positive occludes nothing;
- **the ray stopped short of the patch**: the segment from the patch centre, moved ``occlusion_stop_cm`` (3 cm,
  half the patch's 6 cm side) towards the camera, to the camera centre. Within half its side of its centre the
  ray may meet the patch's own surface where it curves across the square; that is not an occluder;
- **occluded** if that segment comes closer to a capsule's axis than its shrunk radius, except a capsule that
  contains the patch centre itself (a noisy skeleton or a thin part: which side of it the patch is on is unknown,
  so it says nothing).

Occluded cameras are no candidates of the MAP (:mod:`.visibility`: not projected, not sampled, no reference). It is
per patch (its centre, the camera, the body at that time): which other patches share a task changes nothing.
Without a body (or ``body_occlusion`` off) nothing changes. Distances are compared quantised (squared distances to
1e-6 cm^2, :data:`DIST2_QUANTUM_CM2`): the same labels on every machine.

Cost (vectorised, patches x candidate cameras x capsules): each person's capsules are tested only for the rays
that meet the person's bounding sphere, and each capsule only where the ray meets its own bounding sphere.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.recon.patches.parts import BONES

#: The radius of each part's capsule (cm), in :data:`~.parts.BONES` order: a generic adult's (torso, head,
#: shoulders, hips, upper arms, forearms, thighs, shins). A prior only: the skeleton seeds' photometric search looks
#: ``seed_depth_window_cm`` either side of it, and as an occluder it is shrunk by ``occluder_margin_cm``.
PART_RADIUS_CM = np.array([13.0, 9.0, 6.0, 10.0, 5.0, 5.0, 4.0, 4.0, 7.0, 7.0, 5.0, 5.0])
#: Squared distances are compared in multiples of this (cm^2) after rounding.
DIST2_QUANTUM_CM2 = 1e-6
#: Patch-camera rays tested together (memory: rays x capsules of the people they meet).
RAY_CHUNK = 65536


@dataclass(frozen=True)
class BodyPrior:
    """The people over time, as the skeleton stages give them: times_ms (T,) and joints_cm (T, P, 19, 3) joints19
    (world cm, NaN where missing), e.g. the body over time at the reference stream's times. The skeleton seeds'
    depth prior (:mod:`.seed_skeleton`) and the occluders of the views (this module)."""

    times_ms: np.ndarray
    joints_cm: np.ndarray

    def at(self, t_ms: float) -> np.ndarray:
        """(P, 19, 3) the people at ``t_ms`` (one of the prior's times, within 0.5 ms; none there: (0, 19, 3))."""
        t = np.asarray(self.times_ms, dtype=float)
        if not len(t):
            return np.zeros((0, 19, 3))
        k = int(np.argmin(np.abs(t - t_ms)))
        return np.asarray(self.joints_cm[k], float) if abs(t[k] - t_ms) < 0.5 else np.zeros((0, 19, 3))

    def between(self, t_ms: float) -> np.ndarray:
        """(P, 19, 3) the people at any ``t_ms`` inside the prior's times: linear between the two times around it
        (a joint missing at either is missing; a prior's own time within 0.5 ms: its joints); outside the times,
        or ``t_ms`` NaN: (0, 19, 3)."""
        t = np.asarray(self.times_ms, dtype=float)
        if not len(t) or not np.isfinite(t_ms) or t_ms < t[0] - 0.5 or t_ms > t[-1] + 0.5:
            return np.zeros((0, 19, 3))
        k = int(np.argmin(np.abs(t - t_ms)))
        if abs(t[k] - t_ms) < 0.5:
            return np.asarray(self.joints_cm[k], float)
        hi = int(np.searchsorted(t, t_ms))
        w = (t_ms - t[hi - 1]) / (t[hi] - t[hi - 1])
        J = np.asarray(self.joints_cm, float)
        return (1.0 - w) * J[hi - 1] + w * J[hi]


def body_capsules(joints_cm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P, 19, 3) joints -> capsules (A (K, 3), B (K, 3), radius (K,)) of every part whose ends are known."""
    A, B, R, _ = _capsules(joints_cm)
    return A, B, R


def _capsules(joints_cm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`body_capsules` and (K,) each capsule's person."""
    X = np.asarray(joints_cm, dtype=float).reshape(-1, 19, 3)
    A, B, R, who = [], [], [], []
    for p in range(len(X)):
        for k, (_, a, b) in enumerate(BONES):
            end = 0.5 * (X[p, 16] + X[p, 18]) if b < 0 else X[p, b]
            if np.all(np.isfinite(X[p, a])) and np.all(np.isfinite(end)) and np.linalg.norm(end - X[p, a]) > 1e-6:
                A.append(X[p, a]), B.append(end), R.append(PART_RADIUS_CM[k]), who.append(p)
    if not A:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)
    return np.array(A), np.array(B), np.array(R), np.array(who, np.int64)


@dataclass(frozen=True)
class Occluders:
    """The people's parts as occluders at one time: capsules A, B (K, 3), radius (K,) (already shrunk), grouped by
    person (``start`` (P + 1,) offsets into the capsules), and each person's bounding sphere (centre (P, 3),
    radius (P,))."""

    A: np.ndarray
    B: np.ndarray
    radius: np.ndarray
    start: np.ndarray
    centre: np.ndarray
    reach: np.ndarray

    @classmethod
    def of(cls, joints_cm: np.ndarray, margin_cm: float) -> Occluders:
        """(P, 19, 3) joints -> the capsules of :data:`PART_RADIUS_CM` less ``margin_cm`` (those left positive)."""
        A, B, R, who = _capsules(joints_cm)
        keep = R - margin_cm > 0
        A, B, R, who = A[keep], B[keep], R[keep] - margin_cm, who[keep]
        people = np.unique(who)
        start = np.searchsorted(who, np.append(people, np.iinfo(np.int64).max)) if len(who) else np.zeros(1, np.int64)
        centre, reach = np.zeros((len(people), 3)), np.zeros(len(people))
        for i in range(len(people)):
            s = slice(start[i], start[i + 1])
            ends = np.concatenate([A[s], B[s]])
            centre[i] = 0.5 * (ends.min(0) + ends.max(0))
            reach[i] = np.max(np.linalg.norm(ends - centre[i], axis=1) + np.concatenate([R[s], R[s]]))
        return cls(A=A, B=B, radius=R, start=start.astype(np.int64), centre=centre, reach=reach)

    def __len__(self) -> int:
        return len(self.radius)


def _point_segment2(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Squared distance of points P (..., 3) to segments [A, B] (..., 3)."""
    d = B - A
    t = np.clip(np.sum((P - A) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-12), 0.0, 1.0)
    e = P - A - t[..., None] * d
    return np.sum(e * e, -1)


def _segment_segment2(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Squared distance between segments [p1, q1] and [p2, q2] ((M, 3) each, non-degenerate): the closest points'
    parameters minimise the distance over the unit square, clamped (Ericson, Real-Time Collision Detection 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = np.sum(d1 * d1, 1), np.sum(d2 * d2, 1)
    b, c, f = np.sum(d1 * d2, 1), np.sum(d1 * r, 1), np.sum(d2 * r, 1)
    denom = a * e - b * b
    s = np.where(denom > 1e-12 * a * e, np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    g = r + d1 * s[:, None] - d2 * t[:, None]
    return np.sum(g * g, 1)


def _below(d2: np.ndarray, r: np.ndarray) -> np.ndarray:
    """d2 < r^2, both quantised to :data:`DIST2_QUANTUM_CM2`."""
    return np.rint(d2 / DIST2_QUANTUM_CM2) < np.rint(r * r / DIST2_QUANTUM_CM2)


def occluded_views(occ: Occluders, X: np.ndarray, C: np.ndarray, pi: np.ndarray, ci: np.ndarray,
                   stop_cm: float) -> np.ndarray:
    """(M,) bool: whether the people hide patch centre ``X[pi]`` from camera centre ``C[ci]`` (module docstring).

    Args:
        occ: the occluders at the cameras' frame time.
        X: (N, 3) patch centres, world cm; C: (V, 3) camera centres; pi, ci: (M,) the patch-camera pairs judged.
        stop_cm: the ray starts this far from the patch, towards the camera.
    """
    M = len(pi)
    out = np.zeros(M, bool)
    if M == 0 or len(occ) == 0:
        return out
    inside = _below(_point_segment2(X[:, None], occ.A[None], occ.B[None]), occ.radius[None])  # (N, K)
    for lo in range(0, M, RAY_CHUNK):
        p, c = pi[lo:lo + RAY_CHUNK], ci[lo:lo + RAY_CHUNK]
        to_cam = C[c] - X[p]
        dist = np.linalg.norm(to_cam, axis=1)
        live = dist > stop_cm
        start = X[p] + to_cam * (stop_cm / np.where(live, dist, 1.0))[:, None]
        # each person's capsules, only for the rays that meet the person's bounding sphere
        near = live[:, None] & (_point_segment2(occ.centre[None], start[:, None], C[c][:, None])
                                < occ.reach[None] ** 2 + 1.0)  # (m, P), 1 cm^2 of slack: the exact test decides
        r_idx, person = np.nonzero(near)
        if not len(r_idx):
            continue
        n = occ.start[person + 1] - occ.start[person]
        rays = np.repeat(r_idx, n)
        caps = np.repeat(occ.start[person] - np.cumsum(n) + n, n) + np.arange(int(n.sum()))
        caps = caps.astype(np.int64)
        keep = ~inside[p[rays], caps]
        rays, caps = rays[keep], caps[keep]
        # each capsule's bounding sphere first (a point against the ray), then the segments' distance
        mid = 0.5 * (occ.A[caps] + occ.B[caps])
        half = 0.5 * np.linalg.norm(occ.B[caps] - occ.A[caps], axis=1) + occ.radius[caps]
        close = _point_segment2(mid, start[rays], C[c][rays]) < half * half + 1.0
        rays, caps = rays[close], caps[close]
        hit = _below(_segment_segment2(start[rays], C[c][rays], occ.A[caps], occ.B[caps]), occ.radius[caps])
        got = np.zeros(len(p), bool)
        got[rays[hit]] = True
        out[lo:lo + RAY_CHUNK] = got
    return out
