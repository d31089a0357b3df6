"""The patch trajectory stream: seed clouds every ``seed_every_frames`` reference frames, each tracked
``track_frames`` frames backward and forward.

**One time for all streams.** The stream is kept at the frame times of one *reference stream* (by default the
stream with the most cameras, ties by name: VGA in the dome, the one HD stream of a rig). Clouds are seeded from
the reference stream's cameras at a seed frame (their images share its time); every other camera joins through
its own frames, brought to the reference times as the skeleton stages bring detections there: its 2D track is
interpolated linearly between the two frames around the time (``frame_brackets``), see :mod:`.track`, and it is
judged (photometric term) on its nearest frame with the patch moved to that frame's time.
"""
from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.recon.errors import ReconError
from dome_calib.recon.patches.frames import FrameSource, patch_axes
from dome_calib.recon.patches.model import PatchOptions, PatchTrajectories
from dome_calib.recon.patches.seed import Seeds, seed_patches
from dome_calib.recon.patches.seed_features import seed_from_features
from dome_calib.recon.patches.refine import refine_normals
from dome_calib.recon.patches.track import Clock, CloudTrack, judged_frames, quantise_cm, track_cloud
from dome_calib.recon.patches.visibility import camera_neighbours, estimate_visibility
from dome_calib.recon.project import ViewSet, view_set
from dome_calib.recon.streams import cameras_by_stream

logger = logging.getLogger(__name__)

#: Patch ids: cloud number * ID_STRIDE + position in the cloud.
ID_STRIDE = 100_000


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
              seeds: Seeds, o: PatchOptions, neighbours: np.ndarray | None = None) -> tuple[CloudTrack, CloudTrack]:
    """One cloud (or any subset of its seeds) tracked from ``seed_time_ms`` over ``times_ms`` (increasing, holding
    the seed time): (backward, forward), each in travel order from the seed."""
    neighbours = camera_neighbours(views, o.prior_neighbours) if neighbours is None else neighbours
    t = np.asarray(times_ms, dtype=float)
    s = int(np.argmin(np.abs(t - seed_time_ms)))
    X = quantise_cm(seeds.X_cm)
    if o.refine_normals and len(X):
        frames = judged_frames(clocks, float(t[s]))
        vis = estimate_visibility(source, views, frames, X, np.zeros_like(X), seeds.seen, None, neighbours, o)
        X = quantise_cm(refine_normals(source, views, frames, X, vis.visible, o))
    back = track_cloud(source, views, clocks, t[:s + 1][::-1], X, seeds.seen, neighbours, o)
    fwd = track_cloud(source, views, clocks, t[s:], X, seeds.seen, neighbours, o)
    return back, fwd


def patch_stream(bundle: Bundle, source: FrameSource, cameras: list[str], span_ms: tuple[float, float],
                 options: PatchOptions | None = None, *, stream: str | None = None,
                 seed_frames: list[int] | None = None,
                 progress: Callable[[int, int], None] | None = None) -> PatchTrajectories:
    """The dense patch trajectory stream of ``cameras`` (all streams) over ``span_ms``.

    Args:
        bundle: cameras and sync tables (the cameras' own streams).
        source: images (:class:`~dome_calib.recon.patches.frames.FrameSource`).
        stream: the reference stream (default :func:`reference_stream`).
        seed_frames: the reference frames that seed clouds (default every ``seed_every_frames``-th in the span).
        progress: called with (clouds done, clouds).
    Example:
        >>> traj = patch_stream(bundle, TexturedScene(bundle, truth), vga_names, (1000.0, 3000.0))
    """
    o = options or PatchOptions()
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
    parts = []
    for c, f in enumerate(seeds_at):
        pos = int(np.searchsorted(frames_in, f))
        if pos >= len(frames_in) or frames_in[pos] != f:
            raise ReconError(f"seed frame {int(f)} of stream {stream} is not inside the span")
        window = frames_in[max(pos - o.track_frames, 0):pos + o.track_frames + 1]
        t_seed = table.time_of(int(f))
        seeder = seed_from_features if o.seed_method == "features" else seed_patches
        ref_seeds = seeder(source, ref_views, {n: int(f) for n in ref_names}, o)
        seen = np.zeros((len(ref_seeds.X_cm), len(cameras)), bool)
        seen[:, ref_pos] = ref_seeds.seen
        seeds = Seeds(X_cm=ref_seeds.X_cm, normal=ref_seeds.normal, seen=seen)
        back, fwd = run_cloud(source, views, clocks, t_seed, table.times_of(window), seeds, o, neighbours)
        parts.append((c, t_seed, window, back, fwd))
        if progress is not None:
            progress(c + 1, len(seeds_at))
    return assemble(parts, table.times_of(frames_in), list(cameras))


def assemble(parts: list[tuple[int, float, np.ndarray, CloudTrack, CloudTrack]], times_ms: np.ndarray,
             cameras: list[str]) -> PatchTrajectories:
    """Clouds' backward and forward tracks -> one :class:`PatchTrajectories` on the reference times."""
    T, V = len(times_ms), len(cameras)
    ids, seed_t, X, vis, photo, alive = [], [], [], [], [], []
    for c, t_seed, _, back, fwd in parts:
        N = len(fwd.X_cm)
        Xc = np.full((N, T, 3, 3), np.nan)
        vc, pc, ac = np.zeros((N, T, V), bool), np.zeros((N, T, V), bool), np.zeros((N, T), bool)
        for track in (back, fwd):
            pos = np.searchsorted(times_ms, track.times_ms)
            Xc[:, pos], vc[:, pos], pc[:, pos], ac[:, pos] = track.X_cm, track.visible, track.photometric, track.alive
        ids.append(c * ID_STRIDE + np.arange(N))
        seed_t.append(np.full(N, t_seed))
        X.append(Xc), vis.append(vc), photo.append(pc), alive.append(ac)
    if not ids:
        return PatchTrajectories(ids=np.zeros(0, np.int64), seed_time_ms=np.zeros(0), times_ms=times_ms,
                                 cameras=cameras, X_cm=np.zeros((0, T, 3, 3)), normal=np.zeros((0, T, 3)),
                                 visible=np.zeros((0, T, V), bool), photometric=np.zeros((0, T, V), bool),
                                 alive=np.zeros((0, T), bool))
    Xa = np.concatenate(X)
    with np.errstate(invalid="ignore"):
        _, _, normal = patch_axes(Xa[..., 0, :].reshape(-1, 3), Xa[..., 1, :].reshape(-1, 3),
                                  Xa[..., 2, :].reshape(-1, 3))
    return PatchTrajectories(ids=np.concatenate(ids), seed_time_ms=np.concatenate(seed_t), times_ms=times_ms,
                             cameras=cameras, X_cm=Xa, normal=normal.reshape(Xa.shape[:2] + (3,)),
                             visible=np.concatenate(vis), photometric=np.concatenate(photo),
                             alive=np.concatenate(alive))
