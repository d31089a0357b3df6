"""Edges -> biphase-mark bits -> 80-bit frames (forward and reverse play), vectorised.

Biphase mark: every bit opens with a transition; a 1 has a second one at mid-bit. So intervals between
edges are one half-bit (S) or one bit (L) long, measured against a local half-bit period that follows
speed changes. Edges get integer half-bit positions; a run is a stretch of edges with no impossible
interval. In each run the bit boundaries are the positions of one parity (the ends of every L interval
share it); a bit is 1 when an edge sits between two boundaries. Frames are found by their sync word:
0011 1111 1111 1101 forward, and its mirror 1011 1111 1111 1100 when the tape runs backwards. A run that ends
(starts) on a mid-bit edge gets the edge closing (opening) that bit as a virtual edge, and a sync word whose
frame begins before its run (ends after it, in reverse play) gives a partial frame: see ``assemble``.
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
    virtual: npt.NDArray[np.bool_] | None = None  # (E,) edges not in the audio (``with_virtual_edges``)

    def __post_init__(self) -> None:
        if self.virtual is None:
            self.virtual = np.zeros(len(self.t), bool)


@dataclass(kw_only=True)
class RawFrames:
    """Frames found in the bit stream, in time order of their first bit on the wire.

    A partial frame is one whose sync word is in a run but whose first bits (forward play; its last bits in
    reverse play) lie before the run's start (after its end): ``missing`` > 0, ``start_edge`` -1 and those bits 0
    with ``known`` False. Its start position is ``start_pos`` all the same.
    """

    bits: npt.NDArray[np.uint8]  # (F, 80) in frame order (bit 0 first), whatever the play direction
    start_edge: npt.NDArray[np.int64]  # (F,) index of the edge opening bit 0 (-1: not in the run)
    end_edge: npt.NDArray[np.int64]  # (F,) index of the edge closing bit 79
    reverse: npt.NDArray[np.bool_]  # (F,)
    start_pos: npt.NDArray[np.int64]  # (F,) half-bit position of the frame start (the edge, or where it would be)
    missing: npt.NDArray[np.int64]  # (F,) bits not in the run (0: a complete frame)
    known: npt.NDArray[np.bool_]  # (F, 80)


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


def with_virtual_edges(es: EdgeStream) -> EdgeStream:
    """The stream with an edge added after a run that ends on a mid-bit edge and before one that starts on one.

    A run ending with the mid-bit edge of a 1 lacks only the edge closing that bit (the audio, or the LTC,
    stops there); if the bit is the last of a sync word the frame is complete but for its end edge (its start in
    reverse play). The added edges are ``virtual``: their times (one local half-bit beyond the run) are
    placeholders that the clock fit replaces by its extrapolation, and they carry index -1.
    """
    if len(es.t) < 2:
        return es
    par = parity_of_runs(es)
    brk = np.flatnonzero(np.diff(es.run) != 0)
    last = np.concatenate([brk, [len(es.t) - 1]])
    first = np.concatenate([[0], brk + 1])
    mid = (par >= 0) & (es.pos % 2 != par)
    after, before = last[mid[last]], first[mid[first]]
    if after.size + before.size == 0:
        return es

    def local_h(k: npt.NDArray[np.int64], step: int) -> npt.NDArray[np.float64]:
        j = np.clip(k + step, 0, len(es.t) - 1)
        j = np.where(es.run[j] == es.run[k], j, k)
        dp = es.pos[j] - es.pos[k]
        return np.where(dp != 0, (es.t[j] - es.t[k]) / np.where(dp != 0, dp, 1), es.half_bit_samples)

    t = np.concatenate([es.t, es.t[after] + local_h(after, -16), es.t[before] - local_h(before, 16)])
    pos = np.concatenate([es.pos, es.pos[after] + 1, es.pos[before] - 1])
    run = np.concatenate([es.run, es.run[after], es.run[before]])
    index = np.concatenate([es.index, np.full(after.size + before.size, -1)])
    virtual = np.concatenate([es.virtual, np.ones(after.size + before.size, bool)])
    order = np.argsort(pos, kind="stable")  # runs are RUN_GAP apart, so positions order the whole stream
    return EdgeStream(t=t[order], index=index[order], pos=pos[order], run=run[order],
                      half_bit_samples=es.half_bit_samples, virtual=virtual[order])


def find_frames(es: EdgeStream) -> RawFrames:
    """Every 80-bit frame (forward or reverse) whose sync word is in the edge stream: complete frames, and
    partial ones cut by the start (forward) or end (reverse) of their run."""
    par = parity_of_runs(es)
    boundary = np.flatnonzero((par >= 0) & (es.pos % 2 == par))
    z = np.zeros(0, np.int64)
    empty = RawFrames(bits=np.zeros((0, N_BITS), np.uint8), start_edge=z, end_edge=z, reverse=z.astype(bool),
                      start_pos=z, missing=z, known=np.zeros((0, N_BITS), bool))
    if boundary.size < 17:
        return empty
    # a bit lies between consecutive boundary edges of one run, two half-bits apart
    b0, b1 = boundary[:-1], boundary[1:]
    ok = (es.run[b0] == es.run[b1]) & (es.pos[b1] - es.pos[b0] == 2)
    bit = (b1 - b0 == 2).astype(np.uint8)  # an edge in between: a 1
    # give each contiguous stretch of good bits its own id so no frame spans a gap
    seg = np.cumsum(np.concatenate([[0], ~ok[1:] | ~ok[:-1]]))
    seg = np.where(ok, seg, -1 - np.arange(len(ok)))
    nbit = len(bit)
    ar_b = np.arange(nbit)
    opens = np.concatenate([[True], seg[1:] != seg[:-1]])
    closes = np.concatenate([seg[1:] != seg[:-1], [True]])
    first_of = np.maximum.accumulate(np.where(opens, ar_b, 0))  # first bit of each bit's stretch
    last_of = np.minimum.accumulate(np.where(closes, ar_b, nbit)[::-1])[::-1]
    codes = np.zeros(nbit - 15, np.int64)
    for k in range(16):  # 16-bit word starting at each bit, first bit most significant
        codes = (codes << 1) | bit[k:nbit - 15 + k]
    same16 = seg[:-15] == seg[15:]
    fwd = np.flatnonzero((codes == SYNC_CODE) & same16)
    rev = np.flatnonzero((codes == REVERSE_SYNC_CODE) & same16)
    ar = np.arange(N_BITS)
    # forward: frame bit j is bit fwd - 64 + j; those before the segment's first bit are missing
    miss_f = np.maximum(first_of[fwd] - (fwd - 64), 0)
    idx_f = fwd[:, None] - 64 + ar
    known_f = ar[None, :] >= miss_f[:, None]
    bits_f = np.where(known_f, bit[np.clip(idx_f, 0, nbit - 1)], 0)
    # reverse: frame bit 79 - i arrives as bit rev + i; those after the segment's last bit are missing
    miss_r = np.maximum(rev + N_BITS - 1 - last_of[rev], 0)
    idx_r = rev[:, None] + ar
    known_r = (ar[None, :] <= (last_of[rev] - rev)[:, None])[:, ::-1]
    bits_r = np.where(known_r, bit[np.clip(idx_r, 0, nbit - 1)][:, ::-1], 0)
    start = np.concatenate([np.where(miss_f > 0, -1, b0[np.maximum(fwd - 64, 0)]),
                            np.where(miss_r > 0, -1, b1[np.minimum(rev + N_BITS - 1, nbit - 1)])])
    end = np.concatenate([b1[fwd + 15], b0[rev]])
    start_pos = np.concatenate([es.pos[b0[fwd]] - 2 * 64, es.pos[b0[rev]] + 2 * N_BITS])
    first_t = np.concatenate([es.pos[b0[fwd]] - 2 * 64, es.pos[b0[rev]]])  # first bit on the wire
    order = np.argsort(first_t, kind="stable")
    return RawFrames(bits=np.concatenate([bits_f, bits_r]).astype(np.uint8)[order], start_edge=start[order],
                     end_edge=end[order], reverse=np.concatenate([np.zeros(len(fwd), bool),
                                                                  np.ones(len(rev), bool)])[order],
                     start_pos=start_pos[order], missing=np.concatenate([miss_f, miss_r])[order],
                     known=np.concatenate([known_f, known_r])[order])
