"""Triangulate across streams of different rates: VGA (25 fps), HD (29.97 fps), each Kinect colour camera (~30 fps,
its own clock).

Each stream's 2D tracks are interpolated to a universal time with its sync table (``SyncTable.bracket``: the two
frames around the time and their weights; outside the table's span there is nothing; a dropped frame widens the
gap and a gap wider than ``max_gap_frames`` nominal periods is not bridged). The interpolated detections of all
streams are then triangulated together (:func:`dome_calib.recon.triangulate.triangulate`), a batch of times at a
time, so the paper's "VGA only because the streams do not coincide in time" restriction goes away.
"""
from __future__ import annotations

import logging
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated
from enum import StrEnum

import numpy as np

from dome_calib.bundle import Bundle, CameraType, SyncTable
from dome_calib.options import Field, Lax, options
from dome_calib.recon.errors import ReconError
from dome_calib.recon.project import ViewSet
from dome_calib.recon.triangulate import TriangulationOptions, triangulate

logger = logging.getLogger(__name__)


class Interpolation(StrEnum):
    LINEAR = "linear"  # w0 * frame0 + w1 * frame1 (the method)
    NEAREST = "nearest"  # the bracketing frame with the larger weight (ablation: what interpolation buys)


@options
class InterpolationOptions:
    """How streams are brought to a universal time: ``mode``; brackets wider than ``max_gap_frames`` nominal
    frame periods are not bridged."""

    mode: Annotated[Interpolation, Lax] = Interpolation.LINEAR
    max_gap_frames: Annotated[float, Field(ge=1)] = 2.5  # one frame period at least


@dataclass(kw_only=True)
class StreamTracks:
    """2D tracks of the cameras of one stream (one clock, one sync table).

    stream: "vga", "hd" or a Kinect node ("KINECTNODE3", its colour camera); cameras (V_s,) names;
    frame_index (F,) increasing frame indices of ``table``; uv_px (F, V_s, J, 2) OpenCV pixels (NaN = none);
    conf (F, V_s, J) detection confidence (0 or NaN = none).
    """

    stream: str
    table: SyncTable
    cameras: list[str]
    frame_index: np.ndarray
    uv_px: np.ndarray
    conf: np.ndarray

    def __post_init__(self) -> None:
        F, V = len(self.frame_index), len(self.cameras)
        if self.uv_px.ndim != 4 or self.uv_px.shape[:2] != (F, V) or self.uv_px.shape[3] != 2:
            raise ReconError(f"stream {self.stream}: uv_px has shape {self.uv_px.shape} but expected ({F}, {V}, J, 2)")
        if self.conf.shape != self.uv_px.shape[:3]:
            raise ReconError(f"stream {self.stream}: conf has shape {self.conf.shape} but expected "
                             f"{self.uv_px.shape[:3]}")
        if F > 1 and np.any(np.diff(self.frame_index) <= 0):
            raise ReconError(f"stream {self.stream}: frame indices must increase")
        if np.any(self.conf < 0) or np.any(self.conf > 1):
            f, v, j = np.argwhere((self.conf < 0) | (self.conf > 1))[0]
            raise ReconError(f"stream {self.stream}: camera {self.cameras[v]}: frame {int(self.frame_index[f])}: joint "
                             f"{j}: confidence {self.conf[f, v, j]:g} outside [0, 1] (NaN = not detected)")
        # Cleaned copies for interpolation: finite pixels, confidence 0 wherever there is no usable detection.
        finite = np.all(np.isfinite(self.uv_px), axis=-1)
        self._uv = np.where(finite[..., None], self.uv_px, 0.0)
        self._conf = np.where(finite & np.isfinite(self.conf), self.conf, 0.0)


@dataclass(frozen=True)
class SkeletonSequence:
    """Triangulated joints at universal times: times_ms (T,); X_cm (T, J, 3) world (NaN = not reconstructed);
    confidence (T, J) (-1 = not reconstructed); n_inliers (T, J) supporting views; rms_px (T, J)."""

    times_ms: np.ndarray
    X_cm: np.ndarray
    confidence: np.ndarray
    n_inliers: np.ndarray
    rms_px: np.ndarray


def stream_of_camera(bundle: Bundle, name: str) -> tuple[str, SyncTable]:
    """The stream a camera belongs to and its sync table: VGA -> "vga", HD -> "hd", 50_0n -> "KINECTNODE<n>"."""
    if name not in bundle.cameras:
        raise ReconError(f"bundle {bundle.seq}: no camera named {name!r}")
    cam = bundle.cameras[name]
    sync = bundle.sync
    if cam.type == CameraType.KINECT_COLOR:
        node = re.fullmatch(r"\d+_0*([1-9]\d*)", name)
        if node is None:
            raise ReconError(f"bundle {bundle.seq}: Kinect colour camera {name!r} is not named 50_<n>, so its "
                             "Kinect's sync table KINECTNODE<n> is unknown")
        stream = f"KINECTNODE{node.group(1)}"
        tables, file = (sync.kinect_color if sync else {}), f"ksynctables_{bundle.seq}.json (kinect.color)"
    else:
        stream = str(cam.type)
        tables, file = (sync.streams if sync else {}), f"synctables_{bundle.seq}.json"
    if stream not in tables:
        raise ReconError(f"bundle {bundle.seq}: camera {name} needs sync table {stream!r} in {file}, which is missing")
    return stream, tables[stream]


def cameras_by_stream(bundle: Bundle, names: list[str]) -> tuple[dict[str, list[str]], dict[str, SyncTable]]:
    """Cameras grouped by the stream (clock) they belong to, in the order given, and each stream's sync table."""
    groups: dict[str, list[str]] = {}
    tables: dict[str, SyncTable] = {}
    for name in names:
        stream, table = stream_of_camera(bundle, name)
        groups.setdefault(stream, []).append(name)
        tables[stream] = table
    return groups, tables


def group_by_stream(bundle: Bundle, detections: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
                    ) -> list[StreamTracks]:
    """Per-camera detections -> one :class:`StreamTracks` per stream.

    Args:
        detections: camera name -> (frame_index (F_c,), uv_px (F_c, J, 2), conf (F_c, J)); cameras of one stream
            may cover different frames (the union is taken, missing frames have confidence 0).
    """
    J = {d[1].shape[1] for d in detections.values()}
    if len(J) > 1:
        raise ReconError(f"detections have different joint counts across cameras: {sorted(J)}")
    groups, tables = cameras_by_stream(bundle, sorted(detections))
    out = []
    for stream, names in groups.items():
        frames = np.unique(np.concatenate([np.asarray(detections[n][0], dtype=np.int64) for n in names]))
        nj = detections[names[0]][1].shape[1]
        uv = np.full((len(frames), len(names), nj, 2), np.nan)
        conf = np.zeros((len(frames), len(names), nj))
        for v, n in enumerate(names):
            fi, u, c = detections[n]
            pos = np.searchsorted(frames, np.asarray(fi, dtype=np.int64))
            uv[pos, v], conf[pos, v] = u, c
        out.append(StreamTracks(stream=stream, table=tables[stream], cameras=names, frame_index=frames,
                                uv_px=uv, conf=conf))
    return out


def frame_period_ms(table: SyncTable) -> float:
    """Nominal frame period of a stream: the median spacing of its sync table (ms; infinity with fewer than 2
    frames: nothing to bridge)."""
    return float(np.median(np.diff(table.univ_time_ms))) if len(table.index) > 1 else float("inf")


@dataclass(frozen=True)
class Brackets:
    """A stream's two frames around each of (T,) universal times, as positions into the frames it holds.

    pos0, pos1 (T,) positions in the stream's ``frame_index`` (0 where it lacks the frame); has0, has1 (T,) the
    stream holds that frame; w0, w1 (T,) interpolation weights (``w0 + w1 = 1``; both 0 where not usable);
    usable (T,) inside the table's span and the bracket no wider than ``max_gap_frames`` nominal periods.
    """

    pos0: np.ndarray
    pos1: np.ndarray
    has0: np.ndarray
    has1: np.ndarray
    w0: np.ndarray
    w1: np.ndarray
    usable: np.ndarray

    @staticmethod
    def take(values: np.ndarray, pos: np.ndarray, has: np.ndarray) -> np.ndarray:
        """values (F, ...) of the stream's frames -> (T, ...) at the positions, 0 where the stream lacks the frame
        (also when it holds no frame at all: a chunk of time its detections do not reach)."""
        if len(values) == 0:
            return np.zeros((len(pos),) + values.shape[1:], dtype=values.dtype)
        out = values[pos]  # a copy: zeroed in place (one pass over the frames, not two)
        out[~np.asarray(has, dtype=bool)] = 0
        return out


def frame_brackets(table: SyncTable, frame_index: np.ndarray, univ_time_ms: np.ndarray, *,
                   max_gap_frames: float) -> Brackets:
    """The frames (``frame_index`` (F,) increasing, F may be 0) around (T,) universal times (see :class:`Brackets`).

    The one place where a stream is brought to universal times: :func:`interpolate_stream` (one person's tracks)
    and :func:`dome_calib.recon.people.resample.interpolate_people` (unlabelled people) both read it.
    """
    t = np.asarray(univ_time_ms, dtype=float)
    i0, i1, w0, w1 = table.bracket(t)
    gap = table.univ_time_ms[np.searchsorted(table.index, i1)] - table.univ_time_ms[np.searchsorted(table.index, i0)]
    usable = np.isfinite(w1) & (gap <= max_gap_frames * frame_period_ms(table))
    frames = np.asarray(frame_index)

    def position(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if len(frames) == 0:
            return np.zeros(len(idx), dtype=np.int64), np.zeros(len(idx), dtype=bool)
        pos = np.clip(np.searchsorted(frames, idx), 0, len(frames) - 1)
        return pos, frames[pos] == idx

    (pos0, has0), (pos1, has1) = position(i0), position(i1)
    w1 = np.where(usable, np.nan_to_num(w1, nan=0.0), 0.0)
    return Brackets(pos0=pos0, pos1=pos1, has0=has0, has1=has1, w0=np.where(usable, 1.0 - w1, 0.0), w1=w1,
                    usable=usable)


def interpolate_stream(tracks: StreamTracks, univ_time_ms: np.ndarray, *, max_gap_frames: float = 2.5,
                       mode: Interpolation | str = Interpolation.LINEAR) -> tuple[np.ndarray, np.ndarray]:
    """Detections of one stream linearly interpolated to universal times.

    Args:
        univ_time_ms: (T,) universal times.
        max_gap_frames: brackets wider than this many nominal frame periods (median spacing of the table) are
            not bridged (one dropped frame is; motion over longer gaps is not linear enough).
        mode: ``linear`` (default) or ``nearest`` (the bracketing frame with the larger weight; an ablation).
    Returns:
        uv_px (T, V_s, J, 2) and conf (T, V_s, J): ``w0 * uv[f0] + w1 * uv[f1]``; confidence is the smaller of the
        two frames' (a frame with weight 0 is not needed); 0 outside the span, across wide gaps or where a
        needed frame has no detection.
    """
    b = frame_brackets(tracks.table, tracks.frame_index, univ_time_ms, max_gap_frames=max_gap_frames)
    u0, c0 = Brackets.take(tracks._uv, b.pos0, b.has0), Brackets.take(tracks._conf, b.pos0, b.has0)
    u1, c1 = Brackets.take(tracks._uv, b.pos1, b.has1), Brackets.take(tracks._conf, b.pos1, b.has1)
    a0, a1 = b.w0[:, None, None], b.w1[:, None, None]
    if Interpolation(mode) == Interpolation.NEAREST:
        a1 = (a1 > 0.5).astype(float)
        a0 = 1.0 - a1
    need0, need1 = a0 > 0, a1 > 0
    ok = b.usable[:, None, None] & (~need0 | (c0 > 0)) & (~need1 | (c1 > 0))
    conf = np.where(ok, np.minimum(np.where(need0, c0, np.inf), np.where(need1, c1, np.inf)), 0.0)
    uv = a0[..., None] * u0 + a1[..., None] * u1
    uv = np.where((conf > 0)[..., None], uv, np.nan)
    return uv, conf


def gather_streams(streams: list[StreamTracks], univ_time_ms: np.ndarray,
                   interpolation: InterpolationOptions | None = None) -> tuple[list[str], np.ndarray, np.ndarray]:
    """All streams interpolated to (T,) times: (camera names (V,), uv_px (T, V, J, 2), conf (T, V, J))."""
    interpolation = interpolation or InterpolationOptions()
    names, uvs, confs = [], [], []
    for s in streams:
        uv, conf = interpolate_stream(s, univ_time_ms, max_gap_frames=interpolation.max_gap_frames,
                                      mode=interpolation.mode)
        names += s.cameras
        uvs.append(uv)
        confs.append(conf)
    if len(set(names)) != len(names):
        raise ReconError("a camera appears in more than one stream")
    return names, np.concatenate(uvs, axis=1), np.concatenate(confs, axis=1)


def triangulate_streams(views: ViewSet, streams: list[StreamTracks], univ_time_ms: np.ndarray,
                        options: TriangulationOptions | None = None, *, batch_times: int = 16,
                        interpolation: InterpolationOptions | None = None,
                        progress: Callable[[int], None] | None = None) -> SkeletonSequence:
    """Triangulate every joint at every universal time from all streams' interpolated detections.

    Args:
        views: a view set holding (at least) every camera of ``streams``.
        univ_time_ms: (T,) times; batch_times: times solved together (P = batch_times x J points per batch).
        interpolation: how each stream is brought to the times (default linear, gaps up to 2.5 frames).
        progress: called with the number of times finished after each batch.
    Example:
        >>> seq = triangulate_streams(view_set(bundle), group_by_stream(bundle, detections), vga_times_ms)
    """
    options = options or TriangulationOptions()
    t = np.asarray(univ_time_ms, dtype=float)
    names = [n for s in streams for n in s.cameras]
    sub = views.subset(names)
    J = streams[0].uv_px.shape[2] if streams else 0
    X = np.full((len(t), J, 3), np.nan)
    conf = np.full((len(t), J), -1.0)
    n_inl = np.zeros((len(t), J), dtype=np.int64)
    rms = np.full((len(t), J), np.nan)
    for start in range(0, len(t), batch_times):
        sl = slice(start, min(start + batch_times, len(t)))
        _, uv, c = gather_streams(streams, t[sl], interpolation)
        T_b, V = c.shape[:2]
        tri = triangulate(sub, uv.transpose(0, 2, 1, 3).reshape(T_b * J, V, 2),
                          c.transpose(0, 2, 1).reshape(T_b * J, V), options)
        X[sl] = tri.X_cm.reshape(T_b, J, 3)
        conf[sl] = tri.confidence.reshape(T_b, J)
        n_inl[sl] = tri.n_inliers.reshape(T_b, J)
        rms[sl] = tri.rms_px.reshape(T_b, J)
        if progress is not None:
            progress(sl.stop)
    return SkeletonSequence(times_ms=t, X_cm=X, confidence=conf, n_inliers=n_inl, rms_px=rms)
