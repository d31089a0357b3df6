"""Every camera's unlabelled people, grouped by stream (one clock, one sync table), before any time is chosen.

:func:`stream_layouts` checks which cameras and frames a detections folder holds against the bundle's sync tables
(VGA, HD, each Kinect colour camera; one shared stream when the bundle has none: universal time = frame /
``shared_fps``); :func:`fill_stream` / :func:`people_streams` put the people in arrays. A source hands a chunk of
time its streams: :class:`InMemorySource` (streams already read) or :class:`FileSource` (reads only the OpenPose
files of the frames that bracket the chunk's times). The streams are brought to universal times by
:mod:`dome_calib.recon.people.resample`.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle, CameraType, SyncTable
from dome_calib.recon.body_models import EXTRA_JOINTS, BodyModel
from dome_calib.recon.errors import ReconError
from dome_calib.recon.openpose_io import read_openpose_files
from dome_calib.recon.people.detection_cache import KeptDetections, load, store
from dome_calib.recon.streams import cameras_by_stream, frame_period_ms

SHARED_STREAM = "shared"


@dataclass(frozen=True)
class PeopleStream:
    """Unlabelled people of the cameras of one stream: frame_index (F,) increasing; kp (F, V_s, N, 19, 3)
    ``[x_px, y_px, c]`` float32 (c = 0: no joint; a person slot with no joint is empty)."""

    stream: str
    table: SyncTable
    cameras: list[str]
    frame_index: np.ndarray
    kp: np.ndarray


@dataclass(frozen=True)
class StreamLayout:
    """Which cameras and frames a stream has, before any detection is read: frame_index (F,) increasing, all in
    ``table``."""

    stream: str
    table: SyncTable
    cameras: list[str]
    frame_index: np.ndarray


def stream_layouts(bundle: Bundle, frames_of: dict[str, Iterable[int]],
                   files: dict[str, dict[int, Path]] | None = None, *, shared_fps: Fraction | None = None
                   ) -> list[StreamLayout]:
    """camera -> its frame indices -> one :class:`StreamLayout` per stream (VGA, HD, each Kinect; one shared stream
    when the bundle has no sync tables, universal time = frame / ``shared_fps``).

    A frame that the camera's sync table lacks is refused (ReconError naming file, camera and frame); so are the
    cameras of several streams without sync tables (:func:`refuse_mixed_clocks`).
    """
    files = files or {}
    groups: dict[str, list[str]] = {}
    tables: dict[str, SyncTable] = {}
    if bundle.sync is None:
        refuse_mixed_clocks(bundle, frames_of)
        if shared_fps is None:  # no rate is assumed: 60 fps detections read at 30 came out with every time doubled
            raise ReconError(f"bundle {bundle.seq} has no sync tables, so the detections' frame rate is unknown: "
                             "give it (--fps 60, --fps 30000/1001) or the videos the detections came from (--videos)")
        frames = np.unique(np.array([f for c in frames_of.values() for f in c], dtype=np.int64))
        period = float(1000 / Fraction(shared_fps))
        tables[SHARED_STREAM] = SyncTable(index=frames, univ_time_ms=frames * period)
        groups[SHARED_STREAM] = sorted(frames_of)
    else:
        groups, tables = cameras_by_stream(bundle, sorted(frames_of))
    out = []
    for stream, names in groups.items():
        table = tables[stream]
        frames = np.unique(np.array([f for n in names for f in frames_of[n]], dtype=np.int64))
        inside = np.isin(frames, table.index)
        if not inside.all():
            f = int(frames[~inside][0])
            cam = next(n for n in names if f in set(frames_of[n]))
            where = files.get(cam, {}).get(f, f"camera {cam}")
            raise ReconError(f"{where}: camera {cam}: frame {f}: not in the {stream} sync table (frames "
                             f"{int(table.index[0])}..{int(table.index[-1])})")
        out.append(StreamLayout(stream=stream, table=table, cameras=names, frame_index=frames))
    return out


def _clock_of(bundle: Bundle, name: str) -> str:
    """The clock a camera's own frame numbers count: its stream (vga, hd), each Kinect colour camera its own."""
    cam = bundle.cameras[name]
    return f"Kinect {name}" if cam.type == CameraType.KINECT_COLOR else str(cam.type)


def refuse_mixed_clocks(bundle: Bundle, frames_of: dict[str, Iterable[int]]) -> None:
    """A bundle without sync tables puts every camera on one frame index: right for one stream (a synchronised
    rig), wrong for cameras of several streams (VGA, HD, Kinects), whose frame numbers each count their own clock
    (merged, the demo's 7 people came out as 27). Refused in one line saying what to do."""
    clocks: dict[str, list[str]] = {}
    for name in sorted(frames_of):
        clocks.setdefault(_clock_of(bundle, name), []).append(name)
    if len(clocks) < 2:
        return
    spans = []
    for clock, names in sorted(clocks.items()):
        frames = [f for n in names for f in frames_of[n]]
        spans.append(f"{clock}: {len(names)} cameras, frames {min(frames)}..{max(frames)}")
    raise ReconError(f"bundle {bundle.seq} has no sync tables, so every camera would share one frame index, but the "
                     f"detections hold cameras of {len(clocks)} streams that each number their own frames "
                     f"({'; '.join(spans)}): add the sync tables to the bundle (`timecode sync SESSION -o BUNDLE` writes "
                     f"synctables_{bundle.seq}.json), or give a detections folder holding one stream's cameras only")


def fill_stream(layout: StreamLayout, people: dict[str, dict[int, np.ndarray]], n_joints: int = 19) -> PeopleStream:
    """A layout's cameras' people (camera -> {frame -> (N, n_joints, 3)}; frames outside the layout ignored) ->
    :class:`PeopleStream` (``n_joints``: 19, or 19 + the model's extra joints; a reading of more joints gives its
    first ``n_joints``)."""
    names, frames = layout.cameras, layout.frame_index
    N = max([len(p) for n in names for f, p in people.get(n, {}).items()] + [1])
    kp = np.zeros((len(frames), len(names), N, n_joints, 3), dtype=np.float32)
    for v, n in enumerate(names):
        for f, p in people.get(n, {}).items():
            k = np.searchsorted(frames, f)
            if k < len(frames) and frames[k] == f:
                kp[k, v, : len(p)] = p[:, :n_joints]  # a reading with the extra joints serves joints19 too
    return PeopleStream(stream=layout.stream, table=layout.table, cameras=names, frame_index=frames, kp=kp)


def people_streams(bundle: Bundle, people: dict[str, dict[int, np.ndarray]],
                   files: dict[str, dict[int, Path]] | None = None, *, shared_fps: Fraction | None = None
                   ) -> list[PeopleStream]:
    """camera -> {frame -> (N, 19, 3)} -> one :class:`PeopleStream` per stream (see :func:`stream_layouts`)."""
    return [fill_stream(layout, people) for layout in stream_layouts(bundle, people, files, shared_fps=shared_fps)]


def frames_near(layout: StreamLayout, t0_ms: float, t1_ms: float, max_gap_frames: float) -> np.ndarray:
    """(F,) bool: the layout's frames that can bracket a time in [t0, t1]."""
    times = layout.table.times_of(layout.frame_index)
    period = frame_period_ms(layout.table)
    margin = (max_gap_frames + 1.0) * (period if np.isfinite(period) else 0.0)
    return (times >= t0_ms - margin) & (times <= t1_ms + margin)


@dataclass(frozen=True)
class InMemorySource:
    """Streams already read; :meth:`chunk` keeps the frames that bracket a span of times."""

    streams: list[PeopleStream]

    @property
    def cameras(self) -> list[str]:
        return [n for s in self.streams for n in s.cameras]

    def chunk(self, t0_ms: float, t1_ms: float, max_gap_frames: float) -> list[PeopleStream]:
        out = []
        for s in self.streams:
            keep = frames_near(s, t0_ms, t1_ms, max_gap_frames)  # PeopleStream has StreamLayout's fields
            out.append(PeopleStream(stream=s.stream, table=s.table, cameras=s.cameras, frame_index=s.frame_index[keep],
                                    kp=s.kp[keep]))
        return out


@dataclass(frozen=True)
class FileSource:
    """Detections still on disk (camera -> {frame -> OpenPose file}): :meth:`chunk` reads only the files of the
    frames that bracket a span of times, so a long session is never in memory at once (each executor task reads its
    own chunk's files: workers need the detections folder at the same path). With ``cache_dir`` (a run's own folder,
    :mod:`~dome_calib.recon.people.detection_cache`) what one pass read is kept there, every joint the run uses
    (joints19 and the model's extra joints), and later passes read only the frames it lacks: the same streams either
    way, so each file is read once. With ``extras`` the streams hold 19 + E joints (the model's joints that joints19
    lacks after joints19): the extra joints' pass, :mod:`~dome_calib.recon.people.extras`."""

    layouts: list[StreamLayout]
    files: dict[str, dict[int, Path]]
    body_model: BodyModel
    cache_dir: Path | None = None
    digests: dict[str, dict[int, bytes]] | None = None  # what each file's bytes are on the head (a cluster run)
    extras: bool = False

    @property
    def cameras(self) -> list[str]:
        return [n for s in self.layouts for n in s.cameras]

    def kept(self) -> KeptDetections | None:
        """What the passes have kept, by camera (None without ``cache_dir``)."""
        if self.cache_dir is None:
            return None
        return KeptDetections(folder=self.cache_dir, streams=[list(s.cameras) for s in self.layouts])

    def chunk(self, t0_ms: float, t1_ms: float, max_gap_frames: float) -> list[PeopleStream]:
        out = []
        for i, layout in enumerate(self.layouts):
            frames = layout.frame_index[frames_near(layout, t0_ms, t1_ms, max_gap_frames)]
            cache = self.cache_dir
            kept = load(cache, i, layout.cameras, frames) if cache is not None else {}
            wanted = set(frames.tolist())
            files = {n: {f: p for f, p in self.files.get(n, {}).items() if f in wanted and (n, f) not in kept}
                     for n in layout.cameras}
            # kept: with the extra joints, so that the extra joints' pass reads no file again
            people = read_openpose_files(files, self.body_model, self.digests,
                                         extras=self.extras or cache is not None)
            if cache is not None:
                store(cache, i, layout.cameras, people)
            for (n, f), p in kept.items():
                people.setdefault(n, {})[f] = p
            sub = StreamLayout(stream=layout.stream, table=layout.table, cameras=layout.cameras, frame_index=frames)
            out.append(fill_stream(sub, people, 19 + len(EXTRA_JOINTS[self.body_model]) if self.extras else 19))
        return out
