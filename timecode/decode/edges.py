"""Find every LTC transition in a block of audio and time it to a small fraction of a sample.

Steps, all vectorised over the block (one channel):

1. Robust level: per stat block (~8 ms) the 2nd and 98th percentiles give the two signal levels (blocks
   without swing borrow their neighbours'); spikes beyond 1.6x the half swing around the mid are clipped.
2. AC coupling (optional): undo a one-pole high-pass (see ``droop.py``) so plateaus are flat again.
3. Smooth with a Gaussian (about a tenth of a half-bit, ~0.85 samples at low rates): close to the matched
   filter of a band-limited edge, so the crossing of the smoothed signal is a near-optimal time estimate.
4. Detect: a Schmitt trigger (thresholds at mid +- 0.15 half swing) flips once per transition, whatever
   the noise chatter, DC, droop or high-pass decay back toward the mid level.
5. Baseline: per stat block, least squares of the smoothed signal on the ideal +-1 square wave gives the
   offset (DC plus residual droop); it is interpolated to each edge.
6. Fine time: in the window before each flip, the zero of (smoothed - baseline) at a steep step, from a
   cubic through four samples (Newton from the linear estimate); where the baseline is not crossed at a
   steep step (heavily high-passed or clipped audio), the steepest point of the transition.
7. The reading per stat block (``_choose``): the square wave above where its edges keep the LTC half-bit pattern
   and it explains at least ``SQUARE_FIT`` of the block's variance; else an impulse train (``impulses``: a
   differentiating recorder input) where that reading keeps the pattern; else the nearest block's reading.

Times are in samples from the start of the block (0.0 = the first sample).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.ndimage import maximum_filter1d, median_filter

from timecode.audio_io import to_float32
from timecode.decode.droop import Droop, compensate, estimate_droop
from timecode.decode.bits import half_bit_estimate
from timecode.decode.impulses import find_impulses, impulses_readable

#: Highest and lowest LTC bit rates considered (30 fps +15 %, 23.976 fps -15 %), bits per second.
MAX_BIT_RATE = 30 * 80 * 1.15
MIN_BIT_RATE = 23.976 * 80 * 0.85
#: A stat block is read as a square wave only if the square wave explains this much of its variance.
SQUARE_FIT = 0.7


@dataclass(frozen=True, kw_only=True)
class EdgeParams:
    """Per-sample-rate settings of the edge finder (see ``edge_params``)."""

    sample_rate: float
    sigma_samples: float  # Gaussian smoothing
    stat_block: int  # samples per level/baseline block (power of two)
    search_samples: int  # how far before a Schmitt flip the steepest step is searched
    hysteresis: float = 0.15  # Schmitt thresholds at mid +- this fraction of the half swing
    clip_factor: float = 1.6
    impulses: bool = True  # read impulse trains too (``impulses.impulses_readable``)


def edge_params(sample_rate: float, sigma_samples: float | None = None) -> EdgeParams:
    """Settings for ``sample_rate``: smoothing ~ 0.1 half-bit but ~0.85 samples at 16-32 kHz and at most
    0.18 half-bit (8 kHz), found best on band-limited synthetic LTC with noise; ~8 ms stat blocks."""
    half_bit = sample_rate / (2 * 80 * 27.0)
    sigma = sigma_samples if sigma_samples is not None else min(0.18 * half_bit, max(0.85, 0.1 * half_bit))
    stat_block = 1 << max(6, round(math.log2(sample_rate * 0.008)))
    search = max(3, int(math.ceil(2.0 * math.hypot(sigma, 0.85))) + 1)
    return EdgeParams(sample_rate=sample_rate, sigma_samples=sigma, stat_block=stat_block, search_samples=search,
                      impulses=impulses_readable(sample_rate))


@dataclass(kw_only=True)
class BlockEdges:
    """Edges found in one block: times (float samples from the block start), direction and level."""

    t: npt.NDArray[np.float64]
    rising: npt.NDArray[np.bool_]
    amplitude: npt.NDArray[np.float32]  # peak level around the edge (half swing, or the impulse's height)
    impulse: npt.NDArray[np.bool_]  # read from an impulse train (else from a square wave)
    pole: float = float("nan")  # the impulse stretches' input pole a = exp(-1 / tau) (nan: none fitted)

    @classmethod
    def empty(cls) -> BlockEdges:
        return cls(t=np.zeros(0), rising=np.zeros(0, bool), amplitude=np.zeros(0, np.float32),
                   impulse=np.zeros(0, bool))


def _level_sample_index(n: int) -> npt.NDArray[np.int64]:
    """About a quarter of a block's samples for the level percentiles, on every phase modulo 2, 3 and 4: a plain
    stride of 4 sees one phase only of a signal with a 4-sample period (8 kHz LTC at 25 fps: a half-bit is 2
    samples) and can miss one of its levels."""
    i = np.arange(n // 4)
    return 4 * i + i % 4


def block_levels(x2d: npt.NDArray[np.float32]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32],
                                                        npt.NDArray[np.bool_]]:
    """Mid level and half swing per row of (B, L) from the 2nd/98th percentiles, median-filtered over rows, and
    which rows hold a two-level (square) signal of their own."""
    sub = np.sort(x2d[:, _level_sample_index(x2d.shape[1])], axis=1)
    k = sub.shape[1]
    lo = sub[:, int(0.02 * k)]
    hi = sub[:, min(k - 1, int(0.98 * k))]
    # A block with little swing next to blocks with a lot holds no edges (flat lead-in, dropout); one that
    # sits mostly on one level (LTC starts or stops in it) has skewed percentiles; noise alone is not two
    # levels (most samples sit near the middle). Such blocks take the levels of the nearest good block.
    swing = hi - lo
    mid = (lo + hi) / 2
    above = (sub > mid[:, None]).mean(axis=1)
    central = (np.abs(sub - mid[:, None]) < (0.25 * swing)[:, None]).mean(axis=1)
    good = ((swing > 0.25 * maximum_filter1d(swing, 17, mode="nearest")) & (above > 0.2) & (above < 0.8)
            & (central < 0.5))
    if 0 < good.sum() < len(good):
        gi = np.flatnonzero(good)
        rows = np.arange(len(good))
        j = np.searchsorted(gi, rows)
        after, before = gi[np.clip(j, 0, len(gi) - 1)], gi[np.clip(j - 1, 0, len(gi) - 1)]
        nearest = np.where(np.abs(before - rows) < np.abs(after - rows), before, after)
        lo, hi = lo[nearest], hi[nearest]
    if len(lo) >= 5:
        lo, hi = median_filter(lo, 5, mode="nearest"), median_filter(hi, 5, mode="nearest")
    return (lo + hi) / 2, (hi - lo) / 2, good


def schmitt_edges(ys: npt.NDArray[np.float32], mid: npt.NDArray[np.float32], half: npt.NDArray[np.float32],
                  params: EdgeParams) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
    """Hysteresis (Schmitt trigger) edge detection on the smoothed signal ``ys``.

    The state flips high when ys rises above mid + h, low when it falls below mid - h (h = ``hysteresis``
    x half swing), so noise chatter and high-pass decays back toward the mid level never flip it.
    Returns (start, stop, rising): each transition lies between samples start and stop (the first sample
    of the new state plus one, searching back at most ``search_samples`` but not before the last sample
    of the old state). Stat blocks with more flips per sample than LTC can have (noise, music) are dropped.
    """
    L = params.stat_block
    thr = (params.hysteresis * half).astype(np.float32)
    ys2d = ys.reshape(-1, L)
    state = ((ys2d > (mid + thr)[:, None]).view(np.int8) - (ys2d < (mid - thr)[:, None]).view(np.int8)).ravel()
    ch = np.flatnonzero(state[1:] != state[:-1]) + 1  # state[ch] differs from state[ch - 1]
    ch = np.concatenate([[0], ch])  # the initial state counts as a change at sample 0
    new = state[ch]
    nz = new != 0
    ch_nz, new_nz = ch[nz], new[nz]
    if state[0] == 0 and ch_nz.size and ch_nz[0] > params.search_samples:
        # the block starts in silence: the first swing out of it (LTC switched on) is an edge too
        ch_nz, new_nz = np.concatenate([[0], ch_nz]), np.concatenate([[-new_nz[0]], new_nz])
    flip = np.flatnonzero(new_nz[1:] != new_nz[:-1]) + 1
    trig = ch_nz[flip]  # first sample of the new state
    rising = new_nz[flip] > 0
    left_old = ch[np.maximum(np.searchsorted(ch, trig) - 1, 0)]  # first sample after the old state
    start = np.minimum(np.maximum(left_old - 1, trig - params.search_samples), trig - 1)
    stop = np.minimum(trig + 1, len(ys) - 1)
    keep = start >= 1
    start, stop, rising = start[keep], stop[keep], rising[keep]
    per_block = np.bincount(start // L, minlength=ys2d.shape[0])
    dense = per_block > 2.0 * MAX_BIT_RATE * 1.3 / params.sample_rate * L
    if dense.any():
        ok = ~dense[start // L]
        start, stop, rising = start[ok], stop[ok], rising[ok]
    return start, stop, rising


def steepest_steps(ys: npt.NDArray[np.float32], start: npt.NDArray[np.int64], stop: npt.NDArray[np.int64],
                   rising: npt.NDArray[np.bool_]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32],
                                                           npt.NDArray[np.float32]]:
    """Gather each transition window: (j0, w, step) with w[i, e] = ys[j0[e] + i] and the signed steps
    (positive in the edge direction; -inf outside the window). Windows are columns (fast reductions)."""
    width = int((stop - start).max()) + 1 if len(start) else 1
    idx = start[None, :] + np.arange(width)[:, None]
    w = ys[np.minimum(idx, len(ys) - 1)]
    step = np.diff(w, axis=0)
    np.negative(step, out=step, where=~rising[None, :])
    step[idx[1:] > stop[None, :]] = -np.inf
    return start, w, step


def _square_wave(c: npt.NDArray[np.int64], first_high: bool, n: int) -> npt.NDArray[np.int8]:
    """+-1 per sample, flipping after each crossing index in ``c``."""
    counts = np.diff(np.concatenate([[0], c + 1, [n]]))
    lev = np.where(np.arange(len(c) + 1) % 2 == 0, 1, -1).astype(np.int8)
    if not first_high:
        lev = -lev
    return np.repeat(lev, counts)


def baseline(ys2d: npt.NDArray[np.float32], sq2d: npt.NDArray[np.int8], mid: npt.NDArray[np.float32],
             half: npt.NDArray[np.float32], n: int | None = None) -> tuple[npt.NDArray[np.float64],
                                                                     npt.NDArray[np.float64],
                                                                     npt.NDArray[np.float64]]:
    """Per block least squares ys ~ offset + amp * sq; blocks without both levels keep the percentile mid.
    Also the fraction of each block's variance that the square wave explains (0 without both levels). Only the
    first ``n`` samples count (the padding after the audio's end, a held sample, could be anywhere)."""
    B, width = ys2d.shape
    L = np.full(B, float(width))
    if n is not None and n < B * width:
        r = n - (B - 1) * width  # real samples in the last block
        ys2d, sq2d = ys2d.copy(), sq2d.copy()
        ys2d[-1, r:], sq2d[-1, r:], L[-1] = 0, 0, max(r, 1)
    s_y = ys2d.sum(axis=1, dtype=np.float64)
    s_q = sq2d.sum(axis=1, dtype=np.float64)
    s_yq = np.einsum("ij,ij->i", ys2d, sq2d.astype(np.float32), dtype=np.float64)
    s_yy = np.einsum("ij,ij->i", ys2d, ys2d, dtype=np.float64)
    var_q = L - s_q * s_q / L
    ok = var_q > 0.2 * L
    cov = s_yq - s_y * s_q / L
    amp = np.where(ok, cov / np.where(ok, var_q, 1.0), half)
    off = np.where(ok, (s_y - amp * s_q) / L, mid)
    var_y = s_yy - s_y * s_y / L
    explained = np.where(ok & (var_y > 0), cov * amp / np.where(var_y > 0, var_y, 1.0), 0.0)
    return off, np.abs(amp), explained


def regular_blocks(t: npt.NDArray[np.float64], n_blocks: int, stat_block: int,
                   sample_rate: float) -> npt.NDArray[np.bool_]:
    """Stat blocks whose edges ``t`` (sorted, samples) are LTC-like: at least 4 intervals end in the block and
    at least 80 % of them are one or two half-bits (+- 20 %) of the half-bit the edges show overall."""
    d = np.diff(t)
    h = half_bit_estimate(d, sample_rate)
    if h is None:
        return np.zeros(n_blocks, bool)
    r = d / h
    k = np.rint(r)
    ok = ((k == 1) | (k == 2)) & (np.abs(r - k) < 0.2 * k)
    blk = np.clip(t[1:].astype(np.int64) // stat_block, 0, n_blocks - 1)
    total = np.bincount(blk, minlength=n_blocks)
    return (total >= 4) & (np.bincount(blk, weights=ok, minlength=n_blocks) >= 0.8 * total)


def refine_edges(ys: npt.NDArray[np.float32], win: tuple, base: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Sub-sample time of each transition window (from ``_coarse``).

    Normally the zero of ys - base in the edge direction at one of the window's steep steps (at least half
    the steepest): cubic through four samples, Newton from the linear estimate. If the baseline is not
    crossed at a steep step (a strongly high-passed or clipped signal whose transitions start from near
    the mid level), the steepest point: parabola through the three steps around the steepest one.
    """
    start, _, rising, k, w, step = win
    g = w - base.astype(np.float32)[None, :]
    np.negative(g, out=g, where=~rising[None, :])
    cross = (g[:-1] < 0) & (g[1:] >= 0)
    cross &= step >= 0.5 * step.max(axis=0)[None, :]
    score = np.where(cross, step, -np.inf)
    jc = np.argmax(score, axis=0)
    has = cross[jc, np.arange(len(start))]
    c = start + jc
    t = c + _cubic_root(ys[c - 1] - base, ys[c] - base, ys[c + 1] - base, ys[c + 2] - base)
    if not has.all():  # steepest point: parabola through the steps around the steepest one
        kk = k[~has]
        d0, d1, d2 = (ys[kk + i + 1].astype(np.float64) - ys[kk + i] for i in (-1, 0, 1))
        den = d0 - 2.0 * d1 + d2
        off = 0.5 * (d0 - d2) / np.where(den == 0, np.inf, den)
        t[~has] = kk + 0.5 + np.clip(off, -0.5, 0.5)
    return t


def _cubic_root(gm, g0, g1, g2):
    """Root in [-0.5, 1.5] of the cubic through (-1, gm), (0, g0), (1, g1), (2, g2), from the linear guess."""
    a1 = -gm / 3 - g0 / 2 + g1 - g2 / 6
    a2 = (gm + g1) / 2 - g0
    a3 = (g2 - gm) / 6 + (g0 - g1) / 2
    denom = g0 - g1
    u = g0 / np.where(denom == 0, np.inf, denom)
    for _ in range(2):  # Newton from the linear guess: converged to ~1e-8 sample
        p = g0 + u * (a1 + u * (a2 + u * a3))
        dp = a1 + u * (2 * a2 + 3 * u * a3)
        u = np.clip(u - p / np.where(dp == 0, np.inf, dp), -0.5, 1.5)
    return u


def _pad(x: npt.ArrayLike, params: EdgeParams) -> tuple[npt.NDArray[np.float32], int]:
    """Float32 copy padded to whole stat blocks (with the last sample), and the count of real samples."""
    x = to_float32(np.asarray(x))
    n = len(x)
    nb = max(1, -(-n // params.stat_block))
    xp = np.empty(nb * params.stat_block, dtype=np.float32)
    xp[:n] = x
    xp[n:] = x[-1] if n else 0.0
    return xp, n


def _condition(xp: npt.NDArray[np.float32], params: EdgeParams, droop: Droop | None, levels: tuple):
    """Spikes clipped (in place) and droop undone in the padded ``xp``; with mids and half swings."""
    L = params.stat_block
    x2d = xp.reshape(-1, L)
    mid, half, _ = levels
    lo, hi = mid - params.clip_factor * half, mid + params.clip_factor * half
    np.clip(x2d, lo[:, None], hi[:, None], out=x2d)
    if droop is not None and droop.active:
        xp = compensate(xp, droop).astype(np.float32, copy=False)
        mid, half, _ = block_levels(xp.reshape(-1, L))
    return xp, mid, half


def smooth(x: npt.NDArray[np.float32], sigma: float) -> npt.NDArray[np.float32]:
    """Gaussian smoothing (kernel to 4 sigma; the end samples held beyond the ends, so an edge a few samples
    into the audio is seen)."""
    r = max(1, int(math.ceil(4.0 * sigma)))
    kern = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    kern = (kern / kern.sum()).astype(np.float32)
    y = np.convolve(x, kern, mode="same")
    if len(x) > 4 * r:  # the ends again, with the end samples held (no copy of the whole block)
        y[:r] = np.convolve(np.pad(x[:3 * r], r, mode="edge"), kern, mode="valid")[:r]
        y[-r:] = np.convolve(np.pad(x[-3 * r:], r, mode="edge"), kern, mode="valid")[-r:]
        return y
    return np.convolve(np.pad(x, r, mode="edge"), kern, mode="valid")


def _coarse(xp, n, mid, half, params):
    """Smoothed signal, transition windows (gathered) and, for the baseline fit, the steepest step of each."""
    ys = smooth(xp, params.sigma_samples)
    start, stop, rising = schmitt_edges(ys, mid, half, params)
    ok = (stop < n - 1) & (start >= 1)  # the cubic takes ys[c - 1 .. c + 2]; past n: the held last sample
    start, stop, rising = start[ok], stop[ok], rising[ok]
    if start.size == 0:
        return ys, (start, stop, rising, start, np.zeros((1, 0)), np.zeros((1, 0)))
    j0, w, step = steepest_steps(ys, start, stop, rising)
    k = j0 + np.argmax(step, axis=0)
    return ys, (start, stop, rising, k, w, step)


def _square_reading(xp: npt.NDArray[np.float32], n: int, params: EdgeParams, droop: Droop | None):
    """The Schmitt-trigger reading of the padded ``xp`` (clipped in place): (edges, per-block fraction of the
    variance a square wave explains, smoothed signal, transition windows)."""
    L = params.stat_block
    nb = len(xp) // L
    xc, mid, half = _condition(xp, params, droop, block_levels(xp.reshape(nb, L)))
    ys, win = _coarse(xc, n, mid, half, params)
    rising, k = win[2], win[3]
    if k.size < 2:
        return BlockEdges.empty(), np.zeros(nb), ys, win
    sq = _square_wave(k, not bool(rising[0]), nb * L)
    off, _, explained = baseline(ys.reshape(nb, L), sq.reshape(nb, L), mid, half, n)
    centres = (np.arange(nb) + 0.5) * L - 0.5
    base = np.interp(k + 0.5, centres, off)
    t = refine_edges(ys, win, base)
    return (BlockEdges(t=t, rising=rising, amplitude=np.interp(t, centres, half).astype(np.float32),
                       impulse=np.zeros(len(t), bool)), explained, ys, win)


def _choose(square: BlockEdges, explained: npt.NDArray[np.float64], raw: npt.NDArray[np.float32] | None, n: int,
            params: EdgeParams) -> tuple[BlockEdges, npt.NDArray[np.bool_]]:
    """Per stat block, the reading that fits: the square wave where its edges are LTC-like and it explains at
    least ``SQUARE_FIT`` of the variance (bipolar impulses give LTC-like Schmitt edges, but a square wave
    explains little of them); else the impulse reading where its edges are LTC-like. Blocks where neither fits
    (silence, noise, a dropout, where LTC starts) take the reading of the nearest block where one does (the
    square wave on a tie, and everywhere when no impulse reading fits anywhere, as before impulses were read).
    Returns the edges and which blocks were read as impulses."""
    L = params.stat_block
    nb = len(explained)
    square_fit = (explained >= SQUARE_FIT) & regular_blocks(square.t, nb, L, params.sample_rate)
    none = np.zeros(nb, bool)
    if raw is None or square_fit.all():
        return square, none
    imp = _impulses_in(raw, n, ~square_fit, params)
    impulse_fit = ~square_fit & regular_blocks(imp.t, nb, L, params.sample_rate)
    if not impulse_fit.any():
        return square, none
    label = np.where(impulse_fit, 2, np.where(square_fit, 1, 0))
    known = np.flatnonzero(label > 0)
    rows = np.arange(nb)
    j = np.searchsorted(known, rows)
    after, before = known[np.clip(j, 0, len(known) - 1)], known[np.clip(j - 1, 0, len(known) - 1)]
    d_b, d_a = np.abs(rows - before), np.abs(after - rows)
    as_impulse = np.where(d_b < d_a, label[before] == 2,
                          np.where(d_a < d_b, label[after] == 2, (label[before] == 2) & (label[after] == 2)))
    in_imp = lambda t: as_impulse[np.clip(t.astype(np.int64) // L, 0, nb - 1)]  # noqa: E731
    ks, ki = ~in_imp(square.t), in_imp(imp.t)
    t = np.concatenate([square.t[ks], imp.t[ki]])
    order = np.argsort(t, kind="stable")
    cat = lambda a, b: np.concatenate([a[ks], b[ki]])[order]  # noqa: E731
    return BlockEdges(t=t[order], rising=cat(square.rising, imp.rising), amplitude=cat(square.amplitude,
                      imp.amplitude), impulse=cat(square.impulse, np.ones(len(imp.t), bool)), pole=imp.pole), as_impulse


def _impulses_in(raw: npt.NDArray[np.float32], n: int, blocks: npt.NDArray[np.bool_], params: EdgeParams):
    """``impulses.find_impulses`` on the stat blocks ``blocks`` and one block either side only (gathered into
    one array, so the impulses of every stretch fit one input pole), times mapped back to ``raw``."""
    L = params.stat_block
    nb = len(blocks)
    near = blocks.copy()
    near[1:] |= blocks[:-1]
    near[:-1] |= blocks[1:]
    rows = np.flatnonzero(near)
    sub = raw.reshape(nb, L)[rows].ravel()
    n_sub = len(sub) - (nb * L - n if rows[-1] == nb - 1 else 0)
    imp = find_impulses(sub, n_sub, blocks[rows], L, params.sample_rate, _level_sample_index(L))
    k = np.minimum(imp.t.astype(np.int64) // L, len(rows) - 1)
    imp.t = imp.t + (rows[k] - k) * L
    return imp


def find_edges(x: npt.ArrayLike, params: EdgeParams, droop: Droop | None = None) -> BlockEdges:
    """Every LTC transition in one channel block ``x`` (1-D, any dtype, full scale 1.0 for floats), read per
    stat block as a square wave (Schmitt trigger) or as an impulse train (``impulses``), whichever fits."""
    xp, n = _pad(x, params)
    raw = xp.copy() if params.impulses else None  # the square reading clips xp in place
    square, explained, _, _ = _square_reading(xp, n, params, droop)
    return _choose(square, explained, raw, n, params)[0]


def block_droop(x: npt.ArrayLike, params: EdgeParams, edge_sigma_samples: float = 1.0) -> Droop | None:
    """Fit the AC coupling of one channel on an excerpt ``x`` (~1-2 s); None if it holds too few edges.
    None is fitted (corner 0) where the excerpt is mostly read as an impulse train."""
    xp, n = _pad(x, params)
    raw = xp.copy() if params.impulses else None
    square, explained, ys, win = _square_reading(xp, n, params, None)
    if raw is not None and _choose(square, explained, raw, n, params)[1].mean() > 0.5:
        return Droop(corner_hz=0.0, sample_rate=params.sample_rate)
    rising, c = win[2], win[3]
    if c.size < 200:
        return None
    sq = _square_wave(c, not bool(rising[0]), len(xp))[:n]
    guard = 3.0 * float(np.hypot(params.sigma_samples, edge_sigma_samples)) + 1.0
    return estimate_droop(xp[:n], c, sq, params.sample_rate, guard)
