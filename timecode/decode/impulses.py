"""Transitions read from impulse trains: LTC through a field recorder or wireless receiver that differentiates it.

Such an input is a high-pass whose time constant is a few samples: every transition of the square wave becomes
a narrow impulse (one or two samples wide, an exponential tail, sometimes a little ringing) and the level
between impulses sits at the baseline. Impulses alternate in sign, or all have one sign when the receiver
rectifies. Biphase mark needs only the times of the transitions, so the rest of the decoder is unchanged.

Steps, vectorised over one block of one channel (stat blocks as in ``edges``):

1. Which stretches are impulse trains is chosen by ``edges``: per stat block, the reading (square wave or
   impulses) whose edges fit the LTC half-bit pattern.
2. Detect: local maxima of |x - baseline| above half the block's impulse level (the median height of
   the maxima above 0.4 of its 98th percentile), one per +-0.45 shortest half-bit. Sign mode per stat block: alternating (the sign gives the direction) or one sign (directions
   are assigned alternately; polarity carries nothing).
3. The input's pole: the impulses' mean tail decays as a^k; a is fitted on the tail of the mean impulse.
4. Undo the pole: ``d[n] = u[n] - a u[n-1]`` is, in continuous time, the square wave's derivative (each edge's
   Gaussian) convolved with exp(-t / tau) on [0, 1): compact, whatever the tail, and the tails of earlier
   impulses vanish from it too. Its centroid over +-3 samples lies ``c(a) = tau - a / (1 - a)`` after the
   edge (tau = -1 / ln a), so edge = centroid - c(a).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.ndimage import maximum_filter1d, median_filter, uniform_filter1d

from timecode.decode.bits import classify

#: Shortest LTC half-bit (30 fps + 15 %), seconds.
MIN_HALF_BIT_S = 1.0 / (2 * 30 * 80 * 1.15)
#: Impulses are read where the shortest half-bit spans at least this many samples (>= ~33 kHz).
MIN_HALF_BIT_SAMPLES = 6.0
THRESHOLD = 0.4  # detection threshold, fraction of the block's impulse level
HALF_WINDOW = 3  # centroid window, samples each side of the impulse


@dataclass(kw_only=True)
class ImpulseEdges:
    """Edges read from impulses: times (samples from the block start), directions, levels, and the pole."""

    t: npt.NDArray[np.float64]
    rising: npt.NDArray[np.bool_]
    amplitude: npt.NDArray[np.float32]
    pole: float  # a = exp(-1 / tau) of the input high-pass (nan: too few impulses to fit it)


def impulses_readable(sample_rate: float) -> bool:
    """Whether impulse trains are read at this sample rate (a half-bit must hold the impulse and its window)."""
    return MIN_HALF_BIT_S * sample_rate >= MIN_HALF_BIT_SAMPLES


def pole_offset(a: float) -> float:
    """Centroid of exp(-t / tau) on [0, 1) for a = exp(-1 / tau): where the de-tailed impulse's centroid lies
    after the edge (0 for a = 0, 0.5 as a -> 1)."""
    if not 0.0 < a < 1.0:
        return 0.0 if a <= 0.0 else 0.5
    return -1.0 / math.log(a) - a / (1.0 - a)


def fit_pole(u: npt.NDArray[np.float32], peaks: npt.NDArray[np.int64], sign: npt.NDArray[np.float32],
             tail: int) -> float:
    """The pole a of the input high-pass from the mean impulse (sign-corrected, aligned on the peak sample).

    The tail of the mean impulse decays as a^k once the edge's own rise is over, which is as many samples after
    the peak as the rise took before it (the leading side of the mean impulse tells); a is the least-squares
    ratio of consecutive tail samples, weighted by their size. Noise averages out over the impulses (a few
    hundred at least), and so do the earlier impulses' tails (also a^k). nan when no tail can be measured.
    """
    lead = 6
    ok = np.ones(len(peaks), bool)
    ok[:-1] &= np.diff(peaks) > tail + 2
    ok[1:] &= np.diff(peaks) > lead
    ok &= (peaks >= lead) & (peaks + tail < len(u))
    p = peaks[ok]
    if p.size < 100:
        return float("nan")
    k = np.arange(-lead, tail + 1)
    mean = (u[p[:, None] + k].astype(np.float64) * sign[ok, None]).mean(axis=0)
    m0 = mean[lead]
    if m0 <= 0:
        return float("nan")
    rise = 0  # samples before the peak above 5 % of it
    while rise < lead and mean[lead - rise - 1] - mean[0] > 0.05 * (m0 - mean[0]):
        rise += 1
    k1 = lead + rise + 1  # first index of the pure tail
    diff = mean[k1:-1] - mean[k1 + 1:]  # differences: a baseline offset (rectified tails) cancels
    if diff.size < 2:
        return float("nan")
    x, y = diff[:-1], diff[1:]
    den = float(np.dot(x, x))
    if den <= 0:
        return float("nan")
    return float(np.clip(np.dot(x, y) / den, 0.0, 0.98))


def find_impulses(x: npt.NDArray[np.float32], n: int, blocks: npt.NDArray[np.bool_], stat_block: int,
                  sample_rate: float, index: npt.NDArray[np.int64]) -> ImpulseEdges:
    """Impulses in the stat blocks ``blocks`` of ``x`` (raw samples padded to whole stat blocks, ``n`` of them
    real) read as edges: time (samples), direction and level of each."""
    L = stat_block
    nb = len(blocks)
    base = np.median(x.reshape(nb, L)[:, index], axis=1).astype(np.float32)
    u = x - np.repeat(base, L)
    au = np.abs(u)
    level = np.sort(au.reshape(nb, L)[:, index], axis=1)[:, min(len(index) - 1, int(0.98 * len(index)))]
    if nb >= 3:  # a stretch's level (+-4 blocks): a silent or noisy block beside impulses takes theirs
        level = median_filter(level, min(9, nb - (nb % 2 == 0)), mode="mirror")
    h_min = MIN_HALF_BIT_S * sample_rate
    r = max(1, int(0.45 * h_min))
    w = HALF_WINDOW
    peak = (au == maximum_filter1d(au, 2 * r + 1)) & (au > THRESHOLD * np.repeat(level, L)) & np.repeat(blocks, L)
    peak[:w + 2] = False
    peak[n - w - 2:] = False
    m = np.flatnonzero(peak)
    if m.size:
        m = m[np.concatenate([[True], np.diff(m) > r])]  # a flat top counts once
    if m.size < 2:
        return ImpulseEdges(t=np.zeros(0), rising=np.zeros(0, bool), amplitude=np.zeros(0, np.float32),
                            pole=float("nan"))
    # sign mode per block: one sign when over 85 % of the tall candidates (over 0.6 of the 98th percentile, and
    # of half the loudest blocks') within +-4 blocks share it; the other sign is then noise, or the dips between
    # overlapping tails
    blk = m // L
    sign = np.where(u[m] >= 0, 1.0, -1.0).astype(np.float32)
    loud = np.percentile(level[blocks], 90)  # of the blocks read here: not noise in a long silence
    tall = au[m] > 0.6 * np.maximum(level, 0.5 * loud)[blk]
    n_pos = uniform_filter1d(np.bincount(blk, weights=tall & (sign > 0), minlength=nb), 9, mode="mirror")
    n_tall = uniform_filter1d(np.bincount(blk, weights=tall, minlength=nb), 9, mode="mirror")
    pos = n_pos / np.maximum(n_tall, 1e-9)
    one_sign = ((pos > 0.85) | (pos < 0.15)) & (n_tall >= 2)  # two tall impulses a block, at least
    keep = ~(one_sign[blk] & (sign != np.where(pos[blk] > 0.5, 1.0, -1.0)))
    m, sign = m[keep], sign[keep]
    # the impulse level: median height of the candidates per block; half of it is the threshold (noise peaks
    # that passed 0.4 of the 98th percentile do not pass it)
    blk = m // L
    keep = au[m] > 0.5 * _block_median(au[m], blk, nb)[blk]
    m, sign = m[keep], sign[keep]
    blk = m // L
    # alternating stretches: of two neighbours with one sign, a small one is noise on the other's tail
    same = np.concatenate([[False], sign[1:] == sign[:-1]]) & ~one_sign[blk]
    small = au[m] < 0.75 * _block_median(au[m], blk, nb)[blk]
    keep = ~(small & (same | np.concatenate([same[1:], [False]])))
    m, sign = m[keep], sign[keep]
    a = fit_pole(u, m, sign, tail=max(4, int(1.6 * h_min)))
    a_used = 0.0 if math.isnan(a) else a
    d = u.copy()
    d[1:] -= np.float32(a_used) * u[:-1]
    d -= np.repeat(np.median(d.reshape(nb, L)[:, index], axis=1).astype(np.float32), L)
    # centroid of the de-tailed impulse (it peaks at most a sample from |u|'s peak) over +-w samples; samples
    # below the baseline (noise, ringing) weigh nothing, so the window's area cannot vanish
    near = np.stack([d[m - 1], d[m], d[m + 1]]) * sign
    j = m + np.argmax(near, axis=0) - 1
    offs = np.arange(-w, w + 1)
    win = np.maximum(d[j[:, None] + offs].astype(np.float64) * sign[:, None], 0.0)
    area = win.sum(axis=1)
    good = area > 0.25 * np.median(area)
    t = j + (win * offs).sum(axis=1) / np.where(good, area, 1.0) - pole_offset(a_used)
    m, t, sign = m[good], t[good], sign[good]
    keep = _on_grid(t, sample_rate)
    m, t, sign = m[keep], t[keep], sign[keep]
    # one-sign stretches: the sign says nothing, so directions simply alternate
    rising = np.where(one_sign[m // L], np.arange(len(m)) % 2 == 0, sign > 0)
    return ImpulseEdges(t=t, rising=rising, amplitude=au[m].astype(np.float32), pole=a)


def _on_grid(t: npt.NDArray[np.float64], sample_rate: float) -> npt.NDArray[np.bool_]:
    """Impulses to keep: not one whose two intervals are both off the half-bit grid (more than a quarter
    half-bit from one or two half-bits, at the local half-bit) while their sum is on it: noise on an impulse's
    tail, which one sign or a long tail lets through the threshold."""
    keep = np.ones(len(t), bool)
    if len(t) < 40:
        return keep
    n, r, h = classify(t, sample_rate)
    if h is None:
        return keep
    off = (n == 0) | (np.abs(r - n) > 0.25)
    both = off[:-1] & off[1:]  # impulse k + 1 sits between two off-grid intervals
    merged = r[:-1] + r[1:]
    on = np.abs(merged - np.clip(np.rint(merged), 1, 2)) < 0.2
    keep[1:-1] = ~(both & on)
    return keep


def _block_median(v: npt.NDArray, blk: npt.NDArray[np.int64], nb: int) -> npt.NDArray[np.float64]:
    """Median of ``v`` per block id ``blk`` (sorted ascending); blocks without values take the nearest one's."""
    cnt = np.bincount(blk, minlength=nb)
    order = np.lexsort((v, blk))
    first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    med = v[order][np.minimum(first + cnt // 2, len(v) - 1)].astype(np.float64)
    have = np.flatnonzero(cnt > 0)
    return np.interp(np.arange(nb), have, med[have])
