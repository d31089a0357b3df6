"""LTC decoder: audio (file or array, any rate 8-192 kHz, every channel) -> frames with sub-sample times.

Pipeline per channel: blocks of ~20 s with overlap (NaN/inf samples interpolated over; below 16 kHz the
band-limited interpolation at twice the rate) -> ``edges.find_edges`` (sub-sample edge times, each stat block
read as a square wave or an impulse train, whichever fits; DC, AC coupling, spikes and level handled there) ->
``assemble.decode_edges``: ``bits.edge_stream`` / ``bits.find_frames`` (biphase decoding with speed tracking,
forward and reverse sync words, frames at the edges of the audio) -> label validation, rate detection and
continuity (``continuity``) -> frame times from the local bit clock (``bitclock``).

Example:
    >>> result = decode_file("take1.wav")            # doctest: +SKIP
    >>> ch = result[0]; ch.label_strings()[0], ch.start_samples[0]  # doctest: +SKIP
    ('10:00:00:00', 812.4173)
"""
from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import numpy.typing as npt
from scipy.signal import resample_poly

from timecode.decode.assemble import RateMismatchError, decode_edges, pole_to_tau
from timecode.audio_io import AudioReader, RawFormat, to_float32
from timecode.decode.droop import Droop
from timecode.decode.edge_store import EdgeStore, holds_sync_word
from timecode.decode.edges import block_droop, edge_params, find_edges
from timecode.errors import TimecodeError
from timecode.rates import FrameRate
from timecode.decode.result import ChannelDecode
from dome_calib.options import AtLeast, options
from dome_calib.schema import PosFinite

logger = logging.getLogger(__name__)

MIN_RATE, MAX_RATE = 8000, 192000


class DecodeError(TimecodeError, ValueError):
    """A decode request that cannot be met (bad channel, unsupported sample rate)."""


@options
class DecodeOptions:
    """Decoder settings; the defaults suit every supported sample rate."""

    rate: FrameRate | None = None  # None: detect from labels and frame period; else refused if the LTC is not
    smooth_sigma_samples: PosFinite | None = None  # Gaussian smoothing before timing (default ~0.1 half-bit)
    block_seconds: PosFinite = 20.0  # audio processed per step (memory ~ 30 bytes x samples x channels)
    ac_coupling: bool = True  # fit and undo an input high-pass (droop)
    threads: AtLeast(1) | None = None  # channels decoded in parallel (default: one per CPU core)


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
    parts = {c: EdgeStore() for c in chans}  # a block's edges are dropped where no LTC is near (memory bound)
    poles: dict[int, list[float]] = {c: [] for c in chans}
    nonfinite = dict.fromkeys(chans, 0)

    def one_channel(c: int, data: npt.NDArray, d0: int, core0: int, core1: int) -> None:
        x = to_float32(np.ascontiguousarray(data[:, c]))
        bad = ~np.isfinite(x)
        if bad.any():
            nonfinite[c] += int(bad[core0 - d0:core1 - d0].sum())
            x = fill_gaps(x, bad)
        x = upsample(x, up)
        if droops[c] is None:
            excerpt = x[max(0, (len(x) - 2 * fs * up) // 2):][: 2 * fs * up]
            droops[c] = block_droop(excerpt, params)
            if droops[c] is not None and droops[c].active:
                logger.info("channel %d: AC coupling near %.1f Hz detected and undone", c, droops[c].corner_hz)
        be = find_edges(x, params, droops[c])
        t = be.t / up + d0
        keep = (t >= core0 - 0.5) & (t < core1 - 0.5)
        parts[c].add((t[keep], be.rising[keep], be.amplitude[keep], be.impulse[keep]),
                     holds_sync_word(be.t, be.rising, fs * up))
        if be.impulse[keep].any():
            poles[c].append(be.pole ** (1.0 / up))

    workers = max(1, min(len(chans), opts.threads or os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=workers) as pool:  # numpy releases the GIL in the heavy loops
        for d0, core0, core1, data in _prefetch(blocks(block, margin)):
            list(pool.map(lambda c: one_channel(c, data, d0, core0, core1), chans))
            if progress is not None:
                progress(core1, n_samples)

    def finish(c: int) -> ChannelDecode:
        t, rising, amp, imp = parts[c].arrays()
        dr = droops[c]
        return dataclasses.replace(decode_edges(t, rising, amp, fs, impulse=imp, n_samples=n_samples, channel=c, rate=opts.rate,
                            ac_coupling_hz=dr.corner_hz if dr is not None and dr.active else 0.0,
                            impulse_tau_samples=pole_to_tau(poles[c]), n_nonfinite=nonfinite[c],
                            edge_margin_samples=(2 * params.sigma_samples + 2) / up), n_edges=parts[c].n_edges)

    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(finish, chans))


def fill_gaps(x: npt.NDArray[np.float32], bad: npt.NDArray[np.bool_]) -> npt.NDArray[np.float32]:
    """``x`` with its non-finite samples (``bad``) replaced by straight lines between the finite samples around
    them: a lone NaN costs nothing, a long run of them is a gap without transitions. All bad: zeros."""
    good = np.flatnonzero(~bad)
    y = x.copy()
    if good.size == 0:
        y[:] = 0.0
        return y
    where = np.flatnonzero(bad)
    y[where] = np.interp(where, good, x[good].astype(np.float64)).astype(np.float32)
    return y


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


__all__ = ["DecodeError", "DecodeOptions", "RateMismatchError", "decode_edges", "decode_file", "decode_samples"]
