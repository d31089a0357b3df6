"""Long sessions on an executor (a local process pool or Dask): the bodies of each chunk of times, then the tracks
once over the whole session, then the body over time in windows fixed by the session's time index.

1. Each chunk's task gets its own detections from the source (a :class:`~dome_calib.recon.people.sources.FileSource`
   reads only the files of the frames that bracket the chunk's times, so an hour is never in memory at once) and
   returns the bodies of its times without ids, each with the index of its detection in every view
   (:func:`~dome_calib.recon.people.run.people_at_times`: a time's bodies depend on that time's detections only),
   and its tallies (counts and histograms of integer bins: their sum is the same for any cut).
2. Tracking, short-track dropping, the bridging of the tracks' gaps and smoothing run once over all the times
   (:func:`~dome_calib.recon.people.tracking.apply_tracks`, a few milliseconds per time against tens for the bodies;
   :func:`~dome_calib.recon.people.bridging.bridge_gaps` reads the detections of the gaps' times only, in this
   process).
3. The body over time (:func:`~dome_calib.recon.people.windows.refine_session`): bone lengths and camera noise
   measured once over all of it, then windows of the session's own time index, each reading its detections again,
   on the executor.

No id, body or joint depends on where the chunks were cut, how many there are, the batches or which worker ran them.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dome_calib.recon.people.agreement import CameraAgreement
from dome_calib.recon.people.bodies import Bodies
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.run import PeopleOptions, PeopleSequence, over_time, people_at_times
from dome_calib.recon.people.sources import FileSource, InMemorySource, PeopleStream
from dome_calib.recon.project import ViewSet


def _chunk_task(args: tuple, progress: Callable[[int, int], None] | None = None) -> tuple[int, PeopleSequence]:
    """Executor task: the bodies of one chunk of times (module level, picklable); reads the chunk's detections
    from ``source``."""
    index, views, source, times, options, depth = args
    streams = source.chunk(float(times[0]), float(times[-1]), options.max_gap_frames)
    return index, people_at_times(views, streams, times, options, depth=depth, progress=progress)


def reconstruct_people_chunked(views: ViewSet, source: list[PeopleStream] | InMemorySource | FileSource,
                               times_ms: np.ndarray, options: PeopleOptions | None = None, *, executor=None,
                               depth: DepthWitness | None = None,
                               progress: Callable[[int, int], None] | None = None) -> PeopleSequence:
    """The bodies of chunks of ``chunk_times`` times, run on ``executor`` (``map``; a local pool or Dask; None or a
    single chunk: in this process), tracked over all the times at once, then fitted over time in windows (on the
    executor too): the same result as :func:`~dome_calib.recon.people.run.reconstruct_people` over everything, for
    any chunk size, batch size and executor.

    source: the streams, or a :class:`~dome_calib.recon.people.sources.FileSource` whose chunks and windows each
    task reads from disk itself (only the frames that bracket its times); depth: the Kinects' depth witness, or None.
    progress: ``progress(done, total)``: total is the times, twice with the body over time (per frame, then in the
    windows).
    """
    options = options or PeopleOptions()
    source = InMemorySource(source) if isinstance(source, list) else source
    t = np.asarray(times_ms, dtype=float)
    total = len(t) * (2 if options.temporal.enabled else 1)
    step = options.chunk_times
    tasks = [(i, views, source, t[s: s + step], options, depth) for i, s in enumerate(range(0, len(t), step))]
    results: dict[int, PeopleSequence] = {}
    if executor is None or len(tasks) <= 1:  # in this process: progress after every batch
        for task in tasks:
            base = task[0] * step
            report = None if progress is None else (lambda d, n, base=base: progress(base + d, total))
            results[task[0]] = _chunk_task(task, report)[1]
    else:
        for index, seq in executor.map(_chunk_task, tasks):
            results[index] = seq
            if progress is not None:
                progress(sum(len(r.times_ms) for r in results.values()), total)
    bodies: list[Bodies] = []
    agreement = CameraAgreement.empty(source.cameras)
    for i in range(len(tasks)):
        bodies += results[i].bodies
        agreement.add(results[i].cameras)
    seq = PeopleSequence(times_ms=t, bodies=bodies, cameras=agreement)
    return over_time(views, source, seq, options, depth=depth, executor=executor,
                     progress=None if progress is None else (lambda d: progress(len(t) + d, total)))
