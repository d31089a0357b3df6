"""The people as occluders of the patches' views: a geometric-consistency term of the visibility from the body.

The patch stage runs after the people (``reconstruct --images``): the body over time is known at every reference
time. A camera cannot see a patch if the ray from the camera centre to the patch centre passes through a body
part's volume before it reaches the patch. The visibility's own geometric term is only the cosine between the
patch's normal and the direction to the camera; a normal 30-40 deg wrong near a silhouette lets cameras *behind*
the surface in, and a view of the surface's back is exactly a ray that crosses the patch's own limb first. Other
people standing between the camera and the patch, and a person's own arm in front of its torso, are the same test.

The rule, per patch and camera (:func:`occluded_views`):

- **the body as capsules**: each part of :data:`~.parts.BONES` at the camera's frame time (the body over time
  interpolated linearly between its times, :meth:`BodyPrior.at`), a capsule round the bone of the part's
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

Cost (one compiled pass over the patch-camera pairs, numba): each person's capsules are tested only for the rays
that meet the person's bounding sphere, each capsule only where the ray meets its own bounding sphere, and a pair
stops at its first occluder (the labels do not depend on the order: a pair is hidden if any capsule hides it).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.jit import njit
from dome_calib.recon.body_models import BONES19, JOINTS19
from dome_calib.recon.patches.parts import BONES
from dome_calib import ties

#: The radius of each part's capsule (cm), in :data:`~.parts.BONES` order: a generic adult's (torso, head,
#: shoulders, hips, upper arms, forearms, thighs, shins). A prior only: the skeleton seeds' photometric search looks
#: ``seed_depth_window_cm`` either side of it, and as an occluder it is shrunk by ``occluder_margin_cm``.
PART_RADIUS_CM = np.array([13.0, 9.0, 6.0, 10.0, 5.0, 5.0, 4.0, 4.0, 7.0, 7.0, 5.0, 5.0])
#: Squared distances are compared in multiples of this (cm^2) after rounding.
DIST2_QUANTUM_CM2 = 1e-6


@dataclass(frozen=True)
class BodyPrior:
    """The people over time, as the skeleton stages give them: times_ms (T,) and joints_cm (T, P, 19, 3) joints19
    (world cm, NaN where missing), e.g. the body over time at the reference stream's times. The skeleton seeds'
    depth prior (:mod:`.seed_skeleton`) and the occluders of the views (this module)."""

    times_ms: np.ndarray
    joints_cm: np.ndarray

    def at(self, t_ms: float) -> np.ndarray:
        """(P, 19, 3) the people at any ``t_ms`` inside the prior's times: linear between the two times around it
        (a joint missing at either is missing; a prior's own time within 0.5 ms: its joints); outside the times,
        or ``t_ms`` NaN: (0, 19, 3)."""
        t = np.asarray(self.times_ms, dtype=float)
        if not len(t) or not np.isfinite(t_ms) or t_ms < t[0] - 0.5 or t_ms > t[-1] + 0.5:
            return np.zeros((0, 19, 3))
        k = ties.argmin_first(np.abs(t - t_ms), ties.TIME_QUANTUM_MS)
        if abs(t[k] - t_ms) < 0.5:
            return np.asarray(self.joints_cm[k], float)
        hi = int(np.searchsorted(t, t_ms))
        w = (t_ms - t[hi - 1]) / (t[hi] - t[hi - 1])
        J = np.asarray(self.joints_cm, float)
        return (1.0 - w) * J[hi - 1] + w * J[hi]


#: Each joints19 joint's parent in the body's tree (:data:`~dome_calib.recon.body_models.BONES19`, rooted at the
#: neck; -1: the root), in an order where a parent comes before its children.
_TREE = [(JOINTS19.index(b), JOINTS19.index(a)) for a, b in BONES19]


def hold_unseen_parts(times_ms: np.ndarray, joints_cm: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """The people over time with each joint the detector did not see carried by its parent from the times it was
    seen: (T,) times, (T, P, 19, 3) joints (NaN: missing), (T, P, 19) ``seen`` (the joint rests on detections at
    that time) -> (T, P, 19, 3).

    Through an occluded limb the body over time either leaves the joints out (their variance grows past its
    ``max_sigma_cm``: the part has no capsule, so no skeleton seed and no occluder there) or puts them out from its
    smoothness prior alone, its worst estimate (the capsule in the wrong place: a seed's depth and normal, an
    occluder). Per person and joint not seen at a time, parents before children (the neck, the tree's root, is
    kept as it is): its offset from its parent is taken from the nearest times before and after where both were
    seen, linear in time between them (one side: that side's), and added to the parent's place at that time (the
    parent itself already so placed if it was unseen). Where the joint and its parent were never seen together, or
    the parent is missing, the joint is left as it is (missing or not). Seen joints are unchanged bit for bit."""
    t = np.asarray(times_ms, dtype=float)
    J = np.array(joints_cm, dtype=float, copy=True)
    ok = np.asarray(seen, bool) & np.isfinite(J).all(-1)
    for j, a in _TREE:
        both = ok[:, :, j] & ok[:, :, a]  # (T, P)
        for p in np.flatnonzero((~ok[:, :, j]).any(0)):
            have = np.flatnonzero(both[:, p])
            fill = np.flatnonzero(~ok[:, p, j] & np.isfinite(J[:, p, a]).all(-1))
            if not len(have) or not len(fill):
                continue
            off = J[have, p, j] - J[have, p, a]  # (H, 3) the seen offsets
            k = np.searchsorted(t[have], t[fill])
            i0, i1 = np.clip(k - 1, 0, len(have) - 1), np.clip(k, 0, len(have) - 1)
            lo, hi = have[i0], have[i1]
            span = t[hi] - t[lo]
            w = np.where(span > 0, (t[fill] - t[lo]) / np.where(span > 0, span, 1.0), 0.0)[:, None]
            J[fill, p, j] = J[fill, p, a] + (1.0 - w) * off[i0] + w * off[i1]
    return J


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


@njit(nogil=True, boundscheck=False, inline="always")
def _point_segment2(px, py, pz, ax, ay, az, bx, by, bz):  # pragma: no cover - compiled
    """Squared distance of point P to segment [A, B] (non-degenerate)."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    t = ((px - ax) * dx + (py - ay) * dy + (pz - az) * dz) / (dx * dx + dy * dy + dz * dz)
    t = min(max(t, 0.0), 1.0)
    ex, ey, ez = px - ax - t * dx, py - ay - t * dy, pz - az - t * dz
    return ex * ex + ey * ey + ez * ez


@njit(nogil=True, boundscheck=False, inline="always")
def _segment_segment2(p1x, p1y, p1z, q1x, q1y, q1z, p2x, p2y, p2z, q2x, q2y, q2z):  # pragma: no cover - compiled
    """Squared distance between segments [p1, q1] and [p2, q2] (non-degenerate): the closest points' parameters
    minimise the distance over the unit square, clamped (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1x, d1y, d1z = q1x - p1x, q1y - p1y, q1z - p1z
    d2x, d2y, d2z = q2x - p2x, q2y - p2y, q2z - p2z
    rx, ry, rz = p1x - p2x, p1y - p2y, p1z - p2z
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    b = d1x * d2x + d1y * d2y + d1z * d2z
    c = d1x * rx + d1y * ry + d1z * rz
    f = d2x * rx + d2y * ry + d2z * rz
    denom = a * e - b * b
    s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 1e-12 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t, s = 1.0, min(max((b - c) / a, 0.0), 1.0)
    gx, gy, gz = rx + d1x * s - d2x * t, ry + d1y * s - d2y * t, rz + d1z * s - d2z * t
    return gx * gx + gy * gy + gz * gz


@njit(nogil=True, boundscheck=False, inline="always")
def _below(d2, r):  # pragma: no cover - compiled
    """d2 < r^2, both quantised to :data:`DIST2_QUANTUM_CM2`."""
    return np.rint(d2 / DIST2_QUANTUM_CM2) < np.rint(r * r / DIST2_QUANTUM_CM2)


@njit(nogil=True, boundscheck=False)
def _inside(X, A, B, radius, out):  # pragma: no cover - compiled
    """(N, K) each patch centre lies in each capsule."""
    for n in range(X.shape[0]):
        for k in range(A.shape[0]):
            out[n, k] = _below(_point_segment2(X[n, 0], X[n, 1], X[n, 2], A[k, 0], A[k, 1], A[k, 2], B[k, 0], B[k, 1],
                                               B[k, 2]), radius[k])


@njit(nogil=True, boundscheck=False)
def _occluded(X, C, pi, ci, A, B, radius, start, centre, reach, inside, stop_cm, out):  # pragma: no cover - compiled
    """:func:`occluded_views`' loop: per pair, each person whose bounding sphere the ray meets, each of its capsules
    (not one holding the patch) whose bounding sphere the ray meets, until the first that the ray enters."""
    for m in range(pi.shape[0]):
        out[m] = False
        n, c = pi[m], ci[m]
        xx, xy, xz = X[n, 0], X[n, 1], X[n, 2]
        cx, cy, cz = C[c, 0], C[c, 1], C[c, 2]
        tx, ty, tz = cx - xx, cy - xy, cz - xz
        dist = np.sqrt(tx * tx + ty * ty + tz * tz)
        if dist <= stop_cm:
            continue
        w = stop_cm / dist
        sx, sy, sz = xx + tx * w, xy + ty * w, xz + tz * w
        for p in range(centre.shape[0]):
            # 1 cm^2 of slack on the bounding spheres: the exact test decides
            if _point_segment2(centre[p, 0], centre[p, 1], centre[p, 2], sx, sy, sz, cx, cy, cz) >= \
                    reach[p] * reach[p] + 1.0:
                continue
            for k in range(start[p], start[p + 1]):
                if inside[n, k]:
                    continue  # the patch is inside this part: it says nothing
                ax, ay, az, bx, by, bz, r = A[k, 0], A[k, 1], A[k, 2], B[k, 0], B[k, 1], B[k, 2], radius[k]
                hx, hy, hz = bx - ax, by - ay, bz - az
                half = 0.5 * np.sqrt(hx * hx + hy * hy + hz * hz) + r
                if _point_segment2(0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz), sx, sy, sz, cx, cy, cz) >= \
                        half * half + 1.0:
                    continue
                if _below(_segment_segment2(sx, sy, sz, cx, cy, cz, ax, ay, az, bx, by, bz), r):
                    out[m] = True
                    break
            if out[m]:
                break


def occluded_views(occ: Occluders, X: np.ndarray, C: np.ndarray, pi: np.ndarray, ci: np.ndarray,
                   stop_cm: float) -> np.ndarray:
    """(M,) bool: whether the people hide patch centre ``X[pi]`` from camera centre ``C[ci]`` (module docstring).

    Args:
        occ: the occluders at the cameras' frame time.
        X: (N, 3) patch centres, world cm; C: (V, 3) camera centres; pi, ci: (M,) the patch-camera pairs judged.
        stop_cm: the ray starts this far from the patch, towards the camera.
    """
    out = np.zeros(len(pi), bool)
    if len(pi) == 0 or len(occ) == 0:
        return out
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    X, A, B, radius = f64(X), f64(occ.A), f64(occ.B), f64(occ.radius)
    inside = np.zeros((len(X), len(A)), bool)
    _inside(X, A, B, radius, inside)
    _occluded(X, f64(C), np.ascontiguousarray(pi, dtype=np.int64), np.ascontiguousarray(ci, dtype=np.int64), A, B,
              radius, np.ascontiguousarray(occ.start, dtype=np.int64), f64(occ.centre), f64(occ.reach), inside,
              float(stop_cm), out)
    return out
