"""From assigned detections to the bodies of each time: robust triangulation, then one body per person.

:func:`triangulate_people` triangulates every assigned person of a batch of times in one call of the robust
:func:`~dome_calib.recon.triangulate.triangulate` (per-joint RANSAC removes swapped joints and borrowed limbs, then
weighted LM). The joint check (:func:`~dome_calib.recon.people.joint_check.check_joints`) then says which joints
each body keeps, and :func:`build_bodies` keeps the people with at least ``min_body_joints`` joints, one of any two
closer than ``duplicate_cm`` (the best supported), each time's bodies still without ids (tracking gives them).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.recon.people.assign import assigned_detections
from dome_calib.recon.people.compiled import assigned_records
from dome_calib.recon.people.matching import dedupe
from dome_calib.recon.project import ViewSet
from dome_calib.recon.triangulate import TriangulationOptions, triangulate


@dataclass(frozen=True)
class Bodies:
    """The people at one time: X_cm (P, 19, 3) (NaN = joint missing), confidence (P, 19) (-1 = missing),
    n_inliers (P, 19) supporting views, n_views (P,) views assigned, ids (P,) track ids (-1 before tracking);
    assigned (P, V) int16: each body's detection in each view at its time (the index among that view's people as
    :func:`~dome_calib.recon.people.resample.gather_people` orders them, -1: none; None: not kept), from which the
    body over time reads its detections again (:func:`observations_of`)."""

    X_cm: np.ndarray
    confidence: np.ndarray
    n_inliers: np.ndarray
    n_views: np.ndarray
    ids: np.ndarray
    assigned: np.ndarray | None = None

    def take(self, keep: np.ndarray, ids: np.ndarray | None = None) -> Bodies:
        """The bodies selected by ``keep`` (a mask or indices), with new ``ids`` if given."""
        return Bodies(X_cm=self.X_cm[keep], confidence=self.confidence[keep], n_inliers=self.n_inliers[keep],
                      n_views=self.n_views[keep], ids=self.ids[keep] if ids is None else ids,
                      assigned=None if self.assigned is None else self.assigned[keep])


@dataclass(frozen=True)
class Observations:
    """The detections behind bodies, one record per (body row, view, joint) with a detection: row (M,) int32, view
    (M,) int16, joint (M,) int8; uv_px (M, 2) float32 pixels; conf (M,) float32 detection confidence in (0, 1]
    (OpenPose's values above 1 clipped); strong (M,) bool: among its joint's most confident detections (see
    :func:`observations_of`). Rows number the bodies in time order (then in their order at a time); records are
    sorted by row, then view, then joint. 19 bytes a record."""

    row: np.ndarray
    view: np.ndarray
    joint: np.ndarray
    uv_px: np.ndarray
    conf: np.ndarray
    strong: np.ndarray

    @staticmethod
    def concat(parts: list[Observations]) -> Observations:
        fields = ("row", "view", "joint", "uv_px", "conf", "strong")
        if not parts:
            return Observations(row=np.zeros(0, np.int32), view=np.zeros(0, np.int16), joint=np.zeros(0, np.int8),
                                uv_px=np.zeros((0, 2), np.float32), conf=np.zeros(0, np.float32),
                                strong=np.zeros(0, bool))
        return Observations(*(np.concatenate([getattr(o, f) for o in parts]) for f in fields))


@dataclass(frozen=True)
class PeopleTriangulation:
    """Every assigned person of a batch of T times, triangulated (B people in all; time t's are rows
    ``sizes[t]:sizes[t + 1]``): X_cm (B, 19, 3) (NaN = not reconstructed), confidence (B, 19) (-1 = not
    reconstructed), n_inliers (B, 19); the detections used: uv_px (B * 19, V, 2) (NaN = none), conf (B * 19, V);
    assigned (B, V) int16: the person's detection in each view (index into the batch's people, -1: none)."""

    sizes: np.ndarray
    X_cm: np.ndarray
    confidence: np.ndarray
    n_inliers: np.ndarray
    uv_px: np.ndarray
    conf: np.ndarray
    assigned: np.ndarray


def triangulate_people(views: ViewSet, kp: np.ndarray, assigned: list[np.ndarray],
                       options: TriangulationOptions) -> PeopleTriangulation:
    """kp (T, V, N, 19, 3) and the assignment of each time (V, P_t) -> :class:`PeopleTriangulation` (one robust
    triangulation call for the whole batch)."""
    uv, c = assigned_detections(kp, assigned)
    tri = triangulate(views, uv, c, options)
    V = kp.shape[1]
    return PeopleTriangulation(
        sizes=np.cumsum([0] + [A.shape[1] for A in assigned]), X_cm=tri.X_cm.reshape(-1, 19, 3),
        confidence=tri.confidence.reshape(-1, 19), n_inliers=tri.n_inliers.reshape(-1, 19), uv_px=uv, conf=c,
        assigned=np.concatenate([A.T for A in assigned]).astype(np.int16) if assigned else np.zeros((0, V), np.int16))


def build_bodies(tri: PeopleTriangulation, ok: np.ndarray, *, min_body_joints: int, duplicate_cm: float
                 ) -> tuple[list[Bodies], np.ndarray]:
    """The bodies of each time from the triangulation and the joints it keeps (``ok`` (B, 19), the joint check's).

    Returns the bodies per time (ids -1, with their assigned detections) and the (B,) mask of the triangulated
    people that became bodies.
    """
    X = np.where(ok[..., None], tri.X_cm, np.nan)
    n_inl = np.where(ok, tri.n_inliers, 0)
    conf = np.where(ok, tri.confidence, -1.0)
    n_views = (tri.assigned >= 0).sum(1)
    bodies, keeps = [], []
    for t in range(len(tri.sizes) - 1):
        sl = slice(tri.sizes[t], tri.sizes[t + 1])
        keep = np.isfinite(X[sl]).all(-1).sum(1) >= min_body_joints
        keep &= dedupe(X[sl], n_inl[sl], duplicate_cm)
        keeps.append(keep)
        bodies.append(Bodies(X_cm=X[sl][keep], confidence=conf[sl][keep], n_inliers=n_inl[sl][keep],
                             n_views=n_views[sl][keep], ids=np.full(int(keep.sum()), -1, dtype=np.int64),
                             assigned=tri.assigned[sl][keep]))
    return bodies, np.concatenate(keeps) if keeps else np.zeros(0, bool)


def observations_of(kp: np.ndarray, bodies: list[Bodies], first_row: int = 0, *, strongest: int) -> Observations:
    """The detections assigned to the bodies of T times, read again from the people there: kp (T, V, N, 19, 3)
    (:func:`~dome_calib.recon.people.resample.gather_people` at the bodies' times), bodies[t] with ``assigned``;
    rows numbered from ``first_row`` in time order. Every detection, inlier of the triangulation or not (the body
    over time judges them again); ``strong`` marks each joint's ``strongest`` most confident ones (ties: the lower
    view index; confidences compared in steps of 1e-4). One compiled pass
    (:func:`~dome_calib.recon.people.compiled.assigned_records`)."""
    A = np.concatenate([b.assigned for b in bodies] + [np.zeros((0, kp.shape[1]), np.int16)])  # (B, V)
    time_of = np.repeat(np.arange(len(bodies)), [len(b.ids) for b in bodies])
    body, view, joint, uv, conf, strong = assigned_records(kp, time_of, A, strongest)
    return Observations(row=body + np.int32(first_row), view=view, joint=joint, uv_px=uv, conf=conf, strong=strong)
