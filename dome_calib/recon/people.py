"""Many people, no labels: OpenPose-style detections of every camera -> tracked 3D skeletons (joints19, world cm).

Per batch of universal times: every stream's people are brought to the times
(:func:`~dome_calib.recon.people_time.interpolate_people`); at each time the people are proposed and each view's
detections assigned to them (:mod:`dome_calib.recon.people_assoc`); with ``passes`` = 2 the assigned detections
are triangulated linearly (DLT) and assigned again against those skeletons; then all people of the batch are
triangulated in one call of the robust :func:`~dome_calib.recon.triangulate.triangulate`, each body keeps the
joints that agree with it (:func:`~dome_calib.recon.joint_check.check_joints`); duplicates merge.
Then :func:`~dome_calib.recon.tracking.track_bodies` gives ids. :func:`reconstruct_people` runs one chunk of times
in one process; :func:`reconstruct_people_chunked` splits a long session into overlapping chunks on an executor
and stitches ids.

The per-camera agreement (:class:`CameraAgreement`) counts, per camera, the people it detected and the ones used
by a reconstructed body, and a histogram of the pixel distance between its used joints and the reconstructed
joints: a camera that moved since calibration has a large median and a small share used.
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated
from fractions import Fraction

import numpy as np

from dome_calib.options import AtLeast, Field, PosFraction, options, require
from dome_calib.recon.errors import ReconError
from dome_calib.recon.joint_check import JointCheckOptions, check_joints
from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.people_assoc import (AssociationOptions, assign, propose, residual_pairs, select_pairs,
                                          world_rays)
from dome_calib.recon.people_time import FileSource, InMemorySource, PeopleStream, interpolate_people
from dome_calib.recon.project import ViewSet
from dome_calib.recon.tracking import (TrackingOptions, skeleton_distance_cm, smooth_track, stitch_chunks,
                                      track_bodies)
from dome_calib.recon.triangulate import (TriangulationOptions, reprojection_error_px, triangulate, triangulate_dlt,
                                         undistort_detections)

logger = logging.getLogger(__name__)

#: Histogram of reprojection errors per camera: bins of 0.1 px up to 200 px (the last bin holds everything above).
ERROR_BIN_PX = 0.1
ERROR_BINS = 2001


@options
class PeopleOptions:
    """Options of :func:`reconstruct_people`. joint_check: which triangulated joints a body keeps
    (:mod:`~dome_calib.recon.joint_check`); min_body_joints: a body needs this many reconstructed joints;
    max_gap_frames: stream brackets wider than this many frame periods are not bridged; batch_times: times
    triangulated together; chunk_times / overlap_times: the chunks of :func:`reconstruct_people_chunked`."""

    association: AssociationOptions = field(default_factory=AssociationOptions)
    triangulation: TriangulationOptions = field(default_factory=lambda: TriangulationOptions(
        inlier_threshold_px=10.0, min_views=2, min_confidence=0.05))
    tracking: TrackingOptions = field(default_factory=TrackingOptions)
    joint_check: JointCheckOptions = field(default_factory=JointCheckOptions)
    min_body_joints: AtLeast(1) = 6
    max_gap_frames: Annotated[float, Field(ge=1)] = 2.5
    batch_times: AtLeast(1) = 16
    chunk_times: AtLeast(1) = 600
    overlap_times: AtLeast(0) = 12
    shared_fps: PosFraction = Fraction(30)

    _overlap = require(lambda o: o.overlap_times < o.chunk_times, "overlap_times {o.overlap_times} must be below chunk_times {o.chunk_times}")


@dataclass(frozen=True)
class Bodies:
    """The people at one time: X_cm (P, 19, 3) (NaN = joint missing), confidence (P, 19) (-1 = missing),
    n_inliers (P, 19) supporting views, n_views (P,) views assigned, ids (P,) track ids."""

    X_cm: np.ndarray
    confidence: np.ndarray
    n_inliers: np.ndarray
    n_views: np.ndarray
    ids: np.ndarray


@dataclass
class CameraAgreement:
    """Per camera (``names`` order): detected (V,) people detected (with enough joints), used (V,) of them in a
    body, hist (V, ERROR_BINS) counts of |reprojection - detection| of the used joints in ERROR_BIN_PX bins."""

    names: list[str]
    detected: np.ndarray
    used: np.ndarray
    hist: np.ndarray

    @classmethod
    def empty(cls, names: list[str]) -> CameraAgreement:
        V = len(names)
        return cls(names, np.zeros(V, np.int64), np.zeros(V, np.int64), np.zeros((V, ERROR_BINS), np.int64))

    def add(self, other: CameraAgreement) -> None:
        self.detected += other.detected
        self.used += other.used
        self.hist += other.hist

    def median_px(self) -> np.ndarray:
        """(V,) median reprojection error of each camera's used joints (NaN if none), to the bin centre."""
        n = self.hist.sum(1)
        cum = np.cumsum(self.hist, axis=1)
        k = np.argmax(cum >= (n[:, None] + 1) // 2, axis=1)
        return np.where(n > 0, (k + 0.5) * ERROR_BIN_PX, np.nan)


@dataclass
class PeopleSequence:
    """times_ms (T,), bodies[t] (:class:`Bodies`), cameras (:class:`CameraAgreement`)."""

    times_ms: np.ndarray
    bodies: list[Bodies]
    cameras: CameraAgreement


def _gather_people(streams: list[PeopleStream], times: np.ndarray, max_gap_frames: float) -> np.ndarray:
    """All streams' people at the times -> (T, V, N, 19, 3) (views in stream order)."""
    parts = [interpolate_people(s, times, max_gap_frames=max_gap_frames) for s in streams]
    N = max(p.shape[2] for p in parts)
    return np.concatenate([np.pad(p, ((0, 0), (0, 0), (0, N - p.shape[2]), (0, 0), (0, 0))) for p in parts], axis=1)


def _gather_assigned(kp: np.ndarray, assigned: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The assigned detections of every proposal of every time: uv (sum P * 19, V, 2) (NaN = none), conf."""
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


def _linear_skeletons(views: ViewSet, kernel: CameraKernel, kp: np.ndarray, assigned: list[np.ndarray]
                      ) -> np.ndarray:
    """Weighted linear (DLT) triangulation of the assigned detections: (sum P, 19, 3) cm, for assigning again
    (outliers are not removed here: the assignment caps each joint's cost)."""
    uv, conf = _gather_assigned(kp, assigned)
    valid = conf > 0
    xn = undistort_detections(kernel, np.nan_to_num(uv), valid)
    return triangulate_dlt(views, xn, np.where(valid, conf, 0.0)).reshape(-1, 19, 3)


def _dedupe(X: np.ndarray, n_inl: np.ndarray, duplicate_cm: float) -> np.ndarray:
    """(P,) keep mask: of skeletons closer than ``duplicate_cm`` (median joint distance) the best supported stays
    (most inlier views, or joints for proposals; ties by order)."""
    P = len(X)
    keep = np.ones(P, bool)
    if P < 2:
        return keep
    d = skeleton_distance_cm(X, X)
    for i in np.lexsort((np.arange(P), -n_inl.sum(1))):
        if keep[i]:
            dup = d[i] < duplicate_cm
            dup[i] = False
            keep &= ~dup
    return keep


def _residual(views: ViewSet, kernel: CameraKernel, kp: np.ndarray, skeletons: np.ndarray, A: np.ndarray,
              a: AssociationOptions, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Proposals from the detections that no proposal took (see :mod:`~dome_calib.recon.people_assoc`, step 4):
    (V, P) assignment -> (V, P + P_new) and the (P + P_new, 19, 3) skeletons."""
    V, N = kp.shape[:2]
    taken = np.zeros((V, N), bool)
    v, p = np.nonzero(A >= 0)
    taken[v, A[v, p]] = True
    left = ~taken & ((kp[..., 2] > a.min_joint_conf).sum(-1) >= a.min_common_joints)
    has_left = left.any(1)
    if has_left.sum() < a.min_person_views:
        return A, skeletons
    kp_left = np.where(left[..., None, None], kp, 0.0)
    new = propose(views, kernel, kp_left, residual_pairs(views, has_left, a.max_pairs), a, rays)
    if len(new) == 0:
        return A, skeletons
    B = assign(kernel, new, kp_left, a)
    keep = (B >= 0).sum(0) >= a.min_person_views
    return np.concatenate([A, B[:, keep]], axis=1), np.concatenate([skeletons, new[keep]])


def associate_batch(views: ViewSet, kernel: CameraKernel, pairs: np.ndarray, kp: np.ndarray,
                    options: PeopleOptions) -> tuple[list[Bodies], CameraAgreement]:
    """(T, V, N, 19, 3) people at T times -> the bodies of each time (ids -1) and the cameras' agreement."""
    a = options.association
    T, V = kp.shape[:2]
    rays = [world_rays(views, kernel, kp[t]) for t in range(T)]
    skeletons = [propose(views, kernel, kp[t], pairs, a, rays[t]) for t in range(T)]
    skeletons = [S[_dedupe(S, np.isfinite(S).all(-1), a.duplicate_cm)] for S in skeletons]
    assigned = []
    for t in range(T):
        A = assign(kernel, skeletons[t], kp[t], a)
        A, skeletons[t] = _residual(views, kernel, kp[t], skeletons[t], A, a, rays[t])
        assigned.append(A[:, (A >= 0).sum(0) >= a.min_person_views])
    for _ in range(a.passes - 1):  # assign again against linear triangulations of the assigned detections
        X = _linear_skeletons(views, kernel, kp, assigned)
        sizes = np.cumsum([0] + [A.shape[1] for A in assigned])
        for t in range(T):
            S = X[sizes[t]: sizes[t + 1]]
            S = S[np.isfinite(S).all(-1).sum(1) >= options.min_body_joints]
            S = S[_dedupe(S, np.isfinite(S).all(-1), a.duplicate_cm)]
            A = assign(kernel, S, kp[t], a)
            assigned[t] = A[:, (A >= 0).sum(0) >= a.min_person_views]
    uv, c = _gather_assigned(kp, assigned)
    tri = triangulate(views, uv, c, options.triangulation)
    sizes = np.cumsum([0] + [A.shape[1] for A in assigned])
    ok = check_joints(tri.X_cm.reshape(-1, 19, 3), tri.n_inliers.reshape(-1, 19), options.joint_check).reshape(-1)
    X_flat = np.where(ok[:, None], tri.X_cm, np.nan)
    X = X_flat.reshape(-1, 19, 3)
    n_inl = np.where(ok, tri.n_inliers, 0).reshape(-1, 19)
    keeps = []
    for t in range(T):
        sl = slice(sizes[t], sizes[t + 1])
        keep = (np.isfinite(X[sl]).all(-1).sum(1) >= options.min_body_joints)
        keep &= _dedupe(X[sl], n_inl[sl], a.duplicate_cm)
        keeps.append(keep)
    conf = np.where(ok, tri.confidence, -1.0).reshape(-1, 19)
    n_views = np.concatenate([(A >= 0).sum(0) for A in assigned]) if assigned else np.zeros(0, np.int64)
    bodies = []
    for t in range(T):
        sl = slice(sizes[t], sizes[t + 1])
        k = keeps[t]
        bodies.append(Bodies(X_cm=X[sl][k], confidence=conf[sl][k], n_inliers=n_inl[sl][k], n_views=n_views[sl][k],
                             ids=np.full(int(k.sum()), -1, dtype=np.int64)))
    agreement = CameraAgreement.empty(list(views.names))
    detected = (kp[..., 2] > a.min_joint_conf).sum(-1) >= a.min_common_joints  # (T, V, N)
    agreement.detected += detected.sum(axis=(0, 2))
    err = reprojection_error_px(views, np.nan_to_num(X_flat), np.nan_to_num(uv))  # (sumP*19, V)
    used_joint = np.isfinite(uv[..., 0]) & np.isfinite(X_flat).all(1)[:, None] & np.isfinite(err)
    keep_all = np.concatenate(keeps) if keeps else np.zeros(0, bool)
    used_joint &= np.repeat(keep_all, 19)[:, None]
    for v in np.flatnonzero(used_joint.any(0)):
        b = np.minimum((err[used_joint[:, v], v] / ERROR_BIN_PX).astype(np.int64), ERROR_BINS - 1)
        agreement.hist[v] += np.bincount(b, minlength=ERROR_BINS)
    used_person = np.concatenate([(A >= 0).T for A in assigned]) if assigned else np.zeros((0, V), bool)
    agreement.used += used_person[keep_all].sum(0) if len(used_person) else 0
    return bodies, agreement


def reconstruct_people(views: ViewSet, streams: list[PeopleStream], times_ms: np.ndarray,
                       options: PeopleOptions | None = None, *,
                       progress: Callable[[int, int], None] | None = None) -> PeopleSequence:
    """Tracked people at (T,) universal times from the streams' unlabelled detections (one process).

    Args:
        views: holds every camera of ``streams``; streams: from :func:`~dome_calib.recon.people_time.people_streams`.
        progress: ``progress(done_times, total_times)`` after each batch.
    Returns:
        :class:`PeopleSequence`; ids from 0 in order of first appearance.
    Example:
        >>> seq = reconstruct_people(view_set(bundle, names), people_streams(bundle, det.people), vga_times_ms)
    """
    options = options or PeopleOptions()
    t = np.asarray(times_ms, dtype=float)
    names = [n for s in streams for n in s.cameras]
    sub = views.subset(names)
    kernel = CameraKernel(sub)
    pairs = select_pairs(sub, options.association.max_pairs)
    bodies: list[Bodies] = []
    agreement = CameraAgreement.empty(names)
    for start in range(0, len(t), options.batch_times):
        sl = slice(start, min(start + options.batch_times, len(t)))
        kp = _gather_people(streams, t[sl], options.max_gap_frames)
        got, agree = associate_batch(sub, kernel, pairs, kp, options)
        bodies += got
        agreement.add(agree)
        if progress is not None:
            progress(sl.stop, len(t))
    bodies = _track(t, bodies, options.tracking)
    return PeopleSequence(times_ms=t, bodies=bodies, cameras=agreement)


def _track(times: np.ndarray, bodies: list[Bodies], options: TrackingOptions) -> list[Bodies]:
    """Ids by :func:`track_bodies`; bodies of dropped tracks removed; optional smoothing per track."""
    ids = track_bodies(times, [b.X_cm for b in bodies], options)
    out = []
    for b, i in zip(bodies, ids):
        k = i >= 0
        out.append(Bodies(X_cm=b.X_cm[k], confidence=b.confidence[k], n_inliers=b.n_inliers[k],
                          n_views=b.n_views[k], ids=i[k]))
    if options.smooth_half_window > 0:
        for tid in sorted({int(x) for b in out for x in b.ids}):
            where = [(k, int(np.flatnonzero(b.ids == tid)[0])) for k, b in enumerate(out) if np.any(b.ids == tid)]
            X = np.stack([out[k].X_cm[p] for k, p in where])
            Xs = smooth_track(times[[k for k, _ in where]], X, options.smooth_half_window)
            for (k, p), x in zip(where, Xs):
                out[k].X_cm[p] = x
    return out


def _chunk_task(args: tuple) -> tuple[int, PeopleSequence]:
    """Executor task: one chunk of times (module level, picklable); reads the chunk's detections from ``source``."""
    index, views, source, times, options = args
    streams = source.chunk(float(times[0]), float(times[-1]), options.max_gap_frames)
    return index, reconstruct_people(views, streams, times, options)


def reconstruct_people_chunked(views: ViewSet, source: list[PeopleStream] | InMemorySource | FileSource,
                               times_ms: np.ndarray, options: PeopleOptions | None = None, *, executor=None,
                               progress: Callable[[int, int], None] | None = None) -> PeopleSequence:
    """:func:`reconstruct_people` over chunks of ``chunk_times`` times that overlap by ``overlap_times``, run on
    ``executor`` (``map``; a local pool or Dask; None: in this process); ids stitched over the overlaps
    (:func:`~dome_calib.recon.tracking.stitch_chunks`), new ones numbered on, never reused.

    source: the streams, or a :class:`~dome_calib.recon.people_time.FileSource` whose chunks each task reads from
    disk itself (only the frames that bracket the chunk's times).
    """
    options = options or PeopleOptions()
    source = InMemorySource(source) if isinstance(source, list) else source
    t = np.asarray(times_ms, dtype=float)
    step = options.chunk_times
    if len(t) <= step + options.overlap_times:
        streams = source.chunk(float(t[0]), float(t[-1]), options.max_gap_frames) if len(t) else []
        return reconstruct_people(views, streams, t, options, progress=progress)
    starts = list(range(0, len(t), step))
    if len(t) - starts[-1] <= options.overlap_times:
        starts.pop()  # the previous chunk's overlap already reaches the end
    # Short tracks are dropped after stitching: a track cut by a chunk boundary is short only in its chunk.
    chunk_options = dataclasses.replace(options, tracking=dataclasses.replace(options.tracking, drop_short=False))
    tasks = []
    for i, s in enumerate(starts):
        times = t[s: min(s + step + options.overlap_times, len(t))]
        tasks.append((i, views, source, times, chunk_options))
    results: dict[int, PeopleSequence] = {}
    runner = map if executor is None else executor.map
    for index, seq in runner(_chunk_task, tasks):
        results[index] = seq
        if progress is not None:
            progress(min(sum(len(results[k].times_ms) for k in results), len(t)), len(t))
    bodies: list[Bodies] = []
    agreement = CameraAgreement.empty(results[0].cameras.names)
    next_id = 0
    prev_map: dict[int, int] = {}
    for i, s in enumerate(starts):
        seq = results[i]
        if i == 0:
            local = sorted({int(x) for b in seq.bodies for x in b.ids})
            id_map = {k: next_id + n for n, k in enumerate(local)}
        else:
            prev, ov = results[i - 1], options.overlap_times
            tail = prev.bodies[step: step + ov]
            head = seq.bodies[: len(tail)]
            match = stitch_chunks([b.X_cm for b in tail], [b.ids for b in tail], [b.X_cm for b in head],
                                  [b.ids for b in head], options.tracking.gate_cm)
            id_map = {}
            for k in sorted({int(x) for b in seq.bodies for x in b.ids}):
                if k in match and match[k] in prev_map:
                    id_map[k] = prev_map[match[k]]
                else:
                    id_map[k] = next_id
                    next_id += 1
        next_id = max([next_id] + [v + 1 for v in id_map.values()])
        prev_map = id_map
        own = seq.bodies[:step] if i < len(starts) - 1 else seq.bodies
        bodies += [Bodies(X_cm=b.X_cm, confidence=b.confidence, n_inliers=b.n_inliers, n_views=b.n_views,
                          ids=np.array([id_map[int(x)] for x in b.ids], dtype=np.int64)) for b in own]
        agreement.add(seq.cameras)
    return PeopleSequence(times_ms=t, bodies=_drop_short(bodies, options.tracking.min_track_frames), cameras=agreement)


def _drop_short(bodies: list[Bodies], min_frames: int) -> list[Bodies]:
    """Bodies of tracks seen at fewer than ``min_frames`` times removed; ids renumbered 0, 1, ... in order of first
    appearance (ids stay unique: a removed track's id is not given to anyone)."""
    all_ids = np.concatenate([b.ids for b in bodies] + [np.zeros(0, np.int64)])
    uniq, counts = np.unique(all_ids, return_counts=True)
    keep = set(uniq[counts >= min_frames].tolist())
    first = {}
    for b in bodies:
        for i in b.ids:
            if int(i) in keep and int(i) not in first:
                first[int(i)] = len(first)
    out = []
    for b in bodies:
        k = np.array([int(i) in keep for i in b.ids], dtype=bool)
        out.append(Bodies(X_cm=b.X_cm[k], confidence=b.confidence[k], n_inliers=b.n_inliers[k],
                          n_views=b.n_views[k], ids=np.array([first[int(i)] for i in b.ids[k]], dtype=np.int64)))
    return out
