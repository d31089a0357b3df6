"""Clock models from decoded LTC frame starts: a continuous tick count per clock and piecewise linear fits.

Vocabulary:

- *count*: the frame count of an LTC label since midnight (the codec's label -> frame-count conversion, so
  drop-frame labels are already contiguous counts). It wraps at ``frames_per_day``.
- *tick*: a continuous count of the clock's frames over the whole session, 0 at the first locked LTC frame of
  the channel. A timecode jump (labels discontinuous while the audio runs on) and the midnight wrap do not
  interrupt ticks: the clock kept running, only its labels changed.
- *audio segment*: a stretch of the recording whose sample clock is continuous. A recording restart (audio
  cut or paused while the generator ran on) starts a new audio segment; ticks across it are bridged by labels.
- *label segment*: a stretch of ticks whose labels are contiguous; maps labels to ticks.

How breaks are told apart: between two decoded frames the audio ran on continuously when their distance is a
whole number of frame periods (within ``gap_tolerance_frames`` plus the drift allowance); if the labels advanced by
that number too, nothing happened (the decoder just missed frames); if not, the timecode jumped. When the distance
is not a whole number of periods, audio was lost: a restart, bridged by the labels. A splice that happens to remove
a whole number of frames looks like a jump on one channel; :func:`timecode.sync.tables.fit_ltc_pair` recognises it
because both channels of ltc.wav break at the same place, and Kinect audio splices show in the block timestamps.

Per audio segment the frame starts are fitted robustly as ``start_sample = a + b * (tick - tick_ref)``
(offset and drift against the audio sample clock); outliers are rejected and counted.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Annotated

import numpy as np

from timecode.errors import TimecodeError
from dome_calib.options import AtLeast, Field, options
from dome_calib.schema import NonNegFinite, PosFinite

logger = logging.getLogger(__name__)


class ClockError(TimecodeError):
    """A clock cannot be modelled (no LTC, never locks, cannot be bridged)."""


@dataclass(kw_only=True)
class FrameStarts:
    """Decoded LTC frames of one channel: what the decoder reports, reduced to what clock fitting needs."""

    count: np.ndarray  # (N,) int64 label frame count since midnight
    start_samples: np.ndarray  # (N,) float64 sample position of each frame's first edge (sub-sample)
    sample_rate: float  # samples per second of the audio clock
    fps: Fraction  # exact frame rate of the LTC
    frames_per_day: int  # counts wrap here (midnight)
    source: str  # where the frames come from, for messages: "ltc.wav channel 1 (HD)"


@options
class ClockFitOptions:
    """Thresholds of the clock fit (defaults suit 8-192 kHz audio and +-200 ppm clocks)."""

    min_run_frames: AtLeast(1) = 4  # shorter runs of consistent labels are rejected as misreads
    min_lock_frames: AtLeast(1) = 12  # a channel needs one consistent run this long, else "never locks"
    gap_tolerance_frames: Annotated[float, Field(ge=0, lt=0.5)] = 0.005  # |gap / period - n| below this + n * max_drift: audio ran on continuously
    max_drift_ppm: NonNegFinite = 300.0  # clock error the continuity test allows per frame of gap
    outlier_sigma: PosFinite = 6.0  # residuals beyond sigma * robust std (MAD) are rejected ...
    outlier_floor_us: NonNegFinite = 20.0  # ... but never below this many microseconds
    label_margin_frames: AtLeast(0) = 250  # a label may be extrapolated this far beyond a label segment's decoded span


@dataclass(kw_only=True)
class LineFit:
    """``y = y_ref + slope * (x - x_ref)`` fitted robustly, with inlier residual statistics in y units."""

    x_ref: float
    y_ref: float
    slope: float
    n_points: int
    n_outliers: int
    residual_rms: float
    residual_max: float
    residuals: np.ndarray = field(repr=False)  # (N,) y - fit(x), all points (outliers included)
    inliers: np.ndarray = field(repr=False)  # (N,) bool

    def __call__(self, x: np.ndarray | float) -> np.ndarray:
        return self.y_ref + self.slope * (np.asarray(x, dtype=float) - self.x_ref)

    def inverse(self, y: np.ndarray | float) -> np.ndarray:
        return self.x_ref + (np.asarray(y, dtype=float) - self.y_ref) / self.slope


def robust_line(x: np.ndarray, y: np.ndarray, *, sigma: float, floor: float, max_iter: int = 20) -> LineFit:
    """Least-squares line with iterative rejection of points beyond ``max(sigma * 1.4826 * MAD, floor)``."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.size < 2:
        raise ClockError(f"a line needs 2 points, got {x.size}")
    x_ref = float(np.mean(x))
    inl = np.ones(x.size, bool)
    for _ in range(max_iter):
        xi, yi = x[inl] - x_ref, y[inl]
        if xi.size < 2 or np.ptp(xi) == 0:
            raise ClockError("too few distinct points left after outlier rejection")
        # The least-squares line in closed form (means and sums: the same bits on every CPU), not np.linalg.lstsq
        # (LAPACK: another CPU's kernels gave a Kinect clock's slope 3.7e-13 apart, docs/benchmarks.md).
        x_mean, y_mean = float(np.mean(xi)), float(np.mean(yi))
        dx = xi - x_mean
        slope = float(np.sum(dx * (yi - y_mean)) / np.sum(dx * dx))
        y_ref = y_mean - slope * x_mean  # the line at x_ref
        resid = y - (y_ref + slope * (x - x_ref))
        med = np.median(resid[inl])
        thr = max(sigma * 1.4826 * float(np.median(np.abs(resid[inl] - med))), floor)
        new = np.abs(resid) <= thr
        if new.sum() < 2 or np.array_equal(new, inl):
            break
        inl = new
    r_in = resid[inl]
    return LineFit(x_ref=x_ref, y_ref=float(y_ref), slope=float(slope), n_points=int(x.size),
                   n_outliers=int((~inl).sum()), residual_rms=float(np.sqrt(np.mean(r_in**2))),
                   residual_max=float(np.max(np.abs(r_in))), residuals=resid, inliers=inl)


@dataclass(kw_only=True)
class LabelSegment:
    """Ticks ``tick_first..tick_last`` carry contiguous labels starting at ``count_first`` (mod frames_per_day)."""

    count_first: int
    tick_first: int
    tick_last: int


@dataclass(kw_only=True)
class AudioSegment:
    """A continuous stretch of the recording: ticks and samples it spans and its fit ``sample = f(tick)``."""

    tick_first: int
    tick_last: int
    sample_first: float
    sample_last: float
    fit: LineFit  # x = tick, y = start sample

    @property
    def samples_per_tick(self) -> float:
        return self.fit.slope


@dataclass(kw_only=True)
class ChannelClock:
    """The clock of one LTC channel: ticks <-> labels and ticks <-> audio samples, piecewise."""

    source: str
    fps: Fraction
    sample_rate: float
    frames_per_day: int
    audio: list[AudioSegment]
    labels: list[LabelSegment]
    n_decoded: int  # frames the decoder reported
    n_misread: int  # frames dropped because their labels did not fit their neighbours
    events: list[dict]  # jumps, wraps, restarts: {"kind", "tick", "sample", ...}
    ticks: np.ndarray = field(repr=False)  # (K,) ticks of the kept frames
    start_samples: np.ndarray = field(repr=False)  # (K,)

    @property
    def n_outliers(self) -> int:
        return sum(s.fit.n_outliers for s in self.audio)

    @property
    def drift_ppm(self) -> float:
        """Clock rate against the audio sample clock: (measured samples per frame / nominal - 1) * 1e6."""
        nominal = self.sample_rate / float(self.fps)
        w = np.array([s.tick_last - s.tick_first + 1 for s in self.audio], float)
        spt = np.array([s.samples_per_tick for s in self.audio])
        return float((np.sum(w * spt) / w.sum() / nominal - 1.0) * 1e6)

    @property
    def residual_rms_us(self) -> float:
        """Inlier RMS residual of the frame-start fits, microseconds."""
        num = sum(s.fit.residual_rms**2 * (s.fit.n_points - s.fit.n_outliers) for s in self.audio)
        den = sum(s.fit.n_points - s.fit.n_outliers for s in self.audio)
        return float(np.sqrt(num / den) / self.sample_rate * 1e6)

    def _segment_by_tick(self, tick: np.ndarray) -> np.ndarray:
        bounds = [(a.tick_last + b.tick_first) / 2 for a, b in zip(self.audio[:-1], self.audio[1:])]
        return np.searchsorted(np.asarray(bounds, float), tick)

    def _segment_by_sample(self, sample: np.ndarray) -> np.ndarray:
        bounds = [(a.sample_last + b.sample_first) / 2 for a, b in zip(self.audio[:-1], self.audio[1:])]
        return np.searchsorted(np.asarray(bounds, float), sample)

    def in_gap(self, sample: np.ndarray | float) -> np.ndarray:
        """True for sample positions between two audio segments where the splice may lie (neither side's fit is
        known to hold there: after the last decoded frame's end, before the next segment's first frame)."""
        x = np.asarray(sample, dtype=float)
        out = np.zeros(x.shape, bool)
        for a, b in zip(self.audio[:-1], self.audio[1:]):
            out |= (x > a.sample_last + a.samples_per_tick) & (x < b.sample_first)
        return out

    def tick_to_sample(self, tick: np.ndarray | float) -> np.ndarray:
        """Sample position (float) of the start of tick(s), from the nearest audio segment (vectorised)."""
        t = np.asarray(tick, dtype=float)
        seg = self._segment_by_tick(t)
        out = np.empty(t.shape)
        for k, s in enumerate(self.audio):
            m = seg == k
            out[m] = s.fit(t[m])
        return out

    def sample_to_tick(self, sample: np.ndarray | float) -> np.ndarray:
        """Fractional tick at sample position(s), from the audio segment holding them (or the nearest)."""
        x = np.asarray(sample, dtype=float)
        seg = self._segment_by_sample(x)
        out = np.empty(x.shape)
        for k, s in enumerate(self.audio):
            m = seg == k
            out[m] = s.fit.inverse(x[m])
        return out

    def count_to_tick(self, count: np.ndarray | int, *, margin_frames: int = 250) -> tuple[np.ndarray, np.ndarray]:
        """Ticks of label counts. Returns ``(ticks int64, found bool)``; a count is found when exactly one label
        segment holds it (within ``margin_frames`` of its decoded span; ties go to the segment holding it
        strictly). Counts that repeat after a backward jump and are held by two segments are not found."""
        c = np.asarray(count, dtype=np.int64).reshape(-1)
        fpd = self.frames_per_day
        ticks = np.zeros(c.shape, np.int64)
        n_strict = np.zeros(c.shape, int)
        n_loose = np.zeros(c.shape, int)
        loose_tick = np.zeros(c.shape, np.int64)
        for seg in self.labels:
            d = (c - seg.count_first + fpd // 2) % fpd - fpd // 2
            t = seg.tick_first + d
            strict = (t >= seg.tick_first) & (t <= seg.tick_last)
            loose = (t >= seg.tick_first - margin_frames) & (t <= seg.tick_last + margin_frames) & ~strict
            ticks = np.where(strict, t, ticks)
            loose_tick = np.where(loose, t, loose_tick)
            n_strict += strict
            n_loose += loose
        found = (n_strict == 1) | ((n_strict == 0) & (n_loose == 1))
        ticks = np.where(n_strict == 1, ticks, loose_tick)
        shape = np.shape(count)
        return ticks.reshape(shape), found.reshape(shape)

    def count_of_tick(self, tick: np.ndarray | int) -> np.ndarray:
        """Label count (mod frames_per_day) carried by tick(s), from the label segment holding them (or nearest)."""
        t = np.asarray(tick, dtype=np.int64)
        firsts = np.array([s.tick_first for s in self.labels])
        k = np.clip(np.searchsorted(firsts, t, side="right") - 1, 0, len(self.labels) - 1)
        c0 = np.array([s.count_first for s in self.labels])[k]
        return (c0 + t - firsts[k]) % self.frames_per_day


def _continuous(gap_frames: np.ndarray | float, opts: ClockFitOptions) -> tuple[np.ndarray, np.ndarray]:
    """(whole frames, True where the audio between two frame starts is continuous: a whole number of frames)."""
    n = np.round(gap_frames)
    tol = opts.gap_tolerance_frames + np.abs(n) * opts.max_drift_ppm * 1e-6
    return n, (n >= 1) & (np.abs(gap_frames - n) < tol)


def _runs(gap_frames: np.ndarray, dcount: np.ndarray, opts: ClockFitOptions) -> list[tuple[int, int]]:
    """Maximal runs [i, j) of frames whose consecutive gaps agree with their label steps."""
    n_steps, cont = _continuous(gap_frames, opts)
    ok = cont & (dcount == n_steps)
    breaks = np.flatnonzero(~ok) + 1
    edges = np.concatenate([[0], breaks, [gap_frames.size + 1]])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def fit_channel_clock(frames: FrameStarts, options: ClockFitOptions | None = None,
                      *, restarts: list[tuple[float, float]] | None = None) -> ChannelClock:
    """Turn decoded frame starts into a :class:`ChannelClock` (ticks, label segments, audio-segment fits).

    ``restarts`` forces audio-segment breaks inside these ``(sample_before, sample_after)`` intervals (restarts the
    other channel of the same file saw, see :func:`restarts_of`).
    Raises :class:`ClockError` when the channel has no frames or never locks.
    """
    opts = options or ClockFitOptions()
    c = np.asarray(frames.count, dtype=np.int64)
    s = np.asarray(frames.start_samples, dtype=float)
    if c.size == 0:
        raise ClockError(f"{frames.source}: no LTC frames decoded (is there timecode on this channel?)")
    order = np.argsort(s, kind="stable")
    c, s = c[order], s[order]
    fpd = frames.frames_per_day
    period0 = frames.sample_rate / float(frames.fps)
    runs = _runs(np.diff(s) / period0, np.diff(c) % fpd, opts)
    kept = [(a, b) for a, b in runs if b - a >= opts.min_run_frames]
    longest = max(b - a for a, b in runs)
    if not kept or longest < opts.min_lock_frames:
        raise ClockError(f"{frames.source}: LTC never locks ({c.size} frames decoded, longest consistent run "
                         f"{longest} frames, need {opts.min_lock_frames})")
    forced = sorted(restarts or [])
    ticks_parts, idx_parts, events = [], [], []
    audio_breaks: list[int] = [0]  # positions in the kept-frame list where a new audio segment starts
    labels: list[LabelSegment] = []
    n_kept = 0
    tick = 0
    prev: tuple[int, int] | None = None
    for a, b in kept:
        rel = np.concatenate([[0], np.cumsum(np.diff(c[a:b]) % fpd)])
        if prev is None:
            labels.append(LabelSegment(count_first=int(c[a]), tick_first=0, tick_last=0))
        else:
            pa, pb = prev
            span = (s[pb - 1] - s[pa]) / max(1, int(ticks_parts[-1][-1] - ticks_parts[-1][0]))
            period = span if pb - pa >= 2 else period0
            n_f, cont = _continuous((s[a] - s[pb - 1]) / period, opts)
            n = int(n_f)
            dc = int((c[a] - c[pb - 1]) % fpd)
            forced_here = any(f0 < s[a] and s[pb - 1] < f1 for f0, f1 in forced)
            continuous = bool(cont) and not forced_here
            if continuous and dc == n:
                step = n  # misread frames in between were dropped; same label and audio segment
            elif continuous:
                step = n
                events.append({"kind": "jump", "tick": tick + step, "sample": float(s[a]),
                               "sample_before": float(s[pb - 1]),
                               "from_count": int(c[pb - 1]), "to_count": int(c[a])})
                labels.append(LabelSegment(count_first=int(c[a]), tick_first=tick + step, tick_last=tick + step))
            else:
                step = dc if dc > 0 else max(1, n)
                # audio was lost, so labels must advance at least as far as the audio that is there
                doubtful = dc < (s[a] - s[pb - 1]) / period - 1
                events.append({"kind": "restart", "tick": tick + step, "sample": float(s[a]),
                               "sample_before": float(s[pb - 1]), "gap_samples": float(s[a] - s[pb - 1]),
                               "label_gap_frames": dc, "doubtful": bool(doubtful)})
                if doubtful:
                    logger.warning("%s: restart at sample %.0f: the labels jump too (by %d frames over %.1f frames "
                                   "of audio); frames after it are timed by those labels", frames.source, s[a], dc,
                                   (s[a] - s[pb - 1]) / period)
                audio_breaks.append(n_kept)
                if dc == 0:
                    labels.append(LabelSegment(count_first=int(c[a]), tick_first=tick + step, tick_last=tick + step))
            tick += step
        t = tick + rel
        labels[-1].tick_last = int(t[-1])
        ticks_parts.append(t)
        idx_parts.append(np.arange(a, b))
        tick = int(t[-1])
        n_kept += b - a
        prev = (a, b)
    ticks = np.concatenate(ticks_parts).astype(np.int64)
    idx = np.concatenate(idx_parts)
    samples = s[idx]
    audio_breaks.append(ticks.size)
    floor = opts.outlier_floor_us * 1e-6 * frames.sample_rate
    segments = []
    for i0, i1 in zip(audio_breaks[:-1], audio_breaks[1:]):
        tk, sm = ticks[i0:i1], samples[i0:i1]
        fit = robust_line(tk, sm, sigma=opts.outlier_sigma, floor=floor)
        segments.append(AudioSegment(tick_first=int(tk[0]), tick_last=int(tk[-1]), sample_first=float(sm[0]),
                                     sample_last=float(sm[-1]), fit=fit))
    n_misread = int(c.size - ticks.size)
    for seg in labels:
        if seg.count_first + seg.tick_last - seg.tick_first >= fpd:
            wrap_tick = seg.tick_first + fpd - seg.count_first
            events.append({"kind": "midnight", "tick": int(wrap_tick),
                           "sample": float(np.interp(wrap_tick, ticks, samples))})
    for e in events:
        logger.debug("%s: %s at sample %.1f", frames.source, e["kind"], e["sample"])
    return ChannelClock(source=frames.source, fps=frames.fps, sample_rate=frames.sample_rate, frames_per_day=fpd,
                        audio=segments, labels=labels, n_decoded=int(c.size), n_misread=n_misread, events=events,
                        ticks=ticks, start_samples=samples)


def restarts_of(clock: ChannelClock) -> list[tuple[float, float]]:
    """Sample intervals in which this channel saw the recording restart (to force the same breaks elsewhere)."""
    return [(e["sample_before"], e["sample"]) for e in clock.events if e["kind"] == "restart"]
