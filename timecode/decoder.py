"""LTC decoder: audio (file or array, any rate 8-192 kHz, every channel) -> frames with sub-sample times.

Pipeline per channel: blocks of ~20 s with overlap -> ``edges.find_edges`` (sub-sample edge times, DC,
AC coupling, spikes and level handled there) -> ``bits.edge_stream`` / ``bits.find_frames`` (biphase
decoding with speed tracking, forward and reverse sync words) -> label validation, rate detection and
continuity (``continuity``) -> frame times from the local bit clock (``clockfit``).

Example:
    >>> result = decode_file("take1.wav")            # doctest: +SKIP
    >>> ch = result[0]; ch.label_strings()[0], ch.start_samples[0]  # doctest: +SKIP
    ('10:00:00:00', 812.4173)
"""
from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.signal import resample_poly

from timecode.audio_io import AudioReader, RawFormat, to_float32
from timecode.bits import edge_stream, find_frames
from timecode.clockfit import fit_frame_times
from timecode.continuity import continuity, detect_rate
from timecode.droop import Droop
from timecode.edges import block_droop, edge_params, find_edges
from timecode.errors import TimecodeError
from timecode.frame import bgf_bits, unpack_bits
from timecode.labels import labels_to_frames, labels_valid
from timecode.rates import FrameRate
from timecode.result import ChannelDecode

logger = logging.getLogger(__name__)

MIN_RATE, MAX_RATE = 8000, 192000


class DecodeError(TimecodeError, ValueError):
    """A decode request that cannot be met (bad channel, unsupported sample rate)."""


@dataclass(kw_only=True)
class DecodeOptions:
    """Decoder settings; the defaults suit every supported sample rate."""

    rate: FrameRate | None = None  # None: detect from labels and frame period
    smooth_sigma_samples: float | None = None  # Gaussian smoothing before timing (default ~0.1 half-bit)
    block_seconds: float = 20.0  # audio processed per step (memory ~ 30 bytes x samples x channels)
    ac_coupling: bool = True  # fit and undo an input high-pass (droop)
    threads: int | None = None  # channels decoded in parallel (default: one per CPU core)


class _ArrayReader:
    """In-memory samples with AudioReader's block interface."""

    def __init__(self, samples: npt.ArrayLike, sample_rate: int) -> None:
        a = np.asarray(samples)
        self.data = a[:, None] if a.ndim == 1 else a
        if self.data.ndim != 2 or self.data.shape[0] == 0:
            raise DecodeError(f"samples must be (S,) or (S, channels) with S > 0, got shape {a.shape}")
        self.n, self.channels, self.sample_rate = self.data.shape[0], self.data.shape[1], sample_rate

    def blocks(self, block: int, margin: int):
        for core0 in range(0, self.n, block):
            core1 = min(self.n, core0 + block)
            d0, d1 = max(0, core0 - margin), min(self.n, core1 + margin)
            yield d0, core0, core1, self.data[d0:d1]


def decode_samples(samples: npt.ArrayLike, sample_rate: int, *, options: DecodeOptions | None = None,
                   channels: Sequence[int] | None = None) -> list[ChannelDecode]:
    """Decode LTC from samples (S,) or (S, C), integer or float. Returns one ChannelDecode per channel."""
    reader = _ArrayReader(samples, sample_rate)
    return _decode(reader.blocks, reader.n, reader.channels, sample_rate, options or DecodeOptions(), channels, None)


def decode_file(path: str | os.PathLike[str], *, options: DecodeOptions | None = None,
                channels: Sequence[int] | None = None, raw: RawFormat | None = None,
                progress: Callable[[int, int], None] | None = None) -> list[ChannelDecode]:
    """Decode LTC from every (or the given 0-based) channel of an audio file.

    Args:
        path: WAV/FLAC/AIFF/... file, or a headerless file described by ``raw``.
        options: decoder settings.
        channels: 0-based channel indices (default: all).
        raw: sample format, rate and channel count of a headerless file.
        progress: called with (samples done, total samples) after each block.
    """
    with AudioReader(path, raw) as reader:
        info = reader.info
        return _decode(reader.blocks, info.frames, info.channels, info.sample_rate, options or DecodeOptions(),
                       channels, progress)


def _decode(blocks, n_samples: int, n_channels: int, fs: int, opts: DecodeOptions,
            channels: Sequence[int] | None, progress) -> list[ChannelDecode]:
    if not MIN_RATE <= fs <= MAX_RATE:
        raise DecodeError(f"sample rate {fs} Hz is outside the supported {MIN_RATE}-{MAX_RATE} Hz")
    chans = list(range(n_channels)) if channels is None else list(channels)
    for c in chans:
        if not 0 <= c < n_channels:
            raise DecodeError(f"channel {c} does not exist (channels count from 0; the audio has {n_channels})")
    up = upsample_factor(fs)
    params = edge_params(fs * up, None if opts.smooth_sigma_samples is None else opts.smooth_sigma_samples * up)
    stat = params.stat_block // up  # samples of the file per stat block
    block = max(int(opts.block_seconds * fs) // stat, 4) * stat
    margin = 8 * stat
    droops: dict[int, Droop | None] = {c: (None if opts.ac_coupling else Droop(corner_hz=0.0, sample_rate=fs * up))
                                       for c in chans}
    parts: dict[int, list[tuple[npt.NDArray, ...]]] = {c: [] for c in chans}

    def one_channel(c: int, data: npt.NDArray, d0: int, core0: int, core1: int) -> None:
        x = upsample(to_float32(np.ascontiguousarray(data[:, c])), up)
        if droops[c] is None:
            excerpt = x[max(0, (len(x) - 2 * fs * up) // 2):][: 2 * fs * up]
            droops[c] = block_droop(excerpt, params)
            if droops[c] is not None and droops[c].active:
                logger.info("channel %d: AC coupling near %.1f Hz detected and undone", c, droops[c].corner_hz)
        be = find_edges(x, params, droops[c])
        t = be.t / up + d0
        keep = (t >= core0 - 0.5) & (t < core1 - 0.5)
        parts[c].append((t[keep], be.rising[keep], be.amplitude[keep]))

    workers = max(1, min(len(chans), opts.threads or os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=workers) as pool:  # numpy releases the GIL in the heavy loops
        for d0, core0, core1, data in _prefetch(blocks(block, margin)):
            list(pool.map(lambda c: one_channel(c, data, d0, core0, core1), chans))
            if progress is not None:
                progress(core1, n_samples)

    def finish(c: int) -> ChannelDecode:
        t = np.concatenate([p[0] for p in parts[c]]) if parts[c] else np.zeros(0)
        rising = np.concatenate([p[1] for p in parts[c]]) if parts[c] else np.zeros(0, bool)
        amp = np.concatenate([p[2] for p in parts[c]]) if parts[c] else np.zeros(0, np.float32)
        dr = droops[c]
        return decode_edges(t, rising, amp, fs, channel=c, rate=opts.rate,
                            ac_coupling_hz=dr.corner_hz if dr is not None and dr.active else 0.0)

    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(finish, chans))


def upsample_factor(sample_rate: int) -> int:
    """2 below 16 kHz, else 1. At 8-12 kHz a half-bit is 1.7-3 samples: the edge finder then works on the
    band-limited interpolation at twice the rate, which shows each half-bit's level whatever the sampling
    phase (the samples of a 1.7-sample pulse can all sit near its edges)."""
    return 2 if sample_rate < 16000 else 1


def upsample(x: npt.NDArray[np.float32], up: int) -> npt.NDArray[np.float32]:
    """Band-limited interpolation by ``up`` (sample k of the result is at k / up input samples); ends held."""
    if up == 1:
        return x
    return resample_poly(x, up, 1, padtype="edge").astype(np.float32, copy=False)


def _prefetch(blocks: Iterator[tuple]) -> Iterator[tuple]:
    """Read the next block on a helper thread while the current one is decoded."""
    with ThreadPoolExecutor(max_workers=1) as reader:
        it = iter(blocks)
        nxt = reader.submit(next, it, None)
        while True:
            item = nxt.result()
            if item is None:
                return
            nxt = reader.submit(next, it, None)
            yield item


def decode_edges(t: npt.NDArray[np.float64], rising: npt.NDArray[np.bool_], amplitude: npt.NDArray[np.float32],
                 sample_rate: int, *, channel: int = 0, rate: FrameRate | None = None,
                 ac_coupling_hz: float = 0.0) -> ChannelDecode:
    """Frames from one channel's sorted edge times: bits, sync, labels, rate, continuity, clock fit."""
    empty = ChannelDecode(channel=channel, sample_rate=sample_rate, rate=rate, n_edges=len(t),
                          ac_coupling_hz=ac_coupling_hz)
    if len(t) > 1:
        # two edges closer than a tenth of the shortest half-bit cannot both be LTC (block seams)
        close = np.diff(t) < 0.1 * sample_rate / (2 * 2760.0)
        if close.any():
            drop = np.concatenate([[False], close]) | np.concatenate([close, [False]])
            t, rising, amplitude = t[~drop], rising[~drop], amplitude[~drop]
    es = edge_stream(t, rising, sample_rate)
    if es is None:
        return empty
    raw = find_frames(es)
    fields = unpack_bits(raw.bits)
    ok = fields.sync_ok & fields.bcd_ok
    n_found = len(ok)
    hmsf, bits = fields.hmsf[ok], fields.bits[ok]
    start_e, end_e, reverse = raw.start_edge[ok], raw.end_edge[ok], raw.reverse[ok]
    ub, parity = fields.user_bits[ok], fields.parity_ok[ok]
    if len(hmsf) == 0:
        empty.n_rejected = n_found
        return empty
    period = np.abs(es.t[end_e] - es.t[start_e])
    contiguous = np.concatenate([(end_e[:-1] == start_e[1:]) & (reverse[:-1] == reverse[1:]), [False]])
    if rate is None:
        rate = detect_rate(hmsf, bits[:, 10].astype(bool), period, contiguous, sample_rate, es.t[start_e])
    valid = labels_valid(hmsf, rate)
    hmsf, bits, start_e, end_e, reverse, ub, parity, period = (
        a[valid] for a in (hmsf, bits, start_e, end_e, reverse, ub, parity, period))
    counts = labels_to_frames(hmsf, rate)
    mid = (es.t[start_e] + es.t[end_e]) / 2
    keep, disc = continuity(counts, reverse, mid, period, rate.frames_per_day)
    hmsf, bits, start_e, end_e, reverse, ub, parity, counts, disc = (
        a[keep] for a in (hmsf, bits, start_e, end_e, reverse, ub, parity, counts, disc))
    n_rejected = n_found - len(counts)
    if len(counts) == 0:
        empty.rate, empty.n_rejected = rate, n_rejected
        return empty
    # clock-fit segments: never across a discontinuity (runs are already apart in position)
    seg = np.cumsum(disc) - 1
    p_lo = np.minimum(es.pos[start_e], es.pos[end_e])
    p_hi = np.maximum(es.pos[start_e], es.pos[end_e])
    nseg = int(seg[-1]) + 1
    seg_lo = np.full(nseg, np.iinfo(np.int64).max)
    seg_hi = np.full(nseg, np.iinfo(np.int64).min)
    np.minimum.at(seg_lo, seg, p_lo)
    np.maximum.at(seg_hi, seg, p_hi)
    start, end, rms = fit_frame_times(es.t, es.pos, start_e, end_e, seg_lo[seg], seg_hi[seg], es.half_bit_samples)
    i0, i1, i2 = bgf_bits(rate.is_25_layout)
    amp_e = amplitude[es.index[start_e]].astype(np.float64)
    return ChannelDecode(
        channel=channel, sample_rate=sample_rate, rate=rate, labels=hmsf, frame_numbers=counts, user_bits=ub,
        drop_frame=bits[:, 10].astype(bool), color_frame=bits[:, 11].astype(bool),
        bgf=bits[:, [i0, i1, i2]].astype(bool), parity_ok=parity, reverse=reverse,
        start_samples=start, end_samples=end,
        level_dbfs=20 * np.log10(np.maximum(amp_e, 1e-12)),
        jitter_us=rms / sample_rate * 1e6, discontinuity=disc,
        n_edges=len(t), n_rejected=n_rejected, ac_coupling_hz=ac_coupling_hz,
    )

