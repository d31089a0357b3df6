"""A tracked person through thin evidence: the times inside a track's gaps searched again with the track's prediction.

The per-frame pass proposes a person only from a cluster of pair hypotheses whose common joints add up to
``min_cluster_weight``: far fewer, and crossing rays of the people around would make ghosts. A person who shows a
few views only part of his body (close to a panel: his face and one arm) can fall below that for several times in a
row, while he is tracked before and after. There the track is the evidence the floor stands for: after tracking
(once over the whole session), at every time inside a track's gap (:func:`gap_predictions`):

1. **The prediction.** The tracker's motion model (the whole body at constant velocity) between the track's bodies
   on both sides of the gap: each joint interpolated, a joint missing on one side carried by the body's median
   displacement. The gate is the tracker's own: ``gate_cm + gate_cm_per_s x elapsed`` (elapsed from the nearer
   side), so a body found here is one the tracker would have linked to the track.
2. **Hypotheses from the detections no body took** (:func:`~dome_calib.recon.people.proposals.pair_hypotheses` over
   :func:`~dome_calib.recon.people.proposals.residual_pairs`: the same ray-gap gate, common joints and bones as the
   per-frame pass, all from the detector's measured noise). Those within the gate of a prediction are clustered with
   no floor; every other rule is the per-frame pass's: assignment (``passes`` rounds), ``min_person_views`` views,
   robust triangulation, the joint check, the depth witness, ``min_body_joints`` joints, not within
   ``duplicate_cm`` of a body already there.
3. **One body per track** by the tracker's matching (Hungarian on the median joint distance to the predictions,
   quantised to 0.001 cm, gated): it takes the track's id. No track starts here, so no false body can.

Each time is searched on its own, from the tracks (made once over the whole session) and that time's detections:
the result depends on neither chunks, batches nor workers. Cost: only the gaps' times, with the leftover detections.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import linear_sum_assignment

from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.people.agreement import CameraAgreement, tally_agreement
from dome_calib.recon.people.assign import assign, linear_skeletons
from dome_calib.recon.people.bodies import Bodies, build_bodies, triangulate_people
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.joint_check import JointCheckOptions, check_joints
from dome_calib.recon.people.matching import dedupe, skeleton_distance_cm
from dome_calib.recon.people.proposals import (AssociationOptions, cluster_hypotheses, pair_hypotheses,
                                               residual_pairs, world_rays)
from dome_calib.recon.people.resample import gather_people
from dome_calib.recon.people.sources import FileSource, InMemorySource
from dome_calib.recon.people.tracking import TrackingOptions
from dome_calib.recon.project import ViewSet
from dome_calib.recon.triangulate import TriangulationOptions


@dataclasses.dataclass(frozen=True)
class GapPredictions:
    """The tracks missing at one time (index ``k`` into the session's times): ids (G,), predicted skeletons
    X_cm (G, 19, 3) (NaN: unknown joint), gate_cm (G,) the tracker's gate at that time."""

    k: int
    ids: np.ndarray
    X_cm: np.ndarray
    gate_cm: np.ndarray


def gap_predictions(times_ms: np.ndarray, bodies: list[Bodies], options: TrackingOptions) -> list[GapPredictions]:
    """Every time inside a track's gap (the track has bodies before and after it), in time order, with each missing
    track's prediction (module docstring, step 1)."""
    t = np.asarray(times_ms, dtype=float)
    where: dict[int, list[tuple[int, int]]] = {}
    for k, b in enumerate(bodies):
        for row, tid in enumerate(b.ids):
            where.setdefault(int(tid), []).append((k, row))
    per_time: dict[int, list[tuple[int, np.ndarray, float]]] = {}
    for tid in sorted(where):
        for (ka, ra), (kb, rb) in zip(where[tid], where[tid][1:]):
            if kb - ka < 2:
                continue
            Xa, Xb = bodies[ka].X_cm[ra], bodies[kb].X_cm[rb]
            both = np.isfinite(Xa).all(-1) & np.isfinite(Xb).all(-1)
            shift = np.median(Xb[both] - Xa[both], axis=0) if both.any() else np.zeros(3)
            for k in range(ka + 1, kb):
                w = (t[k] - t[ka]) / (t[kb] - t[ka])
                X = np.where(both[:, None], Xa + w * (Xb - Xa), np.where(np.isfinite(Xa), Xa + w * shift,
                                                                         Xb - (1.0 - w) * shift))
                elapsed_ms = min(t[k] - t[ka], t[kb] - t[k])
                per_time.setdefault(k, []).append(
                    (tid, X, options.gate_cm + options.gate_cm_per_s * 1e-3 * elapsed_ms))
    return [GapPredictions(k=k, ids=np.array([g[0] for g in per_time[k]], dtype=np.int64),
                           X_cm=np.stack([g[1] for g in per_time[k]]),
                           gate_cm=np.array([g[2] for g in per_time[k]])) for k in sorted(per_time)]


def _proposals_near(views: ViewSet, kernel: CameraKernel, kp_left: np.ndarray, has_left: np.ndarray,
                    gap: GapPredictions, options: AssociationOptions) -> np.ndarray:
    """(P, 19, 3) proposals from the leftover detections of one time whose pair hypotheses lie within the gate of a
    prediction (clustered with no floor: the track stands for it)."""
    rays = world_rays(views, kernel, kp_left)
    centres, joints, weights = pair_hypotheses(views, rays, kp_left, residual_pairs(views, has_left,
                                                                                   options.max_pairs), options)
    if not len(joints):
        return np.zeros((0, 19, 3))
    d = np.round(skeleton_distance_cm(gap.X_cm, joints), 3)
    near = (d < gap.gate_cm[:, None]).any(0)
    no_floor = dataclasses.replace(options, min_cluster_weight=0.0, relative_cluster_weight=0.0)
    return cluster_hypotheses(centres[near], joints[near], weights[near], no_floor)


def _assign_left(views: ViewSet, kernel: CameraKernel, kp_left: np.ndarray, S: np.ndarray,
                 options: AssociationOptions, min_body_joints: int) -> np.ndarray:
    """The leftover detections assigned to the proposals, ``passes`` rounds as the per-frame pass
    (:func:`~dome_calib.recon.people.assign.associate`) -> (V, P) with ``min_person_views`` views each."""
    A = assign(kernel, S, kp_left, options)
    A = A[:, (A >= 0).sum(0) >= options.min_person_views]
    for _ in range(options.passes - 1):
        X = linear_skeletons(views, kernel, kp_left[None], [A])
        X = X[np.isfinite(X).all(-1).sum(1) >= min_body_joints]
        X = X[dedupe(X, np.isfinite(X).all(-1), options.duplicate_cm)]
        A = assign(kernel, X, kp_left, options)
        A = A[:, (A >= 0).sum(0) >= options.min_person_views]
    return A


def gap_batches(gaps: list[GapPredictions], batch_times: int) -> list[list[GapPredictions]]:
    """The gaps' times in batches within ``batch_times`` consecutive times of the session (a batch reads the frames
    that bracket its span only: gaps an hour apart are never read together)."""
    out: list[list[GapPredictions]] = []
    for gap in gaps:
        if out and gap.k - out[-1][0].k < batch_times:
            out[-1].append(gap)
        else:
            out.append([gap])
    return out


def _concat(a: Bodies, b: Bodies) -> Bodies:
    return Bodies(X_cm=np.concatenate([a.X_cm, b.X_cm]), confidence=np.concatenate([a.confidence, b.confidence]),
                  n_inliers=np.concatenate([a.n_inliers, b.n_inliers]),
                  n_views=np.concatenate([a.n_views, b.n_views]), ids=np.concatenate([a.ids, b.ids]),
                  assigned=np.concatenate([a.assigned, b.assigned]))


def bridge_gaps(views: ViewSet, source: InMemorySource | FileSource, times_ms: np.ndarray, bodies: list[Bodies],
                cameras: CameraAgreement, *, association: AssociationOptions, triangulation: TriangulationOptions,
                joint_check: JointCheckOptions, tracking: TrackingOptions, min_body_joints: int,
                max_gap_frames: float, batch_times: int, depth: DepthWitness | None = None
                ) -> tuple[list[Bodies], CameraAgreement]:
    """The tracked bodies of a whole session -> the same with the bodies found inside the tracks' gaps (module
    docstring), and the per-frame tallies with theirs. Reads the detections of the gaps' times only, in batches
    within ``batch_times`` consecutive times."""
    gaps = gap_predictions(times_ms, bodies, tracking)
    if not gaps:
        return bodies, cameras
    t = np.asarray(times_ms, dtype=float)
    views = views.subset(source.cameras)  # the order of the bodies' detection indices and of the tallies
    kernel = CameraKernel(views)
    a = association
    out = list(bodies)
    tallies = CameraAgreement.empty(list(views.names))
    for batch in gap_batches(gaps, batch_times):
        ks = np.array([g.k for g in batch])
        streams = source.chunk(float(t[ks[0]]), float(t[ks[-1]]), max_gap_frames)
        kp = gather_people(streams, t[ks], max_gap_frames)  # (B, V, N, 19, 3)
        assigned = []
        for gap, kp_k in zip(batch, kp):
            taken = np.zeros(kp_k.shape[:2], bool)
            A0 = bodies[gap.k].assigned.T  # (V, P)
            v, p = np.nonzero(A0 >= 0)
            taken[v, A0[v, p]] = True
            left = ~taken & ((kp_k[..., 2] > a.min_joint_conf).sum(-1) >= a.min_common_joints)
            has_left = left.any(1)
            if has_left.sum() < a.min_person_views:
                assigned.append(np.zeros((len(views.names), 0), np.int64))
                continue
            kp_left = np.where(left[..., None, None], kp_k, 0.0)
            S = _proposals_near(views, kernel, kp_left, has_left, gap, a)
            assigned.append(_assign_left(views, kernel, kp_left, S, a, min_body_joints) if len(S)
                            else np.zeros((len(views.names), 0), np.int64))
        tri = triangulate_people(views, kp, assigned, triangulation)
        ok = check_joints(tri.X_cm, tri.n_inliers, joint_check)
        if depth is not None:
            for j, k in enumerate(ks):
                sl = slice(tri.sizes[j], tri.sizes[j + 1])
                ok[sl] &= depth.keep(np.where(ok[sl, :, None], tri.X_cm[sl], np.nan), float(t[k]))
        found, kept = build_bodies(tri, ok, min_body_joints=min_body_joints, duplicate_cm=a.duplicate_cm)
        taken_rows = np.zeros(len(kept), bool)
        rows_of = np.flatnonzero(kept)
        row = 0
        for gap, new in zip(batch, found):
            rows, row = rows_of[row: row + len(new.ids)], row + len(new.ids)
            if not len(new.ids):
                continue
            here = out[gap.k]
            clash = (skeleton_distance_cm(new.X_cm, here.X_cm) < a.duplicate_cm).any(1) if len(here.ids) else \
                np.zeros(len(new.ids), bool)
            cost = np.round(skeleton_distance_cm(gap.X_cm, new.X_cm), 3)
            cost = np.where((cost < gap.gate_cm[:, None]) & ~clash[None], cost, 1e6)
            r, c = linear_sum_assignment(cost)
            good = cost[r, c] < 1e6
            r, c = r[good], c[good]
            if not len(c):
                continue
            order = np.argsort(c)
            r, c = r[order], c[order]
            out[gap.k] = _concat(here, new.take(c, gap.ids[r]))
            taken_rows[rows[c]] = True
        tallies.add(tally_agreement(views, kp, tri, ok, taken_rows, min_joint_conf=a.min_joint_conf,
                                    min_common_joints=a.min_common_joints))
    # the gaps' times were counted by the per-frame pass already: only what the bodies found here used is added
    tallies.detected[:] = 0
    total = CameraAgreement.empty(list(cameras.names))
    total.add(cameras)
    total.add(tallies)
    return out, total
