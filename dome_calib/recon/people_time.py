"""Unlabelled people of every camera brought to universal times (the multi-person counterpart of
:mod:`dome_calib.recon.streams`).

Each camera's detections are at its own stream's frame times. At a universal time t the two bracketing frames of
the stream (``SyncTable.bracket``) are used: the people of frame f0 and frame f1 are matched to each other in 2D
(:func:`greedy_match` on the mean pixel distance of their common joints, gated relative to the person's size) and
each matched pair is interpolated joint by joint (``w0 * a + w1 * b``; a joint seen in one frame only is kept if
that frame is the nearer one). People found in one frame only are kept if that frame is the nearer one. This is
2D tracking over one frame step: local, stateless (chunks of time are independent) and linear in cameras; the
identity over longer spans is kept in 3D (:mod:`dome_calib.recon.tracking`). A time that coincides with a frame
needs no matching.

A bundle without sync tables: every camera shares one frame index; universal time = frame / ``shared_fps``.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle, SyncTable
from dome_calib.recon.body_models import BodyModel
from dome_calib.recon.errors import ReconError
from dome_calib.recon.openpose_io import read_openpose_files
from dome_calib.recon.streams import cameras_by_stream

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


def greedy_match(cost: np.ndarray, gate: np.ndarray | float) -> np.ndarray:
    """Vectorised greedy one-to-one matching: (..., A, B) costs -> (..., A) index into B or -1.

    Repeatedly takes the smallest cost below ``gate`` (broadcast to cost) over all rows of a batch element. Costs
    are quantised to 1e-3 before comparison and ties go to the lowest (a, b), so the result does not rest on the
    last bits of a float. For the few people per view here it equals the optimal assignment except when two
    people are nearly equally close to two others.
    """
    c = np.round(np.where(cost < gate, cost, np.inf), 3)
    batch, (A, B) = c.shape[:-2], c.shape[-2:]
    if A == 0 or B == 0:
        return np.full((*batch, A), -1, dtype=np.int64)
    c = c.reshape(-1, A * B).copy()
    out = np.full((c.shape[0], A), -1, dtype=np.int64)
    rows = np.arange(c.shape[0])
    for _ in range(min(A, B)):
        k = np.argmin(c, axis=1)
        ok = np.isfinite(c[rows, k])
        if not ok.any():
            break
        a, b = k // B, k % B
        out[rows[ok], a[ok]] = b[ok]
        view = c.reshape(-1, A, B)
        view[rows[ok], a[ok], :] = np.inf
        view[rows[ok], :, b[ok]] = np.inf
    return out.reshape(*batch, A)


@dataclass(frozen=True)
class StreamLayout:
    """Which cameras and frames a stream has, before any detection is read: frame_index (F,) increasing, all in
    ``table``."""

    stream: str
    table: SyncTable
    cameras: list[str]
    frame_index: np.ndarray


def stream_layouts(bundle: Bundle, frames_of: dict[str, Iterable[int]],
                   files: dict[str, dict[int, Path]] | None = None, *, shared_fps: Fraction = Fraction(30)
                   ) -> list[StreamLayout]:
    """camera -> its frame indices -> one :class:`StreamLayout` per stream (VGA, HD, each Kinect; one shared stream
    when the bundle has no sync tables, universal time = frame / ``shared_fps``).

    A frame that the camera's sync table lacks is refused (ReconError naming file, camera and frame).
    """
    files = files or {}
    groups: dict[str, list[str]] = {}
    tables: dict[str, SyncTable] = {}
    if bundle.sync is None:
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


def fill_stream(layout: StreamLayout, people: dict[str, dict[int, np.ndarray]]) -> PeopleStream:
    """A layout's cameras' people (camera -> {frame -> (N, 19, 3)}; frames outside the layout ignored) ->
    :class:`PeopleStream`."""
    names, frames = layout.cameras, layout.frame_index
    N = max([len(p) for n in names for f, p in people.get(n, {}).items()] + [1])
    kp = np.zeros((len(frames), len(names), N, 19, 3), dtype=np.float32)
    for v, n in enumerate(names):
        for f, p in people.get(n, {}).items():
            k = np.searchsorted(frames, f)
            if k < len(frames) and frames[k] == f:
                kp[k, v, : len(p)] = p
    return PeopleStream(stream=layout.stream, table=layout.table, cameras=names, frame_index=frames, kp=kp)


def people_streams(bundle: Bundle, people: dict[str, dict[int, np.ndarray]],
                   files: dict[str, dict[int, Path]] | None = None, *, shared_fps: Fraction = Fraction(30)
                   ) -> list[PeopleStream]:
    """camera -> {frame -> (N, 19, 3)} -> one :class:`PeopleStream` per stream (see :func:`stream_layouts`)."""
    return [fill_stream(layout, people) for layout in stream_layouts(bundle, people, files, shared_fps=shared_fps)]


def frames_near(layout: StreamLayout, t0_ms: float, t1_ms: float, max_gap_frames: float) -> np.ndarray:
    """(F,) bool: the layout's frames that can bracket a time in [t0, t1]."""
    times = layout.table.times_of(layout.frame_index)
    period = float(np.median(np.diff(layout.table.univ_time_ms))) if len(layout.table.index) > 1 else 0.0
    margin = (max_gap_frames + 1.0) * period
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
    own chunk's files: workers need the detections folder at the same path)."""

    layouts: list[StreamLayout]
    files: dict[str, dict[int, Path]]
    body_model: BodyModel

    @property
    def cameras(self) -> list[str]:
        return [n for s in self.layouts for n in s.cameras]

    def chunk(self, t0_ms: float, t1_ms: float, max_gap_frames: float) -> list[PeopleStream]:
        out = []
        for layout in self.layouts:
            frames = layout.frame_index[frames_near(layout, t0_ms, t1_ms, max_gap_frames)]
            wanted = set(frames.tolist())
            files = {n: {f: p for f, p in self.files.get(n, {}).items() if f in wanted} for n in layout.cameras}
            sub = StreamLayout(stream=layout.stream, table=layout.table, cameras=layout.cameras, frame_index=frames)
            out.append(fill_stream(sub, read_openpose_files(files, self.body_model)))
        return out


def _person_size_px(kp: np.ndarray) -> np.ndarray:
    """(..., 19, 3) -> (...,) diagonal of the bounding box of the detected joints (0 if fewer than 2)."""
    have = kp[..., 2] > 0
    big = np.float32(1e9)
    lo = np.where(have[..., None], kp[..., :2], big).min(axis=-2)
    hi = np.where(have[..., None], kp[..., :2], -big).max(axis=-2)
    return np.where(have.sum(-1) >= 2, np.linalg.norm(hi - lo, axis=-1), 0.0)


def interpolate_people(stream: PeopleStream, univ_time_ms: np.ndarray, *, max_gap_frames: float = 2.5,
                       match_gate: float = 0.25, min_gate_px: float = 15.0) -> np.ndarray:
    """People of one stream at (T,) universal times -> (T, V_s, N_out, 19, 3) (empty slots have c = 0).

    match_gate: two frames' people match if their mean joint distance is below ``match_gate`` x the person's
    bounding-box diagonal (at least ``min_gate_px``). Outside the table's span or across gaps wider than
    ``max_gap_frames`` nominal periods there are no people.
    """
    t = np.asarray(univ_time_ms, dtype=float)
    table = stream.table
    i0, i1, w0, w1 = table.bracket(t)
    period = float(np.median(np.diff(table.univ_time_ms))) if len(table.index) > 1 else np.inf
    t0 = table.univ_time_ms[np.searchsorted(table.index, i0)]
    t1 = table.univ_time_ms[np.searchsorted(table.index, i1)]
    usable = np.isfinite(w1) & (t1 - t0 <= max_gap_frames * period)
    F = len(stream.frame_index)

    def lookup(idx: np.ndarray) -> np.ndarray:
        pos = np.clip(np.searchsorted(stream.frame_index, idx), 0, F - 1)
        have = stream.frame_index[pos] == idx
        return np.where(have[:, None, None, None, None], stream.kp[pos], np.float32(0))

    A, B = lookup(i0), lookup(i1)
    w1 = np.where(usable, np.nan_to_num(w1, nan=0.0), 0.0)
    near_a = w1 <= 0.5
    out = np.where(near_a[:, None, None, None, None], A, B)
    out[~usable] = 0.0
    mix = usable & (w1 > 0) & (w1 < 1)
    if not mix.any():
        return out
    a, b = A[mix], B[mix]  # (M, V, N, 19, 3)
    wb = w1[mix].astype(np.float32)  # (M,)
    near = wb <= 0.5
    both = (a[:, :, :, None, :, 2] > 0) & (b[:, :, None, :, :, 2] > 0)  # (M, V, N, N, 19)
    dist = np.linalg.norm(a[:, :, :, None, :, :2] - b[:, :, None, :, :, :2], axis=-1)
    n_common = both.sum(-1)
    cost = np.where(n_common >= 3, np.where(both, dist, 0).sum(-1) / np.maximum(n_common, 1), np.inf)
    gate = np.maximum(match_gate * _person_size_px(a), min_gate_px)[..., None]
    match = greedy_match(cost, gate)  # (M, V, N)
    M, V, N = match.shape
    bm = np.take_along_axis(b, np.maximum(match, 0)[..., None, None], axis=2)
    matched = match >= 0
    ja, jb = a[..., 2] > 0, bm[..., 2] > 0  # (M, V, N, 19)
    w = wb[:, None, None, None, None]
    interp = (1 - w) * a + w * bm
    interp[..., 2] = np.minimum(a[..., 2], bm[..., 2])
    near5 = near[:, None, None, None, None]
    near4 = near[:, None, None, None]
    joint = np.where((ja & jb)[..., None], interp,
                     np.where((ja & near4)[..., None], a, np.where((jb & ~near4)[..., None], bm, 0)))
    slots_a = np.where(matched[..., None, None], joint, np.where(near5, a, 0))
    used_b = np.zeros((M, V, N), bool)
    mi, vi, ni = np.nonzero(matched)
    used_b[mi, vi, match[mi, vi, ni]] = True
    slots_b = np.where((~used_b & ~near[:, None, None])[..., None, None], b, 0)
    merged = np.concatenate([slots_a, slots_b], axis=2)  # (M, V, 2N, 19, 3)
    full = np.zeros((len(t), V, 2 * N, 19, 3), dtype=np.float32)
    full[:, :, :N] = out
    full[mix] = merged
    filled = (full[..., 2] > 0).any(-1)
    order = np.argsort(~filled, axis=2, kind="stable")
    full = np.take_along_axis(full, order[..., None, None], axis=2)
    keep = max(int(filled.sum(axis=2).max()), 1)
    return full[:, :, :keep]
