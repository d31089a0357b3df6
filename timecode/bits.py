"""Edges -> biphase-mark bits -> 80-bit frames (forward and reverse play), vectorised.

Biphase mark: every bit opens with a transition; a 1 has a second one at mid-bit. So intervals between
edges are one half-bit (S) or one bit (L) long, measured against a local half-bit period that follows
speed changes. Edges get integer half-bit positions; a run is a stretch of edges with no impossible
interval. In each run the bit boundaries are the positions of one parity (the ends of every L interval
share it); a bit is 1 when an edge sits between two boundaries. Frames are found by their sync word:
0011 1111 1111 1101 forward, and its mirror 1011 1111 1111 1100 when the tape runs backwards.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.ndimage import uniform_filter1d

from timecode.frame import N_BITS, REVERSE_SYNC_BITS, SYNC_BITS

_W16 = 1 << np.arange(15, -1, -1)
SYNC_CODE = int(SYNC_BITS @ _W16)
REVERSE_SYNC_CODE = int(REVERSE_SYNC_BITS @ _W16)
RUN_GAP = 1 << 20  # half-bit positions left between runs so no window spans two runs


@dataclass(kw_only=True)
class EdgeStream:
    """Edges of one channel with their half-bit positions (``pos`` rises by RUN_GAP between runs)."""

    t: npt.NDArray[np.float64]  # (E,) edge times, samples
    index: npt.NDArray[np.int64]  # (E,) index of each edge in the caller's arrays (glitch pairs removed)
    pos: npt.NDArray[np.int64]  # (E,) half-bit position
    run: npt.NDArray[np.int64]  # (E,) run id
    half_bit_samples: float  # typical half-bit length


@dataclass(kw_only=True)
class RawFrames:
    """Frames found in the bit stream, in time order of their first bit on the wire."""

    bits: npt.NDArray[np.uint8]  # (F, 80) in frame order (bit 0 first), whatever the play direction
    start_edge: npt.NDArray[np.int64]  # (F,) index of the edge opening bit 0
    end_edge: npt.NDArray[np.int64]  # (F,) index of the edge closing bit 79
    reverse: npt.NDArray[np.bool_]  # (F,)


def half_bit_estimate(d: npt.NDArray[np.float64], sample_rate: float) -> float | None:
    """Most likely half-bit length from edge intervals ``d`` (intervals are h or 2h), or None."""
    h_lo, h_hi = sample_rate / (2 * 2760.0), sample_rate / (2 * 1630.0)
    if d.size > 200_000:  # a spread-out subsample is plenty for a histogram
        d = d[:: d.size // 100_000]
    d = d[(d > 0.75 * h_lo) & (d < 2.3 * h_hi)]
    if d.size < 20:
        return None
    ld = np.sort(np.log(d))
    grid = np.log(np.geomspace(h_lo, h_hi, 200))
    tol = np.log(1.15)

    def count(centre: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
        return np.searchsorted(ld, centre + tol) - np.searchsorted(ld, centre - tol)

    score = count(grid) + count(grid + np.log(2.0))
    h = float(np.exp(grid[int(np.argmax(score))]))
    r = d / h
    n = np.rint(r)
    ok = ((n == 1) | (n == 2)) & (np.abs(r - n) < 0.25 * n)
    return float(np.median(d[ok] / n[ok])) if ok.sum() >= 10 else None


def classify(t: npt.NDArray[np.float64], sample_rate: float, track_window: int = 64) -> tuple[
        npt.NDArray[np.int64], npt.NDArray[np.float64], float | None]:
    """Half-bit count n (1, 2, or 0 = impossible) of each interval ``t[k+1]-t[k]``, its length r in local
    half-bits (the local half-bit follows speed changes over ``track_window`` intervals), and the typical
    half-bit in samples."""
    d = np.diff(t)
    h = half_bit_estimate(d, sample_rate)
    n = np.zeros(len(d), np.int64)
    r = np.zeros(len(d))
    if h is None:
        return n, r, None
    h_loc = np.full(len(d), h)
    for _ in range(2):
        r = d / h_loc
        n = np.where((r > 0.45) & (r < 1.5), 1, np.where((r >= 1.5) & (r < 2.6), 2, 0))
        w = (n > 0).astype(np.float64)
        num = uniform_filter1d(np.where(n > 0, d / np.maximum(n, 1), 0.0), track_window, mode="nearest")
        den = uniform_filter1d(w, track_window, mode="nearest")
        h_loc = np.where(den > 0.2, num / np.maximum(den, 1e-9), h)
    return n, d / h_loc, h


def remove_glitches(t: npt.NDArray[np.float64], h: float, passes: int = 3) -> npt.NDArray[np.int64]:
    """Indices of ``t`` left after removing pairs of edges that bound an impossibly short interval (noise
    or a spike inside a half-bit) where the merged interval is a whole half-bit or bit. Where short
    intervals follow each other (a spike next to a real edge), the pair whose removal leaves the most
    regular interval goes."""
    idx = np.arange(len(t))
    for _ in range(passes):
        tt = t[idx]
        d = np.diff(tt)
        k = np.flatnonzero(d < 0.5 * h)
        k = k[(k >= 1) & (k + 2 < len(tt))]
        if k.size == 0:
            break
        merged = (tt[k + 2] - tt[k - 1]) / h
        n = np.rint(merged)
        q = np.where((n == 1) | (n == 2), np.abs(merged - n), np.inf)
        qa = np.full(len(d) + 2, np.inf)  # quality by interval index, padded
        qa[k + 1] = q
        best = (q < 0.3) & (q <= qa[k]) & (q < qa[k + 2])  # better than the overlapping neighbours
        if not best.any():
            break
        drop = np.zeros(len(idx), bool)
        drop[k[best]] = drop[k[best] + 1] = True
        idx = idx[~drop]
    return idx


def edge_stream(t: npt.NDArray[np.float64], rising: npt.NDArray[np.bool_], sample_rate: float) -> EdgeStream | None:
    """Half-bit positions and runs of sorted edge times ``t``; None when no LTC-like intervals exist."""
    if len(t) < 40:
        return None
    h = half_bit_estimate(np.diff(t), sample_rate)
    if h is None:
        return None
    index = remove_glitches(t, h)
    t, rising = t[index], rising[index]
    n, r, h = classify(t, sample_rate)
    if h is None:
        return None
    # consecutive edges must alternate direction
    n = np.where(rising[1:] != rising[:-1], n, 0)
    margin = np.abs(r - 1.5)  # how sure the short/long call of each interval is
    for attempt in range(4):
        brk = n == 0
        run = np.concatenate([[0], np.cumsum(brk)])
        step = np.where(brk, RUN_GAP, n)
        pos = np.concatenate([[0], np.cumsum(step)])
        # both ends of every L interval are bit boundaries, so all L's of a run share a parity. Between two
        # L's that disagree one interval was called wrong: flip the least certain call in between (or,
        # on the last attempt, break the run there).
        L = np.flatnonzero(n == 2)
        if L.size < 2:
            break
        viol = np.flatnonzero((pos[L[1:]] % 2 != pos[L[:-1]] % 2) & (run[L[1:]] == run[L[:-1]]))
        if viol.size == 0:
            break
        lo, hi = L[viol], L[viol + 1]
        if attempt == 3:
            n[hi] = 0
            continue
        width = int((hi - lo).max()) + 1
        idx = lo[:, None] + np.arange(width)
        m = np.where(idx <= hi[:, None], margin[np.minimum(idx, len(margin) - 1)], np.inf)
        pick = lo + np.argmin(m, axis=1)
        ok = n[pick] > 0
        n[pick[ok]] = 3 - n[pick[ok]]
    return EdgeStream(t=t, index=index, pos=pos, run=run, half_bit_samples=h)


def parity_of_runs(es: EdgeStream) -> npt.NDArray[np.int64]:
    """Boundary parity of each edge's run (the parity of the positions where bits start)."""
    d = np.diff(es.pos)
    L = np.flatnonzero(d == 2)
    nruns = int(es.run[-1]) + 1
    odd = np.bincount(es.run[L], weights=es.pos[L] % 2, minlength=nruns)
    tot = np.bincount(es.run[L], minlength=nruns)
    major = np.where(tot > 0, (odd * 2 > tot).astype(np.int64), -1)
    return major[es.run]


def find_frames(es: EdgeStream) -> RawFrames:
    """Every complete 80-bit frame (forward or reverse) in the edge stream."""
    par = parity_of_runs(es)
    boundary = np.flatnonzero((par >= 0) & (es.pos % 2 == par))
    empty = RawFrames(bits=np.zeros((0, N_BITS), np.uint8), start_edge=np.zeros(0, np.int64),
                      end_edge=np.zeros(0, np.int64), reverse=np.zeros(0, bool))
    if boundary.size < N_BITS + 1:
        return empty
    # a bit lies between consecutive boundary edges of one run, two half-bits apart
    b0, b1 = boundary[:-1], boundary[1:]
    ok = (es.run[b0] == es.run[b1]) & (es.pos[b1] - es.pos[b0] == 2)
    bit = (b1 - b0 == 2).astype(np.uint8)  # an edge in between: a 1
    # give each contiguous stretch of good bits its own id so no frame spans a gap
    seg = np.cumsum(np.concatenate([[0], ~ok[1:] | ~ok[:-1]]))
    seg = np.where(ok, seg, -1 - np.arange(len(ok)))
    if len(bit) < 16:
        return empty
    codes = np.zeros(len(bit) - 15, np.int64)
    for k in range(16):  # 16-bit word starting at each bit, first bit most significant
        codes = (codes << 1) | bit[k:len(bit) - 15 + k]
    same16 = seg[:-15] == seg[15:]
    fwd = np.flatnonzero((codes == SYNC_CODE) & same16)
    fwd = fwd[fwd >= 64]
    fwd = fwd[seg[fwd - 64] == seg[fwd]]
    rev = np.flatnonzero((codes == REVERSE_SYNC_CODE) & same16)
    rev = rev[rev + N_BITS <= len(bit)]
    rev = rev[seg[rev + N_BITS - 1] == seg[rev]]
    ar = np.arange(N_BITS)
    f_first = fwd - 64
    bits_f = bit[f_first[:, None] + ar]
    bits_r = bit[rev[:, None] + ar][:, ::-1]
    bits = np.concatenate([bits_f, bits_r])
    start = np.concatenate([b0[f_first], b1[rev + N_BITS - 1]])
    end = np.concatenate([b1[fwd + 15], b0[rev]])
    reverse = np.concatenate([np.zeros(len(fwd), bool), np.ones(len(rev), bool)])
    order = np.argsort(np.minimum(start, end), kind="stable")
    return RawFrames(bits=bits[order], start_edge=start[order], end_edge=end[order], reverse=reverse[order])
