"""Many people, no labels: OpenPose-style detections of every camera -> tracked 3D skeletons (joints19, world cm).

The run, in the order the data flows (each step a function of its own module, testable alone; steps 2-6 are the
per-time association, :func:`~dome_calib.recon.people.per_time.associate_batch`, whose rules the bridging of the
tracks' gaps shares):

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
from dataclasses import dataclass

import numpy as np

from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.people.agreement import CameraAgreement
from dome_calib.recon.people.bridging import bridge_gaps
from dome_calib.recon.people.bodies import Bodies
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.options import PeopleOptions
from dome_calib.recon.people.per_time import associate_batch
from dome_calib.recon.people.proposals import select_pairs
from dome_calib.recon.people.resample import gather_people
from dome_calib.recon.people.sources import FileSource, InMemorySource, PeopleStream
from dome_calib.recon.people.tracking import apply_tracks, smooth_tracks
from dome_calib.recon.people.windows import refine_session
from dome_calib.recon.project import ViewSet

__all__ = ["PeopleOptions", "PeopleSequence", "associate_batch", "people_at_times", "reconstruct_people", "over_time"]

logger = logging.getLogger(__name__)


@dataclass
class PeopleSequence:
    """times_ms (T,), bodies[t] (:class:`Bodies`), cameras (:class:`CameraAgreement`); tracked: the same session
    tracked but before the body over time (what :func:`refit_over_time` fits again; None: no body over time)."""

    times_ms: np.ndarray
    bodies: list[Bodies]
    cameras: CameraAgreement
    tracked: PeopleSequence | None = None


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
        bodies, cameras = bridge_gaps(views, source, seq.times_ms, bodies, cameras, options, depth=depth)
    bodies = smooth_tracks(seq.times_ms, bodies, options.tracking.smooth_half_window)
    tracked = PeopleSequence(times_ms=seq.times_ms, bodies=bodies, cameras=cameras)
    bodies, cameras = refine_session(views, source, seq.times_ms, bodies, cameras, options.temporal,
                                     max_gap_frames=options.max_gap_frames, batch_times=options.batch_times,
                                     depth=depth, executor=executor, progress=progress)
    return PeopleSequence(times_ms=seq.times_ms, bodies=bodies, cameras=cameras,
                          tracked=tracked if options.temporal.enabled else None)


def refit_over_time(views: ViewSet, source: InMemorySource | FileSource, seq: PeopleSequence, options: PeopleOptions,
                    ties, *, depth: DepthWitness | None = None, executor=None) -> PeopleSequence:
    """The body over time fitted again from the same tracks (``seq.tracked``) with ``ties``, the patches' part
    motions (:class:`~dome_calib.recon.patches.body.JointTies`), as a further term, in the session's windows on
    ``executor``; ``seq`` as it is when it has no body over time (``--per-frame``)."""
    if seq.tracked is None:
        return seq
    t = seq.tracked
    bodies, cameras = refine_session(views, source, t.times_ms, t.bodies, t.cameras, options.temporal,
                                     max_gap_frames=options.max_gap_frames, batch_times=options.batch_times,
                                     depth=depth, executor=executor, ties=ties)
    return PeopleSequence(times_ms=t.times_ms, bodies=bodies, cameras=cameras, tracked=t)
