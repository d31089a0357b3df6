"""Long sessions: :func:`~dome_calib.recon.people.run.reconstruct_people` over overlapping chunks of time, run on an
executor (a local process pool or Dask), ids stitched over the overlaps.

Each chunk's task gets its own detections from the source (a :class:`~dome_calib.recon.people.sources.FileSource`
reads only the files of the frames that bracket the chunk's times, so an hour is never in memory at once). Tracks
of two chunks that hold the same people in the overlap are one track
(:func:`~dome_calib.recon.people.tracking.stitch_chunks`); new ids are numbered on, never reused; short tracks are
dropped after stitching (a track cut by a chunk boundary is short only in its chunk).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from dome_calib.recon.people.agreement import CameraAgreement
from dome_calib.recon.people.bodies import Bodies
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.run import PeopleOptions, PeopleSequence, reconstruct_people
from dome_calib.recon.people.sources import FileSource, InMemorySource, PeopleStream
from dome_calib.recon.people.tracking import stitch_chunks
from dome_calib.recon.project import ViewSet


def _chunk_task(args: tuple) -> tuple[int, PeopleSequence]:
    """Executor task: one chunk of times (module level, picklable); reads the chunk's detections from ``source``."""
    index, views, source, times, options, depth = args
    streams = source.chunk(float(times[0]), float(times[-1]), options.max_gap_frames)
    return index, reconstruct_people(views, streams, times, options, depth=depth)


def reconstruct_people_chunked(views: ViewSet, source: list[PeopleStream] | InMemorySource | FileSource,
                               times_ms: np.ndarray, options: PeopleOptions | None = None, *, executor=None,
                               depth: DepthWitness | None = None,
                               progress: Callable[[int, int], None] | None = None) -> PeopleSequence:
    """:func:`reconstruct_people` over chunks of ``chunk_times`` times, each reaching ``overlap_times`` past its
    own on both sides (the body over time sees across the edges; the ids are matched there), run on
    ``executor`` (``map``; a local pool or Dask; None: in this process); ids stitched over the overlaps
    (:func:`~dome_calib.recon.people.tracking.stitch_chunks`), new ones numbered on, never reused.

    source: the streams, or a :class:`~dome_calib.recon.people.sources.FileSource` whose chunks each task reads from
    disk itself (only the frames that bracket the chunk's times); depth: the Kinects' depth witness, or None.
    """
    options = options or PeopleOptions()
    source = InMemorySource(source) if isinstance(source, list) else source
    t = np.asarray(times_ms, dtype=float)
    step = options.chunk_times
    if len(t) <= step + options.overlap_times:
        streams = source.chunk(float(t[0]), float(t[-1]), options.max_gap_frames) if len(t) else []
        return reconstruct_people(views, streams, t, options, depth=depth, progress=progress)
    starts = list(range(0, len(t), step))
    if len(t) - starts[-1] <= options.overlap_times:
        starts.pop()  # the previous chunk's overlap already reaches the end
    # Short tracks are dropped after stitching: a track cut by a chunk boundary is short only in its chunk.
    chunk_options = dataclasses.replace(options, tracking=dataclasses.replace(options.tracking, drop_short=False))
    m = options.overlap_times
    # chunk i reaches m times past its own on both sides: its body over time sees what lies around its edges
    lo = [max(0, s - m) for s in starts]
    hi = [min(len(t), s + step + m) for s in starts]
    tasks = [(i, views, source, t[lo[i]: hi[i]], chunk_options, depth) for i in range(len(starts))]
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
        else:  # the times both chunks hold: [s - m, s + m)
            prev = results[i - 1]
            tail = prev.bodies[lo[i] - lo[i - 1]: hi[i - 1] - lo[i - 1]]
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
        end = starts[i + 1] if i < len(starts) - 1 else len(t)
        own = seq.bodies[s - lo[i]: end - lo[i]]
        bodies += [b.take(slice(None), np.array([id_map[int(x)] for x in b.ids], dtype=np.int64)) for b in own]
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
        out.append(b.take(k, np.array([first[int(i)] for i in b.ids[k]], dtype=np.int64)))
    return out
