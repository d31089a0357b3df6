"""Universal time of every frame from fitted LTC clocks, the sync tables, and the report of the fits.

Universal time is milliseconds on the HD LTC timeline: ``univ_ms = (count0 + hd_tick) * 1000 / hd_fps`` where
``count0`` is the label count of the first locked HD LTC frame (drop-frame labels are converted to their
contiguous count by the codec) and ``hd_tick`` counts HD clock frames from there, continuing through timecode
jumps and past midnight (universal time then exceeds 24 h instead of wrapping).

Chains (each arrow is a fitted line, piecewise per segment):

- HD frame k    -> HD tick (labels)                                             -> universal time
- VGA frame k   -> VGA tick (labels) -> ltc.wav sample (VGA fit) -> HD tick (HD fit) -> universal time
- Kinect frame  -> device time -> universal time, a line fitted to the audio blocks, whose first samples are
  timed by the HD LTC the Kinect microphone recorded (Kinect audio sample -> HD tick -> universal time).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from dome_calib.bundle import SyncTable, SyncTables
from dome_calib.options import options
from dome_calib.schema import NonNegFinite, PosFinite
from timecode.errors import TimecodeError
from timecode.sync.clock import (ChannelClock, ClockError, ClockFitOptions, FrameStarts, LineFit, fit_channel_clock,
                                  restarts_of, robust_line)
from timecode.sync.session import FrameStream, KinectNode, Session

logger = logging.getLogger(__name__)


class SyncError(TimecodeError):
    """Streams cannot be put on universal time (no overlap, no reference, inconsistent references)."""


@options
class SyncOptions:
    """Options of :func:`build_sync`."""

    clock: ClockFitOptions = field(default_factory=ClockFitOptions)
    max_extrapolation_s: NonNegFinite = 2.0  # frames may lie this far outside the LTC their times come from
    device_outlier_sigma: PosFinite = 6.0  # Kinect audio-block timestamp fit: rejection threshold (robust std)
    device_outlier_floor_ms: NonNegFinite = 1.0  # ... never below this
    device_break_ms: PosFinite = 50.0  # a block whose timestamp step disagrees this much starts a new device segment
    strict_kinect: bool = False  # True: a Kinect that cannot be synced is an error; False: flagged and skipped


@dataclass(kw_only=True)
class StreamSummary:
    """One output stream: frames, span, drift against universal time, residual RMS of the fit behind it."""

    name: str  # "vga", "hd", "KINECTNODE1/color"
    n_frames: int
    first_ms: float
    last_ms: float
    drift_ppm: float  # stream clock against the HD clock: (measured period / nominal - 1) * 1e6
    residual_rms_us: float
    n_outliers: int


@dataclass(kw_only=True)
class KinectClock:
    """Device time (100 ns units) -> universal time (ms), piecewise; with the audio clock it came from."""

    audio: ChannelClock
    tick_offset: int  # main HD tick = Kinect-audio tick + tick_offset
    device: list[LineFit]  # x = device_time_100ns, y = univ_ms
    spans: list[tuple[int, int]]  # device-time span of each segment

    def univ_ms(self, device_time_100ns: np.ndarray) -> np.ndarray:
        x = np.asarray(device_time_100ns, dtype=float)
        bounds = [(a[1] + b[0]) / 2 for a, b in zip(self.spans[:-1], self.spans[1:])]
        seg = np.searchsorted(np.asarray(bounds, float), x)
        out = np.empty(x.shape)
        for k, fit in enumerate(self.device):
            out[seg == k] = fit(x[seg == k])
        return out


@dataclass(kw_only=True)
class SyncResult:
    """Everything :func:`build_sync` found: tables, clocks, per-stream summaries, flagged Kinects."""

    seq: str
    tables: SyncTables
    vga: ChannelClock
    hd: ChannelClock
    kinect: dict[str, KinectClock]
    summaries: list[StreamSummary]
    flagged: dict[str, str]  # Kinect node -> why it has no tables
    notes: list[str] = field(default_factory=list)

    def hd_univ_ms(self, hd_tick: np.ndarray | float) -> np.ndarray:
        return hd_univ_ms(self.hd, hd_tick)


def hd_univ_ms(hd: ChannelClock, hd_tick: np.ndarray | float) -> np.ndarray:
    """Universal time (ms) of (fractional) HD ticks."""
    first = hd.labels[0]
    return (first.count_first - first.tick_first + np.asarray(hd_tick, dtype=float)) * (1000.0 / float(hd.fps))


def stream_ticks(stream: FrameStream, clock: ChannelClock, margin_frames: int) -> np.ndarray:
    """Ticks of a stream's frames from its label references (the most common offset wins)."""
    ticks, found = clock.count_to_tick(stream.ref_count, margin_frames=margin_frames)
    if not found.any():
        raise SyncError(f"stream {stream.name}: its reference timecode(s) never occur on {clock.source} "
                        f"(streams do not overlap)")
    offsets = ticks[found] - stream.ref_index[found]
    values, counts = np.unique(offsets, return_counts=True)
    offset = int(values[np.argmax(counts)])
    n_bad = int(found.sum() - counts.max())
    if n_bad:
        logger.warning("stream %s: %d of %d timecode references disagree with the rest", stream.name, n_bad,
                       int(found.sum()))
    return stream.index + offset


def _check_span(name: str, what: np.ndarray, lo: float, hi: float, per_s: float, limit_s: float,
                span: str = "the LTC recording") -> int:
    """Frames outside [lo, hi] (in units of ``per_s`` per second): error past ``limit_s``; returns how many."""
    out = np.maximum(lo - what, what - hi) / per_s
    if np.all(out > limit_s):
        raise SyncError(f"stream {name}: no frame within {span} (streams do not overlap; nearest "
                        f"{out.min():.2f} s outside)")
    if np.any(out > limit_s):
        raise SyncError(f"stream {name}: {int((out > limit_s).sum())} frames lie up to {out.max():.2f} s outside "
                        f"{span} (limit {limit_s} s)")
    return int((out > 0).sum())


def _hd_segment_for(vga: ChannelClock, hd: ChannelClock, k: int) -> int:
    """The HD audio segment sharing most samples with VGA audio segment ``k`` (the same stretch of ltc.wav)."""
    a = vga.audio[k]
    overlap = [min(a.sample_last, b.sample_last) - max(a.sample_first, b.sample_first) for b in hd.audio]
    return int(np.argmax(overlap))


def vga_to_univ_ms(vga: ChannelClock, hd: ChannelClock, vga_tick: np.ndarray) -> np.ndarray:
    """Universal time (ms) of VGA ticks: VGA fit to a sample of ltc.wav, then HD fit of the same stretch."""
    t = np.asarray(vga_tick, dtype=float)
    seg = vga._segment_by_tick(t)
    out = np.empty(t.shape)
    for k, a in enumerate(vga.audio):
        m = seg == k
        out[m] = hd_univ_ms(hd, hd.audio[_hd_segment_for(vga, hd, k)].fit.inverse(a.fit(t[m])))
    return out


def pair_models(vga: ChannelClock, hd: ChannelClock) -> list[dict]:
    """Per stretch of ltc.wav, the VGA clock on universal time: ``univ_ms = offset_ms + period_ms * vga_tick``."""
    out = []
    for k, a in enumerate(vga.audio):
        t0, t1 = float(a.tick_first), float(a.tick_last)
        u0, u1 = vga_to_univ_ms(vga, hd, np.array([t0, t1]))
        period = (u1 - u0) / (t1 - t0) if t1 > t0 else 1000.0 / float(vga.fps)
        out.append({"vga_tick_first": a.tick_first, "vga_tick_last": a.tick_last, "offset_ms": float(u0 - period * t0),
                    "period_ms": period, "drift_ppm": (period * float(vga.fps) / 1000.0 - 1.0) * 1e6})
    return out


def _overlap(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[0] <= b[1] and b[0] <= a[1]


def fit_ltc_pair(vga_frames: FrameStarts, hd_frames: FrameStarts, opts: ClockFitOptions
                 ) -> tuple[ChannelClock, ChannelClock]:
    """Fit both channels of ltc.wav. Both share one sample clock, so a restart either channel sees splits both,
    and label breaks at the same place in both channels are a splice of the recording, not two re-jams."""
    forced: list[tuple[float, float]] = []
    for _ in range(4):
        vga = fit_channel_clock(vga_frames, opts, restarts=forced)
        hd = fit_channel_clock(hd_frames, opts, restarts=forced)
        jumps = [[(e["sample_before"], e["sample"]) for e in c.events if e["kind"] == "jump"] for c in (vga, hd)]
        shared = [j for j in jumps[0] if any(_overlap(j, k) for k in jumps[1])]
        shared += [k for k in jumps[1] if any(_overlap(j, k) for j in jumps[0])]
        new = sorted(set(forced) | set(restarts_of(vga)) | set(restarts_of(hd)) | set(shared))
        if new == sorted(set(forced)):
            break
        forced = new
    return vga, hd


def block_splices(node: KinectNode, sample_rate: float, min_gap_ms: float = 8.0) -> list[tuple[float, float]]:
    """Where a Kinect's audio file lacks blocks: the device time jumps more than the samples between two blocks."""
    first = node.block_first_sample.astype(float)
    excess_ms = np.diff(node.block_device_time_100ns) * 1e-4 - np.diff(first) / sample_rate * 1e3
    return [(first[b + 1], first[b + 1]) for b in np.flatnonzero(excess_ms > min_gap_ms)]


def kinect_clock(node: KinectNode, frames: FrameStarts, hd: ChannelClock, opts: SyncOptions) -> KinectClock:
    """Fit device time -> universal time for one Kinect from the HD LTC its microphone recorded."""
    audio = fit_channel_clock(frames, opts.clock, restarts=block_splices(node, frames.sample_rate))
    main, found = hd.count_to_tick(audio.count_of_tick(audio.ticks), margin_frames=opts.clock.label_margin_frames)
    if not found.any():
        raise SyncError(f"{frames.source}: its HD timecode never occurs in the HD LTC recording "
                        "(streams do not overlap)")
    values, counts = np.unique(main[found] - audio.ticks[found], return_counts=True)
    offset = int(values[np.argmax(counts)])
    s0, s1 = audio.start_samples[0], audio.start_samples[-1]
    keep = (node.block_first_sample >= s0 - frames.sample_rate) & (node.block_first_sample <= s1 + frames.sample_rate)
    keep &= ~audio.in_gap(node.block_first_sample.astype(float))  # blocks where the audio may be spliced
    if keep.sum() < 4:
        raise SyncError(f"{frames.source}: fewer than 4 audio blocks lie within the decoded LTC "
                        "(audio_blocks do not overlap the audio)")
    x = node.block_device_time_100ns[keep].astype(float)
    y = hd_univ_ms(hd, audio.sample_to_tick(node.block_first_sample[keep].astype(float)) + offset)
    step_err = np.abs(np.diff(y) - np.diff(x) * 1e-4)
    breaks = np.concatenate([[0], np.flatnonzero((step_err > opts.device_break_ms) | (np.diff(x) <= 0)) + 1, [x.size]])
    fits, spans = [], []
    for i0, i1 in zip(breaks[:-1], breaks[1:]):
        if i1 - i0 < 4:
            continue
        fits.append(robust_line(x[i0:i1], y[i0:i1], sigma=opts.device_outlier_sigma,
                                floor=opts.device_outlier_floor_ms))
        spans.append((int(x[i0]), int(x[i1 - 1])))
    if not fits:
        raise SyncError(f"{frames.source}: audio block timestamps are inconsistent (no stretch of 4 agreeing blocks)")
    return KinectClock(audio=audio, tick_offset=offset, device=fits, spans=spans)


def build_sync(session: Session, vga_frames: FrameStarts, hd_frames: FrameStarts,
               kinect_frames: dict[str, FrameStarts | str], options: SyncOptions | None = None) -> SyncResult:
    """Fit every clock and put every frame of the session on universal time.

    Args:
        session: the loaded session (frame indices, references, Kinect timestamps).
        vga_frames, hd_frames: decoded LTC of the two channels of ltc.wav.
        kinect_frames: per Kinect node its decoded HD LTC, or a one-line reason why there is none.
        options: thresholds; ``strict_kinect`` turns a Kinect that cannot be synced into an error.
    Returns:
        SyncResult with the tables; Kinects that could not be synced are listed in ``flagged``.
    """
    opts = options or SyncOptions()
    vga, hd = fit_ltc_pair(vga_frames, hd_frames, opts.clock)
    lo = max(vga.start_samples[0], hd.start_samples[0])
    hi = min(vga.start_samples[-1], hd.start_samples[-1])
    if hi <= lo:
        raise SyncError(f"{vga.source} and {hd.source}: the two LTC channels never run at the same time "
                        "(streams do not overlap)")
    margin = opts.clock.label_margin_frames
    streams, summaries, notes = {}, [], []
    pairs = pair_models(vga, hd)
    for name, st in session.streams.items():
        clock = vga if st.clock == "vga" else hd
        ticks = stream_ticks(st, clock, margin)
        n_out = _check_span(name, ticks.astype(float), clock.ticks[0], clock.ticks[-1], float(clock.fps),
                    opts.max_extrapolation_s)
        if n_out:
            notes.append(f"{name}: {n_out} frames lie outside the decoded LTC; their times are extrapolated")
        if st.clock == "vga":
            univ = vga_to_univ_ms(vga, hd, ticks)
            w = np.array([p["vga_tick_last"] - p["vga_tick_first"] + 1 for p in pairs], float)
            drift = float(np.sum(w * [p["drift_ppm"] for p in pairs]) / w.sum())
        else:
            univ = hd_univ_ms(hd, ticks)
            drift = 0.0
        streams[name] = SyncTable(index=st.index.copy(), univ_time_ms=univ)
        summaries.append(StreamSummary(name=name, n_frames=int(st.index.size), first_ms=float(univ[0]),
                                       last_ms=float(univ[-1]), drift_ppm=drift,
                                       residual_rms_us=clock.residual_rms_us, n_outliers=clock.n_outliers))
    tables = SyncTables(streams=streams)
    kin: dict[str, KinectClock] = {}
    flagged: dict[str, str] = {}
    for name, node in session.kinects.items():
        got = kinect_frames.get(name, "no decoded audio")
        try:
            if isinstance(got, str):
                raise SyncError(f"{name}: {got}")
            kc = kinect_clock(node, got, hd, opts)
            for kind in ("color", "depth"):
                fr = getattr(node, kind)
                n_out = _check_span(f"{name}/{kind}", fr.device_time_100ns.astype(float), kc.spans[0][0],
                                    kc.spans[-1][1], 1e7, opts.max_extrapolation_s,
                                    "the audio blocks timed by its decoded LTC")
                if n_out:
                    notes.append(f"{name}/{kind}: {n_out} frames lie outside the timed audio blocks; their times "
                                 "are extrapolated")
                univ = kc.univ_ms(fr.device_time_100ns)
                if np.any(np.diff(univ) <= 0):
                    raise SyncError(f"{name}/{kind}: device timestamps do not increase with the frame index")
                (tables.kinect_color if kind == "color" else tables.kinect_depth)[name] = SyncTable(
                    index=fr.index.copy(), univ_time_ms=univ)
                slope = np.average([f.slope for f in kc.device], weights=[f.n_points for f in kc.device])
                rms = np.sqrt(np.mean(np.concatenate([f.residuals[f.inliers] for f in kc.device]) ** 2)) * 1e3
                summaries.append(StreamSummary(name=f"{name}/{kind}", n_frames=int(fr.index.size),
                                               first_ms=float(univ[0]), last_ms=float(univ[-1]),
                                               drift_ppm=float((slope / 1e-4 - 1.0) * 1e6), residual_rms_us=float(rms),
                                               n_outliers=sum(f.n_outliers for f in kc.device)))
            kin[name] = kc
        except (SyncError, ClockError) as exc:
            if opts.strict_kinect:
                raise
            tables.kinect_color.pop(name, None)
            tables.kinect_depth.pop(name, None)
            summaries = [s for s in summaries if not s.name.startswith(f"{name}/")]
            flagged[name] = str(exc).removeprefix(f"{name}: ")
            logger.debug("%s: not synced: %s", name, exc)
    notes = [n for n in notes if n.split("/")[0].split(":")[0] not in flagged]
    return SyncResult(seq=session.seq, tables=tables, vga=vga, hd=hd, kinect=kin, summaries=summaries,
                      flagged=flagged, notes=notes)
