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
   no floor; every other rule is the per-frame pass's, taken from where it lives: the leftover rule, the assignment
   and its ``passes`` rounds, ``min_person_views`` views (:mod:`~dome_calib.recon.people.assign`), then the per-time
   association's bodies stage (:func:`~dome_calib.recon.people.per_time.bodies_of`: robust triangulation, the joint
   check, the depth witness, ``min_body_joints`` joints); a body found is not within ``duplicate_cm`` of a body
   already there.
3. **One body per track** by the tracker's matching (Hungarian on the median joint distance to the predictions,
   quantised to :data:`~dome_calib.ties.SKELETON_DISTANCE_QUANTUM_CM`, as is the gate): it takes the track's id. No
   track starts here, so no false body can.

Each time is searched on its own, from the tracks (made once over the whole session) and that time's detections:
the result depends on neither chunks, batches nor workers. Cost: only the gaps' times, with the leftover detections.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from dome_calib import ties
from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.people.agreement import CameraAgreement
from dome_calib.recon.people.assign import assign, assign_passes, enough_views, leftover
from dome_calib.recon.people.bodies import Bodies
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.matching import gated_assignment, skeleton_distance_cm
from dome_calib.recon.people.options import PeopleOptions
from dome_calib.recon.people.per_time import bodies_of
from dome_calib.recon.people.proposals import (AssociationOptions, cluster_hypotheses, pair_hypotheses,
                                               residual_pairs, world_rays)
from dome_calib.recon.people.resample import gather_people
from dome_calib.recon.people.sources import FileSource, InMemorySource
from dome_calib.recon.people.tracking import TrackingOptions
from dome_calib.recon.project import ViewSet


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
    near = ties.below(skeleton_distance_cm(gap.X_cm, joints), gap.gate_cm[:, None],
                      ties.SKELETON_DISTANCE_QUANTUM_CM).any(0)
    no_floor = dataclasses.replace(options, min_cluster_weight=0.0, relative_cluster_weight=0.0)
    return cluster_hypotheses(centres[near], joints[near], weights[near], no_floor)


def gap_assignment(views: ViewSet, kernel: CameraKernel, kp: np.ndarray, A0: np.ndarray, gap: GapPredictions,
                   options: PeopleOptions) -> np.ndarray:
    """One gap's time: its detections kp (V, N, 19, 3) and the (V, P) assignment of the bodies already there ->
    the (V, P') assignment of the people found in the detections they left (:func:`~.assign.leftover`) near the
    tracks' predictions: assigned, then ``passes`` rounds (:func:`~.assign.assign_passes`), with the per-frame
    pass's own rules (module docstring, step 2)."""
    a = options.association
    none = np.zeros((len(views.names), 0), np.int64)
    left = leftover(kp, A0, a)
    has_left = left.any(1)
    if has_left.sum() < a.min_person_views:
        return none
    kp_left = np.where(left[..., None, None], kp, 0.0)
    S = _proposals_near(views, kernel, kp_left, has_left, gap, a)
    if not len(S):
        return none
    A = assign(kernel, S, kp_left, a)
    return assign_passes(views, kernel, kp_left[None], [A[:, enough_views(A, a)]], a,
                         min_body_joints=options.min_body_joints)[0]


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
                cameras: CameraAgreement, options: PeopleOptions, *, depth: DepthWitness | None = None
                ) -> tuple[list[Bodies], CameraAgreement]:
    """The tracked bodies of a whole session -> the same with the bodies found inside the tracks' gaps (module
    docstring), and the per-frame tallies with theirs. Reads the detections of the gaps' times only, in batches
    within ``batch_times`` consecutive times. The bodies come from the per-time association's own stage
    (:func:`~dome_calib.recon.people.per_time.bodies_of`: triangulation, joint check, depth witness, build)."""
    gaps = gap_predictions(times_ms, bodies, options.tracking)
    if not gaps:
        return bodies, cameras
    t = np.asarray(times_ms, dtype=float)
    views = views.subset(source.cameras)  # the order of the bodies' detection indices and of the tallies
    kernel = CameraKernel(views)
    a = options.association
    out = list(bodies)
    tallies = CameraAgreement.empty(list(views.names))
    for batch in gap_batches(gaps, options.batch_times):
        ks = np.array([g.k for g in batch])
        streams = source.chunk(float(t[ks[0]]), float(t[ks[-1]]), options.max_gap_frames)
        kp = gather_people(streams, t[ks], options.max_gap_frames)  # (B, V, N, 19, 3)
        assigned = [gap_assignment(views, kernel, kp_k, bodies[gap.k].assigned.T, gap, options)
                    for gap, kp_k in zip(batch, kp)]
        found = bodies_of(views, kp, assigned, options, times_ms=t[ks], depth=depth)
        taken_rows = np.zeros(len(found.kept), bool)
        rows_of = np.flatnonzero(found.kept)
        row = 0
        for gap, new in zip(batch, found.bodies):
            rows, row = rows_of[row: row + len(new.ids)], row + len(new.ids)
            if not len(new.ids):
                continue
            here = out[gap.k]
            step = ties.SKELETON_DISTANCE_QUANTUM_CM
            clash = ties.below(skeleton_distance_cm(new.X_cm, here.X_cm), a.duplicate_cm, step).any(1) \
                if len(here.ids) else np.zeros(len(new.ids), bool)
            cost = skeleton_distance_cm(gap.X_cm, new.X_cm)
            r, c = gated_assignment(cost, ties.below(cost, gap.gate_cm[:, None], step) & ~clash[None], step)
            if not len(c):
                continue
            order = np.argsort(c)
            r, c = r[order], c[order]
            out[gap.k] = _concat(here, new.take(c, gap.ids[r]))
            taken_rows[rows[c]] = True
        tallies.add(found.agreement(views, kp, taken_rows, a))
    # the gaps' times were counted by the per-frame pass already: only what the bodies found here used is added
    # (their depth verdicts are not counted: as before this stage was shared, cameras.json's depth figures are the
    # per-frame pass's)
    tallies.detected[:] = 0
    total = CameraAgreement.empty(list(cameras.names))
    total.add(cameras)
    total.add(tallies)
    return out, total
