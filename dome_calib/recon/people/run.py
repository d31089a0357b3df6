"""Many people, no labels: OpenPose-style detections of every camera -> tracked 3D skeletons (joints19, world cm).

The run, in the order the data flows (each step a function of its own module, testable alone):

1. :func:`~dome_calib.recon.people.resample.gather_people`: every stream's people at a batch of universal times;
2. :func:`~dome_calib.recon.people.assign.associate`: proposals (:mod:`~dome_calib.recon.people.proposals`) and
   each view's detections assigned to them, per time;
3. :func:`~dome_calib.recon.people.bodies.triangulate_people`: all people of the batch triangulated robustly in one
   call;
4. :func:`~dome_calib.recon.people.joint_check.check_joints`: the joints each body keeps (and, given Kinect depth
   frames, those no depth sensor sees through: :mod:`~dome_calib.recon.people.depth_witness`);
5. :func:`~dome_calib.recon.people.bodies.build_bodies`: enough joints, no duplicates;
6. :func:`~dome_calib.recon.people.agreement.tally_agreement`: how each camera agrees;

then, over the whole session, :func:`~dome_calib.recon.people.tracking.apply_tracks` gives ids,
:func:`~dome_calib.recon.people.bridging.bridge_gaps` searches the times inside the tracks' gaps again, and
:func:`~dome_calib.recon.people.windows.refine_session` makes each person one body over time (constant bones,
smooth motion, every detection weighed against the body: :mod:`~dome_calib.recon.people.temporal`), in windows
fixed by the session's time index, with bone lengths and camera noise measured once over the whole session.
:func:`people_at_times` runs steps 1-6 over a span of times (each time on its own: the result at a time does not
depend on the other times of its batch or chunk); :func:`reconstruct_people` adds the tracking and the body over
time in one process; :func:`~dome_calib.recon.people.chunks.reconstruct_people_chunked` runs the spans and the
windows of a long session on an executor, and tracks once over all of them in between. No result depends on the
batches, the chunks or the workers. ``shared_fps``: the frame rate of a bundle without sync tables (its frames'
universal times); no default: a rate nobody gave is refused (:func:`~dome_calib.recon.people.sources.stream_layouts`).
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Annotated

import numpy as np

from dome_calib.options import AtLeast, Field, PosFraction, options
from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.people.agreement import CameraAgreement, tally_agreement
from dome_calib.recon.people.assign import associate
from dome_calib.recon.people.bridging import bridge_gaps
from dome_calib.recon.people.bodies import Bodies, build_bodies, triangulate_people
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.joint_check import JointCheckOptions, check_joints
from dome_calib.recon.people.proposals import AssociationOptions, select_pairs
from dome_calib.recon.people.resample import gather_people
from dome_calib.recon.people.sources import FileSource, InMemorySource, PeopleStream
from dome_calib.recon.people.temporal import TemporalOptions
from dome_calib.recon.people.tracking import TrackingOptions, apply_tracks, smooth_tracks
from dome_calib.recon.people.windows import refine_session
from dome_calib.recon.project import ViewSet
from dome_calib.recon.triangulate import TriangulationOptions

logger = logging.getLogger(__name__)


@options
class PeopleOptions:
    """Options of :func:`reconstruct_people`. joint_check: which triangulated joints a body keeps
    (:mod:`~dome_calib.recon.people.joint_check`); min_body_joints: a body needs this many reconstructed joints;
    max_gap_frames: stream brackets wider than this many frame periods are not bridged; batch_times: times
    triangulated together; chunk_times: the times of one task of :func:`reconstruct_people_chunked`. Neither
    changes the result (only memory and speed). temporal: the body over time (:mod:`~dome_calib.recon.people.temporal`;
    ``enabled=False`` keeps the per-frame joints). triangulation: a view supports a joint within 15 px (3 sigma of
    the detector's noise: 3.5-5 px per camera measured on real OpenPose BODY_25B of 1080p phone video, Pose2Sim's
    balancing trial; Pose2Sim's own ``reproj_error_threshold_triangulation`` is 15 px). At 10 px three views that
    agree to 10-12 px lost to any two views (two always meet): the left hip of that trial had two inlier views in
    66 of 99 frames, the pair changing from frame to frame."""

    association: AssociationOptions = field(default_factory=AssociationOptions)
    triangulation: TriangulationOptions = field(default_factory=lambda: TriangulationOptions(
        inlier_threshold_px=15.0, min_views=2, min_confidence=0.05))
    tracking: TrackingOptions = field(default_factory=TrackingOptions)
    joint_check: JointCheckOptions = field(default_factory=JointCheckOptions)
    temporal: TemporalOptions = field(default_factory=TemporalOptions)
    min_body_joints: AtLeast(1) = 6
    max_gap_frames: Annotated[float, Field(ge=1)] = 2.5
    batch_times: AtLeast(1) = 16
    chunk_times: AtLeast(1) = 600
    shared_fps: PosFraction | None = None


@dataclass
class PeopleSequence:
    """times_ms (T,), bodies[t] (:class:`Bodies`), cameras (:class:`CameraAgreement`)."""

    times_ms: np.ndarray
    bodies: list[Bodies]
    cameras: CameraAgreement


def associate_batch(views: ViewSet, kernel: CameraKernel, pairs: np.ndarray, kp: np.ndarray,
                    options: PeopleOptions, *, times_ms: np.ndarray | None = None, depth: DepthWitness | None = None
                    ) -> tuple[list[Bodies], CameraAgreement]:
    """(T, V, N, 19, 3) people at T times -> the bodies of each time (ids -1, each with its assigned detections) and
    the cameras' agreement (steps 2-6 of the module docstring; with ``depth`` and the batch's ``times_ms``, step 4
    also drops the joints the Kinects see through, :mod:`~dome_calib.recon.people.depth_witness`)."""
    a = options.association
    assigned = associate(views, kernel, pairs, kp, a, min_body_joints=options.min_body_joints)
    tri = triangulate_people(views, kp, assigned, options.triangulation)
    ok = check_joints(tri.X_cm, tri.n_inliers, options.joint_check)
    before = int(ok.sum())
    if depth is not None:
        for k in range(len(tri.sizes) - 1):
            sl = slice(tri.sizes[k], tri.sizes[k + 1])
            ok[sl] &= depth.keep(np.where(ok[sl, :, None], tri.X_cm[sl], np.nan), float(times_ms[k]))
    bodies, kept = build_bodies(tri, ok, min_body_joints=options.min_body_joints, duplicate_cm=a.duplicate_cm)
    agreement = tally_agreement(views, kp, tri, ok, kept, min_joint_conf=a.min_joint_conf,
                                min_common_joints=a.min_common_joints)
    if depth is not None:
        agreement.depth_joints, agreement.depth_rejected = before, before - int(ok.sum())
    return bodies, agreement


def people_at_times(views: ViewSet, streams: list[PeopleStream], times_ms: np.ndarray,
                    options: PeopleOptions | None = None, *, depth: DepthWitness | None = None,
                    progress: Callable[[int, int], None] | None = None) -> PeopleSequence:
    """The bodies at (T,) universal times from the streams' unlabelled detections, without ids (-1): steps 1-6 of
    the module docstring, ``batch_times`` times at a time. Each time's bodies depend on that time's detections only,
    so any split of the times into batches or chunks gives the same bodies.

    depth: the Kinects' depth frames as a witness (joints they see through are dropped), or None.
    progress: ``progress(done_times, total_times)`` after each batch.
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
        kp = gather_people(streams, t[sl], options.max_gap_frames)
        got, agree = associate_batch(sub, kernel, pairs, kp, options, times_ms=t[sl], depth=depth)
        bodies += got
        agreement.add(agree)
        if progress is not None:
            progress(sl.stop, len(t))
    return PeopleSequence(times_ms=t, bodies=bodies, cameras=agreement)


def reconstruct_people(views: ViewSet, streams: list[PeopleStream], times_ms: np.ndarray,
                       options: PeopleOptions | None = None, *, depth: DepthWitness | None = None,
                       progress: Callable[[int, int], None] | None = None) -> PeopleSequence:
    """Tracked people at (T,) universal times from the streams' unlabelled detections (one process): the bodies of
    each time, the tracks, then the body over time (unless ``options.temporal.enabled`` is False).

    Args:
        views: holds every camera of ``streams``; streams: from :func:`~dome_calib.recon.people.sources.people_streams`.
        depth: the Kinects' depth frames as a witness (joints they see through are dropped), or None.
        progress: ``progress(done, total)`` after each batch and each window: total is the times, twice with the
            body over time (each time is worked on per frame, then in its window).
    Returns:
        :class:`PeopleSequence`; ids from 0 in order of first appearance.
    Example:
        >>> seq = reconstruct_people(view_set(bundle, names), people_streams(bundle, det.people), vga_times_ms)
    """
    options = options or PeopleOptions()
    t = np.asarray(times_ms, dtype=float)
    total = len(t) * (2 if options.temporal.enabled else 1)
    seq = people_at_times(views, streams, t, options, depth=depth,
                          progress=None if progress is None else (lambda d, n: progress(d, total)))
    return over_time(views, InMemorySource(streams), seq, options, depth=depth,
                     progress=None if progress is None else (lambda d: progress(len(t) + d, total)))


def over_time(views: ViewSet, source: InMemorySource | FileSource, seq: PeopleSequence, options: PeopleOptions, *,
              depth: DepthWitness | None = None, executor=None,
              progress: Callable[[int], None] | None = None) -> PeopleSequence:
    """The session's bodies of every time (ids -1) -> tracked once over all of them, the tracks' gaps searched again
    with their predictions (:mod:`~dome_calib.recon.people.bridging`), optional smoothing, then one body per person
    over time (windows on ``executor``; ``progress(times_done)`` after each)."""
    bodies = apply_tracks(seq.times_ms, seq.bodies, options.tracking)
    cameras = seq.cameras
    if options.tracking.bridge_gaps:
        bodies, cameras = bridge_gaps(views, source, seq.times_ms, bodies, cameras, association=options.association,
                                      triangulation=options.triangulation, joint_check=options.joint_check,
                                      tracking=options.tracking, min_body_joints=options.min_body_joints,
                                      max_gap_frames=options.max_gap_frames, batch_times=options.batch_times,
                                      depth=depth)
    bodies = smooth_tracks(seq.times_ms, bodies, options.tracking.smooth_half_window)
    bodies, cameras = refine_session(views, source, seq.times_ms, bodies, cameras, options.temporal,
                                     max_gap_frames=options.max_gap_frames, batch_times=options.batch_times,
                                     depth=depth, executor=executor, progress=progress)
    return PeopleSequence(times_ms=seq.times_ms, bodies=bodies, cameras=cameras)
