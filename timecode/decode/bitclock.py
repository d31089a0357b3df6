"""Frame times from the local bit clock: a robust quadratic fit of edge time against half-bit position.

An LTC generator's edges sit on a regular clock locked to the video frame, so the best estimate of the
time of one edge uses its neighbours too: around each frame start we fit t(pos) = c0 + c1 x + c2 x^2
(x = half-bit offset from the frame start) to every edge within +-1 frame (320 half-bits), trimmed twice
at 3 and 3.5 times the RMS residual, and take c0. The quadratic term follows speed changes. Fits never
cross a break in the edge run or a timecode discontinuity (``seg_lo``/``seg_hi``), nor a slip (edges the stream
counted a half-bit off, which shows as a jump of the residuals). The RMS of the kept residuals is the frame's
jitter figure. The centre need not be an edge: a frame edge outside the audio is the fit's extrapolation.
"""
from __future__ import annotations

import numpy as np
import numpy.typing as npt

WINDOW_HALF_BITS = 2 * 80  # one frame either side
BATCH = 8192


def fit_frame_times(
    t: npt.NDArray[np.float64],
    pos: npt.NDArray[np.int64],
    use: npt.NDArray[np.bool_],
    centre_pos: npt.NDArray[np.int64],
    other_pos: npt.NDArray[np.int64],
    ref_edge: npt.NDArray[np.int64],
    seg_lo: npt.NDArray[np.int64],
    seg_hi: npt.NDArray[np.int64],
    half_bit_samples: float,
    window: int = WINDOW_HALF_BITS,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Fitted times at half-bit positions ``centre_pos`` and ``other_pos``, and the RMS residual, all in samples.

    Args:
        t, pos: (E,) edge times and half-bit positions (positions increase with the index).
        use: (E,) edges the fits may use (added edges that are not in the audio may not).
        centre_pos, other_pos: (F,) positions to time (e.g. frame start and end); an edge need not be there.
        ref_edge: (F,) a usable edge at, or nearest to, each centre: its time anchors the fit, and where the
            window reaches one side only the fit takes the edges within half a window of it.
        seg_lo, seg_hi: (F,) inclusive half-bit position range the fit of each frame may use.
        half_bit_samples: typical half-bit length (removed before fitting, for float32 precision).
    """
    nf = len(centre_pos)
    c_out = np.empty(nf)
    o_out = np.empty(nf)
    rms_out = np.empty(nf)
    for b0 in range(0, nf, BATCH):
        sl = slice(b0, min(nf, b0 + BATCH))
        c, o, r = _fit_batch(t, pos, use, centre_pos[sl], other_pos[sl], ref_edge[sl], seg_lo[sl], seg_hi[sl],
                             window, half_bit_samples)
        c_out[sl], o_out[sl], rms_out[sl] = c, o, r
    return c_out, o_out, rms_out


def _fit_batch(t, pos, use, p0, po, ref, seg_lo, seg_hi, window, h):
    t0 = t[ref] + h * (p0 - pos[ref])  # the centre's time from the reference edge and the nominal clock
    lo = np.searchsorted(pos, np.maximum(p0 - window, seg_lo), side="left")
    hi = np.searchsorted(pos, np.minimum(p0 + window, seg_hi), side="right")
    width = max(int((hi - lo).max()) if len(lo) else 0, 1)
    idx = lo[:, None] + np.arange(width)
    valid = idx < hi[:, None]
    idx = np.minimum(idx, len(t) - 1)
    valid &= use[idx]
    dp = pos[idx] - p0[:, None]
    # residual from the nominal clock is small, so float32 keeps ~1e-5 sample precision
    y = (t[idx] - t0[:, None] - h * dp).astype(np.float32)
    x = (dp * (1.0 / window)).astype(np.float32)
    x2 = x * x
    # quadratic where the window reaches well to both sides of the centre; at the end of a run a line
    # through the nearest half frame of edges (extrapolating a parabola, or a line over a long curved stretch
    # of a speed change, would cost more than it gains)
    left = (p0 - pos[lo]) >= window // 3
    right = (pos[np.maximum(hi - 1, 0)] - p0) >= window // 3
    two_sided = left & right
    ridge = np.where(two_sided, 0.0, 1e9)
    valid &= two_sided[:, None] | (np.abs(pos[idx] - pos[ref][:, None]) <= window // 2)
    # a slip: consecutive edges whose residuals jump by half a half-bit or more (an edge the stream counted at
    # the wrong position, which moves every edge after it). Only the centre's side of a slip is fitted.
    jump = (np.abs(np.diff(y, axis=1)) > 0.5 * h) & valid[:, 1:] & valid[:, :-1]
    if jump.any():
        side = np.concatenate([np.zeros((len(y), 1), np.int64), np.cumsum(jump, axis=1)], axis=1)
        centre_col = np.argmin(np.where(valid, np.abs(dp), np.iinfo(np.int64).max), axis=1)
        valid &= side == side[np.arange(len(y)), centre_col][:, None]
    w = valid.astype(np.float32)
    coef = _solve(x, x2, y, w, ridge)
    res = y - _poly(coef, x, x2)
    for k in (3.0, 3.5):  # trim outliers twice; only rows that change are solved again
        rms = np.sqrt((w * res * res).sum(axis=1) / np.maximum(w.sum(axis=1), 1.0))
        w_new = (valid & (np.abs(res) <= np.maximum(k * rms, 1e-6)[:, None])).astype(np.float32)
        rows = np.flatnonzero((w_new != w).any(axis=1))
        w = w_new
        if rows.size:
            coef[rows] = _solve(x[rows], x2[rows], y[rows], w[rows], ridge[rows])
            res[rows] = y[rows] - _poly(coef[rows], x[rows], x2[rows])
    n = w.sum(axis=1)
    rms = np.sqrt((w * res * res).sum(axis=1) / np.maximum(n - 3, 1.0))
    xo = (po - p0) / float(window)
    few = n < 8  # too few edges for a fit: the reference edge and the nominal clock
    centre = np.where(few, t0, t0 + coef[:, 0])
    other = t0 + h * (po - p0) + np.where(few, 0.0, coef[:, 0] + coef[:, 1] * xo + coef[:, 2] * xo * xo)
    return centre, other, np.where(few, np.nan, rms)


def _poly(coef, x, x2):
    c = coef.astype(np.float32)
    return c[:, 0:1] + c[:, 1:2] * x + c[:, 2:3] * x2


def _solve(x, x2, y, w, ridge):
    wx, wx2 = w * x, w * x2
    s = np.stack([w.sum(1), wx.sum(1), wx2.sum(1), (wx2 * x).sum(1), (wx2 * x2).sum(1),
                  (w * y).sum(1), (wx * y).sum(1), (wx2 * y).sum(1)], axis=1).astype(np.float64)
    m = s[:, [[0, 1, 2], [1, 2, 3], [2, 3, 4]]]
    m[:, 2, 2] += ridge
    m[:, [0, 1, 2], [0, 1, 2]] += 1e-9  # keeps empty or one-edge windows solvable (their result is unused)
    return np.linalg.solve(m, s[:, 5:8, None])[:, :, 0]
