"""LTC audio encoder with every edge at an exact sub-sample time: the ground truth for tests and synthesis.

Each biphase-mark transition is a Gaussian-CDF (erf) step centred on its exact time, evaluated at the
sample times, so the 50 % crossing of every edge is known exactly. The edge width is the larger of the
requested 10-90 % rise time (SMPTE 12M: 40 us +- 10 us) and the width that attenuates the edge by
``nyquist_atten_db`` at the Nyquist frequency (what a recorder's anti-alias filter does at low sample
rates; without it a 40 us edge sampled at 16 kHz would be aliased and carry no sub-sample timing).

Times: ``frame_start_samples[j]`` is the exact time, in samples (0.0 = the first sample), of the edge
that opens bit 0 of frame j (SMPTE's frame start). In reverse play frames arrive last-first and the
edge that opens bit 0 is the frame's last edge in time; ``frame_end_samples`` is the edge closing bit 79.

Example:
    >>> from fractions import Fraction
    >>> enc = encode_ltc("01:00:00:00", 25, fps=Fraction(25), sample_rate=48000)
    >>> float(enc.frame_start_samples[1] - enc.frame_start_samples[0])
    1920.0
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Annotated, Literal

import numpy as np
import numpy.typing as npt
from scipy.special import log_ndtr, ndtr

from timecode.errors import TimecodeError
from timecode.frame import N_BITS, pack_bits
from timecode.labels import Timecode, frames_to_labels, label_problem, label_to_frames, labels_valid
from timecode.rates import FrameRate, rate_from
from dome_calib.options import AtLeast, Field, options
from dome_calib.schema import Finite, NonNegFinite, PosFinite

_RISE_10_90_SIGMAS = 2.0 * 1.2815515655446004  # 10-90 % rise of a Gaussian CDF in standard deviations


class EncoderError(TimecodeError, ValueError):
    """Impossible encoder request (bad label, rate, sample rate or option)."""


@options
class EncoderOptions:
    """How the LTC audio is shaped. Defaults: a clean SMPTE-conforming signal at -6 dBFS peak."""

    rise_time_us: PosFinite = 40.0  # 10-90 % rise time of each edge (SMPTE 12M: 40 +- 10 us)
    nyquist_atten_db: NonNegFinite = 30.0  # edges are widened until attenuated this much at fs/2 (0 = never)
    level_dbfs: Annotated[float, Field(le=0)] = -6.0  # peak level of the square wave, dB re full scale (1.0)
    polarity: Literal[1, -1] = 1  # +1: every frame starts with a rising edge; -1: falling
    start_offset_samples: NonNegFinite | None = None  # time of the first edge, float samples (default: half a frame)
    drift_ppm: Annotated[float, Field(gt=-1e6, lt=1e6)] = 0.0  # generator clock error: +100 = runs 100 ppm fast (frames 100 ppm shorter)
    time_warp: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]] | None = None  # nominal s -> actual s
    reverse: bool = False  # tape played backwards: frames last-first, each frame's bits 79..0
    tail_samples: AtLeast(0) | None = None  # samples after the last edge (default: one frame)
    color_frame: bool = False
    bgf: tuple[bool, bool, bool] = (False, False, False)  # binary group flags BGF0, BGF1, BGF2
    # what a field recorder or wireless receiver does to it (defaults: nothing)
    highpass_tau_samples: NonNegFinite = 0.0  # one-pole high-pass of this time constant (1-4: every edge an impulse)
    rectify: bool = False  # output |signal| (one-sign impulses; polarity carries nothing)
    noise_snr_db: Finite | None = None  # white noise this far below the peak^2 of the signal (None: no noise)
    noise_seed: AtLeast(0) = 0


@dataclass(kw_only=True)
class EncodedLTC:
    """Encoded audio plus its exact ground truth."""

    samples: npt.NDArray[np.float64]  # (S,) mono, full scale = 1.0
    sample_rate: int
    rate: FrameRate
    labels: npt.NDArray[np.int64]  # (N, 4) hours, minutes, seconds, frames in encoding order
    user_bits: npt.NDArray[np.uint32]  # (N,)
    bits: npt.NDArray[np.uint8]  # (N, 80) wire bits of each frame
    frame_start_samples: npt.NDArray[np.float64]  # (N,) exact time of the edge opening bit 0
    frame_end_samples: npt.NDArray[np.float64]  # (N,) exact time of the edge closing bit 79
    edge_samples: npt.NDArray[np.float64]  # (E,) every edge, in time order
    edge_sigma_samples: float  # standard deviation of the Gaussian edge, samples
    reverse: bool = False

    def label(self, j: int) -> Timecode:
        h, m, s, f = (int(v) for v in self.labels[j])
        return Timecode(h, m, s, f, self.rate.drop_frame)


def label_range(start: Timecode | str, n_frames: int, rate: FrameRate) -> npt.NDArray[np.int64]:
    """(n, 4) consecutive labels from ``start`` at ``rate`` (drop-frame skips and midnight wrap applied)."""
    return frames_to_labels(label_to_frames(start, rate) + np.arange(n_frames), rate)


def encode_ltc(
    start: Timecode | str,
    n_frames: int,
    *,
    fps: Fraction | FrameRate | str,
    drop_frame: bool = False,
    sample_rate: int,
    user_bits: int | npt.ArrayLike = 0,
    options: EncoderOptions | None = None,
) -> EncodedLTC:
    """Encode ``n_frames`` consecutive frames from label ``start`` at ``fps`` (exact Fraction) as audio.

    Args:
        start: first label, e.g. ``"10:00:00;00"``.
        n_frames: number of frames.
        fps: exact rate, e.g. ``Fraction(30000, 1001)``; or a FrameRate / rate name.
        drop_frame: drop-frame labels (29.97 only).
        sample_rate: audio samples per second (any integer rate).
        user_bits: 32-bit user bits, one value for all frames or one per frame.
        options: signal shape, level, polarity, drift, offset, reverse play.

    Returns:
        EncodedLTC with ``.samples`` and the exact ``.frame_start_samples``.
    """
    rate = rate_from(fps, drop_frame)
    if n_frames < 1:
        raise EncoderError(f"n_frames must be >= 1, got {n_frames}")
    return encode_ltc_labels(label_range(start, n_frames, rate), fps=rate, sample_rate=sample_rate,
                             user_bits=user_bits, options=options)


def encode_ltc_labels(
    labels: Sequence[Timecode | str] | npt.ArrayLike,
    *,
    fps: Fraction | FrameRate | str,
    drop_frame: bool = False,
    sample_rate: int,
    user_bits: int | npt.ArrayLike = 0,
    options: EncoderOptions | None = None,
) -> EncodedLTC:
    """Encode one frame per label, in the given order, on one continuous bit clock.

    Any sequence is allowed, so timecode jumps (a generator re-jammed, a spliced session) are encoded by
    listing the labels, e.g. ``np.concatenate([label_range(a, 100, r), label_range(b, 100, r)])``.
    """
    opts = options or EncoderOptions()
    rate = rate_from(fps, drop_frame)
    hmsf = _labels_array(labels, rate)
    n = len(hmsf)
    if not 1000 <= sample_rate <= 1_000_000:
        raise EncoderError(f"sample_rate must be 1 kHz - 1 MHz, got {sample_rate}")
    ub = np.broadcast_to(np.asarray(user_bits, dtype=np.int64), (n,)).astype(np.uint32)
    bits = pack_bits(hmsf, is_25_layout=rate.is_25_layout, user_bits=ub, drop_frame=rate.drop_frame,
                     color_frame=opts.color_frame, bgf=opts.bgf)

    # half-bit positions of the edges: every bit opens with an edge, a 1 adds one at mid-bit,
    # and one closing edge ends the last frame
    stream = bits.ravel()
    u = np.sort(np.concatenate([2 * np.arange(stream.size), 2 * np.flatnonzero(stream) + 1, [2 * stream.size]]))
    total_u = 2 * stream.size
    if opts.reverse:
        u = total_u - u[::-1]
    half_bit_s = 1.0 / (2 * N_BITS * float(rate.fps))
    offset = (round(rate.samples_per_frame(sample_rate) / 2) if opts.start_offset_samples is None
              else float(opts.start_offset_samples))
    edges = offset + _warp(u * half_bit_s, opts) * sample_rate

    frame_u = 2 * N_BITS * np.arange(n)
    if opts.reverse:
        start_u, end_u = total_u - frame_u, total_u - frame_u - 2 * N_BITS
    else:
        start_u, end_u = frame_u, frame_u + 2 * N_BITS
    to_samples = lambda uu: offset + _warp(uu * half_bit_s, opts) * sample_rate  # noqa: E731

    sigma = _edge_sigma_samples(opts, sample_rate)
    tail = int(opts.tail_samples if opts.tail_samples is not None else math.ceil(rate.samples_per_frame(sample_rate)))
    n_samples = int(math.ceil(edges[-1] + 6 * sigma)) + 1 + tail
    if edges[0] - 6 * sigma < 0:
        raise EncoderError(f"start_offset_samples {offset} leaves no room for the first edge "
                           f"(needs >= {6 * sigma:.2f})")
    amp = 10.0 ** (opts.level_dbfs / 20.0) * opts.polarity
    samples = recorded(edges, n_samples, sigma, amp, opts)
    return EncodedLTC(
        samples=samples, sample_rate=sample_rate, rate=rate, labels=hmsf, user_bits=ub, bits=bits,
        frame_start_samples=to_samples(start_u), frame_end_samples=to_samples(end_u),
        edge_samples=edges, edge_sigma_samples=sigma, reverse=opts.reverse,
    )


def synthesize_edges(edges: npt.NDArray[np.float64], n_samples: int, sigma: float, amp: float,
                     chunk_edges: int = 1 << 17) -> npt.NDArray[np.float64]:
    """A square wave of peak ``amp`` flipping at each of the sorted ``edges`` (float samples), with Gaussian
    edges of standard deviation ``sigma`` samples. Level before the first edge is ``-amp``; after it ``+amp``."""
    edges = np.asarray(edges, dtype=np.float64)
    if np.any(np.diff(edges) <= 0):
        raise EncoderError("edge times must be strictly increasing")
    # hard square wave: level changes at the first sample at or after each edge
    first = np.clip(np.ceil(edges).astype(np.int64), 0, n_samples)
    counts = np.diff(np.concatenate([[0], first, [n_samples]]))
    levels = amp * np.where(np.arange(len(edges) + 1) % 2 == 0, -1.0, 1.0)
    out = np.repeat(levels, counts)
    # replace the hard step by the Gaussian step around each edge (corrections add linearly)
    half = int(math.ceil(7 * sigma)) + 1
    offs = np.arange(-half, half + 1)
    step = np.where(np.arange(len(edges)) % 2 == 0, 2.0 * amp, -2.0 * amp)
    for c0 in range(0, len(edges), chunk_edges):
        e = edges[c0:c0 + chunk_edges]
        idx = np.floor(e).astype(np.int64)[:, None] + offs
        x = idx - e[:, None]
        corr = step[c0:c0 + chunk_edges, None] * (ndtr(x / sigma) - (x >= 0))
        ok = (idx >= 0) & (idx < n_samples)
        lo = int(idx[ok].min())
        acc = np.bincount((idx[ok] - lo), weights=corr[ok])
        out[lo:lo + len(acc)] += acc
    return out


def recorded(edges: npt.NDArray[np.float64], n_samples: int, sigma: float, amp: float,
             opts: EncoderOptions) -> npt.NDArray[np.float64]:
    """The square wave of ``synthesize_edges`` as a recorder delivers it: high-passed (then its impulses peak
    at ``|amp|``), rectified, with noise, as ``opts`` asks."""
    if opts.highpass_tau_samples > 0:
        x = synthesize_highpassed_edges(edges, n_samples, sigma, 1.0, opts.highpass_tau_samples)
        x *= abs(amp) / float(np.max(np.abs(x)))
        x = x if amp > 0 else -x
    else:
        x = synthesize_edges(edges, n_samples, sigma, amp)
    if opts.rectify:
        x = np.abs(x)
    if opts.noise_snr_db is not None:
        x = x + np.random.default_rng(opts.noise_seed).normal(0.0, abs(amp) / 10 ** (opts.noise_snr_db / 20), x.size)
    return x


def synthesize_highpassed_edges(edges: npt.NDArray[np.float64], n_samples: int, sigma: float, amp: float,
                                tau: float, chunk_edges: int = 1 << 16) -> npt.NDArray[np.float64]:
    """The Gaussian-edged square wave of ``synthesize_edges`` through an analog one-pole high-pass of time
    constant ``tau`` samples (what a differentiating recorder input does), sampled exactly: each edge of
    height 2 amp at t_k becomes 2 amp g(n - t_k), g(x) = exp(-x / tau + sigma^2 / (2 tau^2)) Phi(x / sigma -
    sigma / tau) (the high-pass step response exp(-x / tau) convolved with the Gaussian edge). The level is 0
    before the first edge (the high-pass has removed the DC)."""
    edges = np.asarray(edges, dtype=np.float64)
    out = np.zeros(n_samples)
    lo_off, hi_off = int(math.ceil(7 * sigma)) + 1, int(math.ceil(7 * sigma + 40 * tau)) + 1
    offs = np.arange(-lo_off, hi_off + 1)
    step = np.where(np.arange(len(edges)) % 2 == 0, 2.0 * amp, -2.0 * amp)
    for c0 in range(0, len(edges), chunk_edges):
        e = edges[c0:c0 + chunk_edges]
        idx = np.floor(e).astype(np.int64)[:, None] + offs
        x = idx - e[:, None]
        g = np.exp(-x / tau + sigma * sigma / (2 * tau * tau) + log_ndtr(x / sigma - sigma / tau))
        ok = (idx >= 0) & (idx < n_samples)
        lo = int(idx[ok].min())
        acc = np.bincount(idx[ok] - lo, weights=(step[c0:c0 + chunk_edges, None] * g)[ok])
        out[lo:lo + len(acc)] += acc
    return out


def _edge_sigma_samples(opts: EncoderOptions, sample_rate: int) -> float:
    sigma_rise = opts.rise_time_us * 1e-6 * sample_rate / _RISE_10_90_SIGMAS
    # Gaussian response at fs/2 is exp(-(pi*sigma)^2/2) with sigma in samples
    sigma_aa = 0.0
    if opts.nyquist_atten_db > 0:
        sigma_aa = math.sqrt(2.0 * opts.nyquist_atten_db * math.log(10.0) / 20.0) / math.pi
    return max(sigma_rise, sigma_aa)


def _warp(t_s: npt.NDArray[np.float64], opts: EncoderOptions) -> npt.NDArray[np.float64]:
    if opts.time_warp is not None:
        t_s = np.asarray(opts.time_warp(t_s), dtype=np.float64)
        if np.any(np.diff(t_s) <= 0):
            raise EncoderError("time_warp must be strictly increasing")
    # a clock running fast by p ppm emits its edges earlier: nominal time / (1 + p 1e-6)
    return t_s / (1.0 + opts.drift_ppm * 1e-6)


def _labels_array(labels: Sequence[Timecode | str] | npt.ArrayLike, rate: FrameRate) -> npt.NDArray[np.int64]:
    if isinstance(labels, np.ndarray) and labels.ndim == 2:
        hmsf = labels.astype(np.int64)
    else:
        items = list(labels)  # type: ignore[arg-type]
        hmsf = np.array([(Timecode.parse(x) if isinstance(x, str) else x).as_tuple() if isinstance(x, (str, Timecode))
                         else tuple(x) for x in items], dtype=np.int64).reshape(-1, 4)
    if len(hmsf) == 0:
        raise EncoderError("no labels to encode")
    bad = np.flatnonzero(~labels_valid(hmsf, rate))
    if bad.size:
        row = hmsf[bad[0]]
        raise EncoderError(f"cannot encode label {row.tolist()} (#{bad[0]}) at {rate} fps: "
                           f"{label_problem(*(int(v) for v in row), rate)}")
    return hmsf
