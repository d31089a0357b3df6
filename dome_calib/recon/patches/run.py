"""The patch trajectory stream: seed clouds every ``seed_every_frames`` reference frames, each tracked
``track_frames`` frames backward and forward.

**One time for all streams.** The stream is kept at the frame times of one *reference stream* (by default the
stream with the most cameras, ties by name: VGA in the dome, the one HD stream of a rig). Clouds are seeded from
the reference stream's cameras at a seed frame (their images share its time) and, with ``seed_streams="all"``,
from every other stream at its own frame nearest that time, then carried to it by one tracking step
(:func:`place_seeds`); every other camera joins through
its own frames, brought to the reference times as the skeleton stages bring detections there: its 2D track is
interpolated linearly between the two frames around the time (``frame_brackets``), see :mod:`.track`, and it is
judged (photometric term) on its nearest frame with the patch moved to that frame's time.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.executor import in_order
from dome_calib.recon.errors import ReconError
from dome_calib.recon.patches.frames import FrameSource, patch_axes
from dome_calib.recon.patches.model import PatchOptions, PatchTrajectories
from dome_calib.recon.patches.seed import (CameraSeeds, Seeds, merge_camera_seeds, reference_cameras,
                                           seed_camera, thin_to_cells)
from dome_calib.recon.patches.seed_depth import DepthFrames, seed_from_depth, seed_from_own_kinect
from dome_calib.recon.patches.seed_features import seed_from_features
from dome_calib.recon.patches.seed_skeleton import (BodyPrior, CameraBodySeeds, merge_body_seeds, seed_camera_on_body,
                                                    stream_may_seed)
from dome_calib.recon.patches.refine import refine_normals
from dome_calib.recon.patches.track import (Clock, CloudTrack, judged_frames, quantise_cm, seed_visibility,
                                            track_cloud)
from dome_calib.recon.patches.visibility import camera_neighbours, estimate_visibility
from dome_calib.recon.project import ViewSet, view_set
from dome_calib.recon.streams import cameras_by_stream, frame_period_ms
from dome_calib import ties

logger = logging.getLogger(__name__)

#: Patch ids: cloud number * ID_STRIDE + position in the cloud.
ID_STRIDE = 100_000
#: Seeds per track task by default. A task makes two optical-flow calls per camera and step whatever its patches
#: (OpenCV builds both images' pyramids in each, ~0.5 ms per VGA image), so on a dense dome the task's size sets
#: that cost's share: a full-dome cloud (~7,300 seeds with 8 people) in two tasks, one per core of a small machine
#: (docs/patches.md#speed). The cut changes no bit of the result.
PATCHES_PER_TASK = 4000


def imaged_views(source: FrameSource, cameras: list[str]) -> ViewSet:
    """The cameras as the source images them (scaled intrinsics if the images are), in ``cameras`` order."""
    return view_set(Bundle(seq="imaged", cameras={n: source.camera(n) for n in cameras}), list(cameras))


def reference_stream(bundle: Bundle, cameras: list[str]) -> str:
    """The stream with the most of ``cameras`` (ties by stream name)."""
    groups, _ = cameras_by_stream(bundle, cameras)
    if not groups:
        raise ReconError("the patch stage needs at least one camera")
    return sorted(groups, key=lambda s: (-len(groups[s]), s))[0]


def clocks_of(bundle: Bundle, source: FrameSource, cameras: list[str]) -> list[Clock]:
    """Each camera's stream table and the frames of it the source holds."""
    groups, tables = cameras_by_stream(bundle, cameras)
    stream_of = {n: s for s, names in groups.items() for n in names}
    out = []
    for n in cameras:
        table = tables[stream_of[n]]
        held = np.intersect1d(np.asarray(source.frame_indices(n), dtype=np.int64), table.index)
        out.append(Clock(table=table, frames=held))
    return out


def seed_frames_in(table_index: np.ndarray, table_times: np.ndarray, span_ms: tuple[float, float], every: int
                   ) -> np.ndarray:
    """Reference frames inside ``span_ms`` whose index is a multiple of ``every``."""
    inside = (table_times >= span_ms[0]) & (table_times <= span_ms[1])
    return table_index[inside & (table_index % every == 0)]


def run_cloud(source: FrameSource, views: ViewSet, clocks: list[Clock], seed_time_ms: float, times_ms: np.ndarray,
              seeds: Seeds, o: PatchOptions, neighbours: np.ndarray | None = None, *, refine: bool | None = None,
              body: BodyPrior | None = None) -> tuple[CloudTrack, CloudTrack]:
    """One cloud (or any subset of its seeds) tracked from ``seed_time_ms`` over ``times_ms`` (increasing, holding
    the seed time): (backward, forward), each in travel order from the seed. ``refine``: refine the seeds' normals
    photometrically first (:mod:`.refine`; None: ``o.refine_normals``). ``body``: the people over time, occluders of
    the views with ``o.body_occlusion`` (:mod:`.occlusion`)."""
    neighbours = camera_neighbours(views, o.prior_neighbours) if neighbours is None else neighbours
    t = np.asarray(times_ms, dtype=float)
    s = ties.argmin_first(np.abs(t - seed_time_ms), ties.TIME_QUANTUM_MS)
    X = quantise_cm(seeds.X_cm)
    if (o.refine_normals if refine is None else refine) and len(X):
        frames = judged_frames(clocks, float(t[s]))
        vis = estimate_visibility(source, views, frames, X, np.zeros_like(X), seeds.seen, None, neighbours, o, body)
        X = quantise_cm(refine_normals(source, views, frames, X, vis.visible, o))
    start = seed_visibility(source, views, clocks, float(t[s]), X, seeds.seen, neighbours, o, body)
    back = track_cloud(source, views, clocks, t[:s + 1][::-1], X, seeds.seen, neighbours, o, start, body)
    fwd = track_cloud(source, views, clocks, t[s:], X, seeds.seen, neighbours, o, start, body)
    return back, fwd


@dataclass(frozen=True)
class SeedTask:
    """Executor task: the seeds of cloud ``cloud`` from reference camera ``camera`` (image seeding by the depth
    sweep, or on the people ``body_cm`` at the seed time with ``options.seed_method == "skeleton"``:
    :mod:`.seed_skeleton`), or the whole cloud (``camera`` -1) from the Kinects' depth (``depth`` given) or from
    matched features (``options.seed_method == "features"``: :mod:`.seed_features`)."""

    cloud: int
    camera: int
    source: FrameSource
    ref_views: ViewSet
    frames: dict[str, int]
    seed_time_ms: float
    options: PatchOptions
    bundle: Bundle | None = None
    depth: DepthFrames | None = None
    body_cm: np.ndarray | None = None
    stream_rank: int = 0  # 0: the reference stream; k > 0: the k-th other stream that seeds (sorted by name)
    node: str = ""  # a Kinect seeding from its own depth in its colour camera ``camera`` of ``ref_views``

    @property
    def key(self) -> tuple[int, int, int]:
        return (self.cloud, self.stream_rank, self.camera)


def seed_task(task: SeedTask) -> tuple[tuple[int, int, int], CameraSeeds | CameraBodySeeds | Seeds]:
    """Run one :class:`SeedTask` (module level: picklable for a process pool or Dask)."""
    if task.node:
        return task.key, seed_from_own_kinect(task.bundle, task.depth, task.node, task.seed_time_ms, task.source,
                                              task.ref_views, task.camera, task.frames[task.ref_views.names[
                                                  task.camera]], task.options)
    if task.depth is not None:
        return task.key, seed_from_depth(task.bundle, task.depth, task.seed_time_ms, task.source, task.ref_views,
                                         task.frames, task.options)
    if task.options.seed_method == "features":
        return task.key, seed_from_features(task.source, task.ref_views, task.frames, task.options)
    if task.options.seed_method == "skeleton":
        return task.key, seed_camera_on_body(task.source, task.ref_views, task.frames, task.camera, task.body_cm,
                                             task.options)
    return task.key, seed_camera(task.source, task.ref_views, task.frames, task.camera, task.options)


def stream_seed_frame(clocks: list[Clock], t_ms: float) -> int | None:
    """The frame of one stream (its cameras' ``clocks``) nearest ``t_ms`` that every camera holds, within half a
    nominal period (ties: the earlier frame); None if there is none."""
    held = clocks[0].frames
    for c in clocks[1:]:
        held = np.intersect1d(held, c.frames)
    if len(held) == 0:
        return None
    times = clocks[0].table.times_of(held)
    k = ties.argmin_first(np.abs(times - t_ms), ties.TIME_QUANTUM_MS)
    return int(held[k]) if abs(times[k] - t_ms) <= 0.5 * frame_period_ms(clocks[0].table) + 1e-6 else None


def place_seeds(source: FrameSource, views: ViewSet, clocks: list[Clock], from_ms: float, to_ms: float, seeds: Seeds,
                neighbours: np.ndarray, o: PatchOptions, *, refine: bool | None = None,
                body: BodyPrior | None = None) -> tuple[Seeds, np.ndarray]:
    """Seeds of a stream at its own frame time ``from_ms`` (``seeds.seen`` over ``views``) -> the same patches at the
    cloud's seed time ``to_ms``: normals refined photometrically at ``from_ms`` (where the seeding stream's cameras
    have their frames, :mod:`.refine`), then one tracking step to ``to_ms`` (:func:`track_cloud`: each camera's track
    interpolated linearly between its frames around the time, as every camera joins the tracking), the visibility
    there (MAP) their ``seen``. A seed that does not survive the step is dropped -> (the placed seeds, (N,) which of
    ``seeds`` they are). Per patch, like the tracking."""
    V = len(views.names)
    if len(seeds.X_cm) == 0:
        return Seeds(X_cm=np.zeros((0, 3, 3)), normal=np.zeros((0, 3)), seen=np.zeros((0, V), bool)), np.zeros(0, bool)
    X = quantise_cm(seeds.X_cm)
    if o.refine_normals if refine is None else refine:
        frames = judged_frames(clocks, from_ms)
        vis = estimate_visibility(source, views, frames, X, np.zeros_like(X), seeds.seen, None, neighbours, o, body)
        X = quantise_cm(refine_normals(source, views, frames, X, vis.visible, o))
    times = np.array([from_ms, to_ms]) if abs(to_ms - from_ms) >= 0.5 else np.array([to_ms])
    track = track_cloud(source, views, clocks, times, X, seeds.seen, neighbours, o, body=body)
    ok = track.alive[:, -1]
    Xo = track.X_cm[ok, -1]
    _, _, normal = patch_axes(Xo[:, 0], Xo[:, 1], Xo[:, 2])
    return Seeds(X_cm=Xo, normal=normal, seen=track.visible[ok, -1]), ok


@dataclass(frozen=True)
class PlaceTask:
    """Executor task: the merged seeds of cloud ``cloud`` from the ``stream_rank``-th other stream, at its frame
    time ``from_ms``, carried to the cloud's seed time ``to_ms`` (:func:`place_seeds`)."""

    cloud: int
    stream_rank: int
    source: FrameSource
    views: ViewSet
    clocks: list[Clock]
    from_ms: float
    to_ms: float
    seeds: Seeds
    neighbours: np.ndarray
    options: PatchOptions
    refine: bool = True  # refine the normals first (not depth seeds': the depth's normal is better)
    body: BodyPrior | None = None  # occluders of the views (body_occlusion)

    @property
    def key(self) -> tuple[int, int]:
        return (self.cloud, self.stream_rank)


def place_task(task: PlaceTask) -> tuple[tuple[int, int], Seeds]:
    """Run one :class:`PlaceTask` (module level: picklable)."""
    return task.key, place_seeds(task.source, task.views, task.clocks, task.from_ms, task.to_ms, task.seeds,
                                 task.neighbours, task.options, refine=task.refine, body=task.body)[0]


def merge_streams(clouds: list[Seeds], o: PatchOptions) -> Seeds:
    """One cloud's seeds of each stream (the reference stream's first, each ``seen`` over all cameras) -> one cloud:
    one seed per ``seed_spacing_cm`` cell, the earlier stream's first (the reference stream's seeds are all kept,
    in their order), then the one seen by most cameras, then the first."""
    X = np.concatenate([c.X_cm for c in clouds])
    rank = np.concatenate([np.full(len(c.X_cm), k) for k, c in enumerate(clouds)])
    seen = np.concatenate([c.seen for c in clouds])
    pick = thin_to_cells(X[:, 0], [np.arange(len(X)), -seen.sum(1), rank], o.seed_spacing_cm)
    return Seeds(X_cm=X[pick], normal=np.concatenate([c.normal for c in clouds])[pick], seen=seen[pick])


@dataclass(frozen=True)
class TrackTask:
    """Executor task: seeds ``start``.. of cloud ``cloud`` (``seeds`` holds them), refined and tracked both ways."""

    cloud: int
    start: int
    source: FrameSource
    views: ViewSet
    clocks: list[Clock]
    seed_time_ms: float
    times_ms: np.ndarray
    seeds: Seeds
    neighbours: np.ndarray
    options: PatchOptions
    refine: bool = True
    body: BodyPrior | None = None  # occluders of the views (body_occlusion)

    @property
    def key(self) -> tuple[int, int]:
        return (self.cloud, self.start)


def track_task(task: TrackTask) -> tuple[tuple[int, int], CloudTrack, CloudTrack]:
    """Run one :class:`TrackTask` (module level: picklable)."""
    back, fwd = run_cloud(task.source, task.views, task.clocks, task.seed_time_ms, task.times_ms, task.seeds,
                          task.options, task.neighbours, refine=task.refine, body=task.body)
    return task.key, back, fwd


def run_tasks(executor, fn: Callable, tasks: list) -> list:
    """``fn`` of every task (each with a ``key``), in the tasks' order: on ``executor`` (``map``: a local pool or
    Dask), or in this process when there is none or a single task."""
    if executor is None or len(tasks) <= 1:
        return [fn(t) for t in tasks]
    return list(in_order(executor.map(fn, tasks), [t.key for t in tasks], lambda r: r[0]))


def _concat_tracks(tracks: list[CloudTrack]) -> CloudTrack:
    return CloudTrack(times_ms=tracks[0].times_ms, X_cm=np.concatenate([t.X_cm for t in tracks]),
                      visible=np.concatenate([t.visible for t in tracks]),
                      photometric=np.concatenate([t.photometric for t in tracks]),
                      alive=np.concatenate([t.alive for t in tracks]),
                      carried=None if any(t.carried is None for t in tracks)
                      else np.concatenate([t.carried for t in tracks]))


def patch_stream(bundle: Bundle, source: FrameSource, cameras: list[str], span_ms: tuple[float, float],
                 options: PatchOptions | None = None, *, stream: str | None = None,
                 seed_frames: list[int] | None = None, depth: DepthFrames | None = None,
                 body: BodyPrior | None = None, executor=None,
                 patches_per_task: int = PATCHES_PER_TASK,
                 progress: Callable[[int, int], None] | None = None) -> PatchTrajectories:
    """The dense patch trajectory stream of ``cameras`` (all streams) over ``span_ms``.

    The work runs on ``executor`` (``map``; a local process pool or Dask; None: in this process) in two rounds of
    tasks: the seeds (per cloud and reference camera; per cloud from depth), merged per cloud here, then the tracks
    (per cloud and run of ``patches_per_task`` seeds, both ways). Depth seeds keep the normal of the depth (the SVD of
    the dense depth points is better than the photometric refinement of image seeds: 4 against 10 deg median on the
    small test group). Every patch's result depends on its own seed and
    the images only, so how the work is cut changes not a bit of the result (``tests/test_patches_executor.py``).

    Args:
        bundle: cameras and sync tables (the cameras' own streams).
        source: images (:class:`~dome_calib.recon.patches.frames.FrameSource`; picklable for a process pool).
        stream: the reference stream (default :func:`reference_stream`).
        seed_frames: the reference frames that seed clouds (default every ``seed_every_frames``-th in the span).
        depth: the Kinects' depth frames: clouds seeded from depth (:mod:`.seed_depth`); None: from image features.
        body: the people over time, the depth prior of ``seed_method="skeleton"`` (:mod:`.seed_skeleton`; needed
            there, at the seed frames' times), and with ``body_occlusion`` the occluders of the views
            (:mod:`.occlusion`; at the tracked times, linear between the body's times; None: no such term).
        progress: called with (tracking tasks done, tracking tasks).
    Example:
        >>> traj = patch_stream(bundle, TexturedScene(bundle, truth), vga_names, (1000.0, 3000.0))
    """
    o = options or PatchOptions()
    if patches_per_task < 1:
        raise ReconError(f"patches_per_task must be at least 1 (got {patches_per_task})")
    on_body = depth is None and o.seed_method == "skeleton"
    if on_body and body is None:
        raise ReconError('seed_method "skeleton" needs the people over time (patch_stream(..., body=BodyPrior))')
    # the tasks carry the body only where it is used: the occluders of the views (body_occlusion), the parts'
    # motions a lost centre is re-found from (refind_from_body); with both off, none (the same bits as without it)
    occluders = body if o.body_occlusion or o.refind_from_body else None
    stream = stream or reference_stream(bundle, cameras)
    groups, tables = cameras_by_stream(bundle, cameras)
    if stream not in groups:
        raise ReconError(f"reference stream {stream!r} has none of the cameras")
    table = tables[stream]
    views = imaged_views(source, cameras)
    ref_names = groups[stream]
    ref_views = views.subset(ref_names)
    ref_pos = views.index_of(ref_names)
    clocks = clocks_of(bundle, source, cameras)
    neighbours = camera_neighbours(views, o.prior_neighbours)
    inside = (table.univ_time_ms >= span_ms[0]) & (table.univ_time_ms <= span_ms[1])
    frames_in = table.index[inside]
    seeds_at = (np.asarray(seed_frames, dtype=np.int64) if seed_frames is not None
                else seed_frames_in(table.index, table.univ_time_ms, span_ms, o.seed_every_frames))
    windows = []
    for f in seeds_at:
        pos = int(np.searchsorted(frames_in, f))
        if pos >= len(frames_in) or frames_in[pos] != f:
            raise ReconError(f"seed frame {int(f)} of stream {stream} is not inside the span")
        windows.append(frames_in[max(pos - o.track_frames, 0):pos + o.track_frames + 1])
    seed_times = [table.time_of(int(f)) for f in seeds_at]
    refs = reference_cameras(ref_views, o.seed_reference_spacing_deg, o.volume_height_cm)
    # the other streams that seed (sweep, skeleton): each with the cameras a seed needs (stream_may_seed), by name
    others = ([st for st in sorted(groups) if st != stream and stream_may_seed(len(groups[st]), o, on_body)]
              if o.seed_streams == "all" and (o.seed_method != "features" or depth is not None) else [])
    # with depth, a Kinect's colour camera (a stream of one camera, its own clock) seeds from its own depth
    depth_nodes = (bundle.sync.kinect_depth if bundle.sync is not None and bundle.sync.kinect_depth else {})
    own_kinects = ([st for st in sorted(groups) if st != stream and st not in others and len(groups[st]) == 1
                    and st in depth_nodes and (depth.nodes is None or st in depth.nodes)]
                   if o.seed_streams == "all" and depth is not None else [])
    others += own_kinects
    other_views = [views.subset(groups[st]) for st in others]
    other_clocks = [[clocks[i] for i in views.index_of(groups[st])] for st in others]
    other_refs = [reference_cameras(v, o.seed_reference_spacing_deg, o.volume_height_cm) for v in other_views]
    other_at: dict[tuple[int, int], tuple[int, float]] = {}  # (cloud, rank) -> the stream's frame and its time
    seed_tasks = []
    for c, f in enumerate(seeds_at):
        frames = {n: int(f) for n in ref_names}
        if depth is not None or o.seed_method == "features":  # the whole cloud in one task
            seed_tasks.append(SeedTask(c, -1, source, ref_views, frames, seed_times[c], o, bundle, depth))
        else:
            body_cm = body.at(seed_times[c]) if on_body else None
            seed_tasks += [SeedTask(c, int(r), source, ref_views, frames, seed_times[c], o, body_cm=body_cm)
                           for r in refs]
        for k, st in enumerate(others, start=1):
            g = stream_seed_frame(other_clocks[k - 1], seed_times[c])
            if g is None:
                continue
            other_at[c, k] = (g, other_clocks[k - 1][0].table.time_of(g))
            at_g = {n: g for n in groups[st]}
            if st in own_kinects:  # the points are where they were at the depth frame's own time: placed from there
                _, dt = depth_nodes[st].nearest(other_at[c, k][1])
                other_at[c, k] = (g, other_at[c, k][1] + float(dt))
                seed_tasks.append(SeedTask(c, int(views.index_of(groups[st])[0]), source, views, at_g,
                                           other_at[c, k][1], o, bundle, depth, stream_rank=k, node=st))
            elif depth is not None:  # the depth at the stream's frame time, placed in the stream's cameras
                seed_tasks.append(SeedTask(c, -1, source, other_views[k - 1], at_g, other_at[c, k][1], o, bundle,
                                           depth, stream_rank=k))
            else:  # on the body: the people at the stream's own frame time
                body_g = body.at(other_at[c, k][1]) if on_body else None
                seed_tasks += [SeedTask(c, int(r), source, other_views[k - 1], at_g, other_at[c, k][1], o,
                                        body_cm=body_g, stream_rank=k) for r in other_refs[k - 1]]
    got: dict[tuple[int, int], list] = {}
    for (c, k, _), result in run_tasks(executor, seed_task, seed_tasks):
        got.setdefault((c, k), []).append(result)
    place_tasks = []
    for (c, k), (g, t_g) in sorted(other_at.items()):
        merged = (got[c, k][0] if depth is not None
                  else merge_body_seeds(got.get((c, k), []), len(groups[others[k - 1]]), o) if on_body
                  else merge_camera_seeds(got.get((c, k), []), other_views[k - 1], o))
        if others[k - 1] in own_kinects:  # seen over all cameras already
            seen = merged.seen
        else:
            seen = np.zeros((len(merged.X_cm), len(cameras)), bool)
            seen[:, views.index_of(groups[others[k - 1]])] = merged.seen
        place_tasks.append(PlaceTask(c, k, source, views, clocks, t_g, seed_times[c],
                                     Seeds(X_cm=merged.X_cm, normal=merged.normal, seen=seen), neighbours, o,
                                     refine=o.refine_normals and depth is None and not on_body, body=occluders))
    placed: dict[int, list[Seeds]] = {}
    for (c, _), result in run_tasks(executor, place_task, place_tasks):
        placed.setdefault(c, []).append(result)
    track_tasks = []
    for c in range(len(seeds_at)):
        ref_seeds = (got[c, 0][0] if depth is not None or o.seed_method == "features"
                     else merge_body_seeds(got.get((c, 0), []), len(ref_names), o) if on_body
                     else merge_camera_seeds(got.get((c, 0), []), ref_views, o))
        seen = np.zeros((len(ref_seeds.X_cm), len(cameras)), bool)
        seen[:, ref_pos] = ref_seeds.seen
        seeds = Seeds(X_cm=ref_seeds.X_cm, normal=ref_seeds.normal, seen=seen)
        if placed.get(c):
            seeds = merge_streams([seeds] + placed[c], o)
        for lo in range(0, max(len(seeds.X_cm), 1), patches_per_task):
            part = slice(lo, lo + patches_per_task)
            track_tasks.append(TrackTask(c, lo, source, views, clocks, seed_times[c], table.times_of(windows[c]),
                                         Seeds(X_cm=seeds.X_cm[part], normal=seeds.normal[part],
                                               seen=seeds.seen[part]), neighbours, o,
                                         refine=o.refine_normals and depth is None and not on_body, body=occluders))
    tracks: dict[int, list[tuple[CloudTrack, CloudTrack]]] = {}
    results = (map(track_task, track_tasks) if executor is None or len(track_tasks) <= 1
               else in_order(executor.map(track_task, track_tasks), [t.key for t in track_tasks], lambda r: r[0]))
    for done, ((c, _), back, fwd) in enumerate(results, start=1):
        tracks.setdefault(c, []).append((back, fwd))
        if progress is not None:
            progress(done, len(track_tasks))
    parts = [(c, seed_times[c], windows[c], _concat_tracks([b for b, _ in tracks[c]]),
              _concat_tracks([f for _, f in tracks[c]])) for c in range(len(seeds_at))]
    return assemble(parts, table.times_of(frames_in), list(cameras))


def assemble(parts: list[tuple[int, float, np.ndarray, CloudTrack, CloudTrack]], times_ms: np.ndarray,
             cameras: list[str]) -> PatchTrajectories:
    """Clouds' backward and forward tracks -> one :class:`PatchTrajectories` on the reference times."""
    T, V = len(times_ms), len(cameras)
    ids, seed_t, X, vis, photo, alive, carried = [], [], [], [], [], [], []
    for c, t_seed, _, back, fwd in parts:
        N = len(fwd.X_cm)
        Xc = np.full((N, T, 3, 3), np.nan)
        vc, pc, ac = np.zeros((N, T, V), bool), np.zeros((N, T, V), bool), np.zeros((N, T), bool)
        cc = np.zeros((N, T), bool)
        for track in (back, fwd):
            pos = np.searchsorted(times_ms, track.times_ms)
            Xc[:, pos], vc[:, pos], pc[:, pos], ac[:, pos] = track.X_cm, track.visible, track.photometric, track.alive
            if track.carried is not None:
                cc[:, pos] |= track.carried
        ids.append(c * ID_STRIDE + np.arange(N))
        seed_t.append(np.full(N, t_seed))
        X.append(Xc), vis.append(vc), photo.append(pc), alive.append(ac), carried.append(cc)
    if not ids:
        return PatchTrajectories(ids=np.zeros(0, np.int64), seed_time_ms=np.zeros(0), times_ms=times_ms,
                                 cameras=cameras, X_cm=np.zeros((0, T, 3, 3)), normal=np.zeros((0, T, 3)),
                                 visible=np.zeros((0, T, V), bool), photometric=np.zeros((0, T, V), bool),
                                 alive=np.zeros((0, T), bool), carried=np.zeros((0, T), bool))
    Xa = np.concatenate(X)
    with np.errstate(invalid="ignore"):
        _, _, normal = patch_axes(Xa[..., 0, :].reshape(-1, 3), Xa[..., 1, :].reshape(-1, 3),
                                  Xa[..., 2, :].reshape(-1, 3))
    return PatchTrajectories(ids=np.concatenate(ids), seed_time_ms=np.concatenate(seed_t), times_ms=times_ms,
                             cameras=cameras, X_cm=Xa, normal=normal.reshape(Xa.shape[:2] + (3,)),
                             visible=np.concatenate(vis), photometric=np.concatenate(photo),
                             alive=np.concatenate(alive), carried=np.concatenate(carried))
