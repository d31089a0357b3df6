"""The detector's joints that joints19 lacks (the feet, BODY_25B's UpperNeck, the head top:
:data:`~dome_calib.recon.body_models.EXTRA_JOINTS`), triangulated for the people the run found.

The people, their ids and their joints19 come from the run: at each time every body keeps its detection in each view
(:attr:`~dome_calib.recon.people.bodies.Bodies.assigned`, an index among that view's people as
:func:`~dome_calib.recon.people.resample.gather_people` orders them). This pass reads the detection files again with
the extra joints (:class:`~dome_calib.recon.people.sources.FileSource` with ``extras``), brings them to the same
times the same way (the matching between frames, the slots' order and their count read joints19 only, so a body's
assigned detection is the same person's), and triangulates each extra joint of each body from its assigned
detections with the run's robust triangulation (per-joint RANSAC, the same inlier threshold and minimum views).

An extra joint hangs from a joint of its body (:data:`~dome_calib.recon.body_models.EXTRA_BONE_CM`: a foot from its
ankle, the head top from the nose) and is checked as joints19's bones are
(:mod:`~dome_calib.recon.people.joint_check`): farther from it than ``max_bone_ratio`` x the nominal length +
``bone_slack_cm`` (40 cm for a big toe), or, where the body lacks that joint, seen by fewer than
``min_views_alone`` inlier views, it is dropped (two views always agree with each other). Without the check, a
synthetic crouching person's big toe came out 3 m from its ankle in one frame, and Pose2Sim's filtering and
kinematics took it.

Each time on its own: the extra joints are not part of the body over time (:mod:`~dome_calib.recon.people.temporal`
fits joints19), so they carry the per-frame triangulation's noise; Pose2Sim's filtering smooths a TRC before its
kinematics. But an extra joint whose views do not hold its depth (:func:`depth_unheld`: fewer than
``min_views_alone`` inlier views, two always agreeing, whose rays meet at less than 30 degrees) moves with its
anchor: the anchor is triangulated again from those same views, and where it meets in every one of them, the extra
joint is put at the body's anchor + its offset from that anchor (:func:`on_its_anchor`). Two close views put the
foot and its ankle off alike along their rays (the same cameras' bias on the same person): on the demo's tiny dome a
crouching person's ankles and feet are inside two cameras' images only, 10 degrees apart, and the feet came out 6-12
cm off where the body put the ankles 1-2 cm from the truth (the synthetic detector gives a foot its ankle's error
exactly, so there the offset is exact). Elsewhere an extra joint keeps its own triangulation: on Pose2Sim's real
balancing trial (4 cameras 55-130 degrees apart), moving every foot with its ankle put the toes and heels 1-5 px
farther from the cameras that agree, and moving those seen by two views only still 2.4 px for the right big toe (a
real foot's error is only partly its ankle's). Confidence: the mean detection confidence of the inlier views (-1:
not reconstructed).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from dome_calib.recon.body_models import EXTRA_BONE_CM, EXTRA_JOINTS, JOINTS19
from dome_calib.recon.people.assign import assigned_detections
from dome_calib.recon.people.resample import gather_people
from dome_calib.recon.people.run import PeopleOptions, PeopleSequence
from dome_calib.recon.people.sources import FileSource
from dome_calib.recon.project import ViewSet
from dome_calib.recon.triangulate import triangulate


@dataclass(frozen=True)
class ExtraJoints:
    """The extra joints of every body of every time: ``names`` (E,) joint names (the model's order);
    X_cm[t] (P_t, E, 3) world cm (NaN: not reconstructed), confidence[t] (P_t, E) (-1 there), n_inliers[t] (P_t, E);
    bodies in the order of ``PeopleSequence.bodies[t]``."""

    names: list[str]
    X_cm: list[np.ndarray]
    confidence: list[np.ndarray]
    n_inliers: list[np.ndarray]


def extra_joints(views: ViewSet, source: FileSource, seq: PeopleSequence, options: PeopleOptions, *,
                 progress: Callable[[int, int], None] | None = None) -> ExtraJoints | None:
    """The extra joints of the bodies of ``seq`` (see the module docstring); None when the model has none.

    views: the run's view set (the source's cameras, in its order); progress: ``progress(done, total)`` times.
    """
    names = EXTRA_JOINTS[source.body_model]
    if not names:
        return None
    src = replace(source, extras=True)  # what the run's first pass kept (its cache), else the files
    anchor = np.array([JOINTS19.index(EXTRA_BONE_CM[n][0]) for n in names])
    E, t = len(names), np.asarray(seq.times_ms, dtype=float)
    X, conf, inl = [], [], []
    for c0 in range(0, len(t), options.chunk_times):
        c1 = min(c0 + options.chunk_times, len(t))
        streams = src.chunk(float(t[c0]), float(t[c1 - 1]), options.max_gap_frames)
        for b0 in range(c0, c1, options.batch_times):
            b1 = min(b0 + options.batch_times, c1)
            bodies = seq.bodies[b0:b1]
            kp = gather_people(streams, t[b0:b1], options.max_gap_frames)  # (T, V, N, 19 + E, 3)
            V = kp.shape[1]
            assigned = [b.assigned.T if b.assigned is not None else np.full((V, len(b.ids)), -1) for b in bodies]
            uv, c = assigned_detections(kp[..., 19:, :], assigned)  # (B * E, V, 2), (B * E, V)
            tri = triangulate(views, uv, c, options.triangulation)
            # the anchor of each extra joint whose depth its views do not hold, triangulated from those views
            uv_a, c_a = assigned_detections(kp[..., anchor, :], assigned)
            loose = depth_unheld(views, tri.X_cm, tri.inliers, options.joint_check.min_views_alone)[:, None]
            tri_a = triangulate(views, uv_a, np.where(loose & tri.inliers, c_a, 0.0), options.triangulation)
            same = loose[:, 0] & (tri_a.n_inliers == tri.n_inliers)  # the anchor met in every one of those views
            sizes = np.cumsum([0] + [len(b.ids) for b in bodies])
            Xb = tri.X_cm.reshape(-1, E, 3)
            Xa = np.where(same[:, None], tri_a.X_cm, np.nan).reshape(-1, E, 3)
            cb, nb = tri.confidence.reshape(-1, E), tri.n_inliers.reshape(-1, E)
            for k in range(len(bodies)):
                sl = slice(sizes[k], sizes[k + 1])
                Xb[sl] = on_its_anchor(Xb[sl], Xa[sl], bodies[k].X_cm[:, anchor])
                keep = hangs_from_its_body(Xb[sl], nb[sl], bodies[k].X_cm, names, options)
                X.append(np.where(keep[..., None], Xb[sl], np.nan))
                conf.append(np.where(keep, cb[sl], -1.0))
                inl.append(np.where(keep, nb[sl], 0))
            if progress is not None:
                progress(b1, len(t))
    return ExtraJoints(names=list(names), X_cm=X, confidence=conf, n_inliers=inl)


#: Two views whose rays meet at less than this hold a point's depth less than twice as well as its side position
#: (1 / sin 30 deg = 2).
MAX_LOOSE_RAY_DEG = 30.0


def depth_unheld(views: ViewSet, X: np.ndarray, inliers: np.ndarray, min_views_alone: int) -> np.ndarray:
    """(P,) the points X (P, 3) triangulated from fewer than ``min_views_alone`` inlier views (``inliers`` (P, V);
    two views always agree) whose rays meet at less than MAX_LOOSE_RAY_DEG: their depth along the rays is what a
    pixel of bias makes it."""
    n = inliers.sum(1)
    out = np.zeros(len(X), bool)
    cand = np.flatnonzero((n >= 2) & (n < min_views_alone) & np.isfinite(X).all(1))
    if not len(cand):
        return out
    two = np.argsort(~inliers[cand], axis=1, kind="stable")[:, :2]  # the first two inlier views
    rays = X[cand, None, :] - views.center_cm[two]  # (K, 2, 3)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    cos = np.einsum("ki,ki->k", rays[:, 0], rays[:, 1])
    out[cand] = cos > np.cos(np.radians(MAX_LOOSE_RAY_DEG))
    return out


def on_its_anchor(X: np.ndarray, X_anchor: np.ndarray, body_anchor: np.ndarray) -> np.ndarray:
    """(P, E, 3) the extra joints X of P bodies moved as their anchors were: the body's anchor (``body_anchor``,
    the body over time) + the extra joint's offset from the anchor triangulated alone from the same views
    (``X_anchor``); X as it was where either anchor is missing."""
    moved = body_anchor + (X - X_anchor)
    return np.where(np.isfinite(moved).all(-1, keepdims=True), moved, X)


def hangs_from_its_body(X: np.ndarray, n_inliers: np.ndarray, body_cm: np.ndarray, names: list[str],
                         options: PeopleOptions) -> np.ndarray:
    """(P, E) keep each triangulated extra joint of P bodies (X (P, E, 3), body_cm (P, 19, 3) joints19): within
    ratio x nominal + slack of the joint it hangs from, or, that joint missing, seen by ``min_views_alone`` views."""
    check = options.joint_check
    anchor = np.array([JOINTS19.index(EXTRA_BONE_CM[n][0]) for n in names])
    limit = np.array([check.max_bone_ratio * EXTRA_BONE_CM[n][1] + check.bone_slack_cm for n in names])
    A = body_cm[:, anchor]  # (P, E, 3)
    have = np.isfinite(A).all(-1)
    with np.errstate(invalid="ignore"):
        near = np.linalg.norm(X - A, axis=-1) <= limit
    found = np.isfinite(X).all(-1)
    if not check.enabled:
        return found
    return found & np.where(have, near, n_inliers >= check.min_views_alone)
