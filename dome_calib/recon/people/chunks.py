"""Long sessions: the bodies of each chunk of times computed on an executor (a local process pool or Dask), then
tracked once over the whole session.

Each chunk's task gets its own detections from the source (a :class:`~dome_calib.recon.people.sources.FileSource`
reads only the files of the frames that bracket the chunk's times, so an hour is never in memory at once) and
returns the bodies of its times without ids (:func:`~dome_calib.recon.people.run.people_at_times`: a time's bodies
depend on that time's detections only). Tracking, short-track dropping and smoothing then run once over all the
times (:func:`~dome_calib.recon.people.tracking.apply_tracks`, a few milliseconds per time against tens for the
bodies): no id, body or joint depends on where the chunks were cut, how many there are or which worker ran them.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dome_calib.recon.people.agreement import CameraAgreement
from dome_calib.recon.people.bodies import Bodies
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.run import PeopleOptions, PeopleSequence, people_at_times
from dome_calib.recon.people.sources import FileSource, InMemorySource, PeopleStream
from dome_calib.recon.people.tracking import apply_tracks
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
    single chunk: in this process), then tracked over all the times at once: the same result as
    :func:`~dome_calib.recon.people.run.reconstruct_people` over everything, for any chunk size and executor.

    source: the streams, or a :class:`~dome_calib.recon.people.sources.FileSource` whose chunks each task reads from
    disk itself (only the frames that bracket the chunk's times); depth: the Kinects' depth witness, or None.
    """
    options = options or PeopleOptions()
    source = InMemorySource(source) if isinstance(source, list) else source
    t = np.asarray(times_ms, dtype=float)
    step = options.chunk_times
    tasks = [(i, views, source, t[s: s + step], options, depth) for i, s in enumerate(range(0, len(t), step))]
    results: dict[int, PeopleSequence] = {}
    if executor is None or len(tasks) <= 1:  # in this process: progress after every batch
        for task in tasks:
            base = task[0] * step
            report = None if progress is None else (lambda d, n, base=base: progress(base + d, len(t)))
            results[task[0]] = _chunk_task(task, report)[1]
    else:
        for index, seq in executor.map(_chunk_task, tasks):
            results[index] = seq
            if progress is not None:
                progress(sum(len(r.times_ms) for r in results.values()), len(t))
    bodies: list[Bodies] = []
    agreement = CameraAgreement.empty(source.cameras)
    for i in range(len(tasks)):
        bodies += results[i].bodies
        agreement.add(results[i].cameras)
    return PeopleSequence(times_ms=t, bodies=apply_tracks(t, bodies, options.tracking), cameras=agreement)
