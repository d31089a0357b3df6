"""AC-coupling (high-pass droop) estimation and compensation.

A recorder input coupled through a capacitor is a one-pole high-pass: each flat LTC half-bit sags toward
zero, and the sag bends the baseline at every edge, which would bias edge times by the same amount for
every edge. We fit the corner frequency ``fc`` of that high-pass to the decoded square wave (least squares
over a short excerpt) and then replace it by a much lower residual corner (2 Hz): the filter

    G(z) = (k_r / k_c) (1 - p_c z^-1) / (1 - p_r z^-1)

cancels the high-pass pole-zero pair exactly (bilinear one-pole high-pass H(z) = k (1 - z^-1)/(1 - p z^-1)),
so the signal looks as if it had been coupled at 2 Hz. The slow baseline that remains is tracked per stat
block by the edge finder.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

RESIDUAL_HZ = 2.0
MIN_CORNER_HZ = 4.0  # below this the droop is too small to matter


@dataclass(frozen=True, kw_only=True)
class Droop:
    """A fitted AC coupling: ``corner_hz`` of the one-pole high-pass (0 = none found)."""

    corner_hz: float
    sample_rate: float
    residual_hz: float = RESIDUAL_HZ

    @property
    def active(self) -> bool:
        return self.corner_hz >= MIN_CORNER_HZ


def _pole(fc: float, fs: float) -> tuple[float, float]:
    """(p, k) of the bilinear one-pole high-pass at corner ``fc``."""
    w = math.tan(math.pi * fc / fs)
    p = (1.0 - w) / (1.0 + w)
    return p, (1.0 + p) / 2.0


def highpass(x: npt.ArrayLike, fc: float, fs: float) -> npt.NDArray[np.float64]:
    """One-pole high-pass (what an AC-coupled input does), started in steady state for ``x[0]`` = 0 mean."""
    p, k = _pole(fc, fs)
    return lfilter([k, -k], [1.0, -p], np.asarray(x, dtype=np.float64))


def compensate(x: npt.NDArray, droop: Droop) -> npt.NDArray:
    """Undo the fitted high-pass (replace its corner by ``residual_hz``).

    The filter's state before ``x[0]`` is unknown; a wrong guess adds a transient decaying with the
    residual pole. Its amplitude is fitted so that the first ~0.1 s averages to zero (LTC is nearly
    DC-free) and subtracted, so the first frames of a block are as good as the rest.
    """
    pc, kc = _pole(droop.corner_hz, droop.sample_rate)
    pr, kr = _pole(droop.residual_hz, droop.sample_rate)
    b = np.array([1.0, -pc]) * (kr / kc)
    a = np.array([1.0, -pr])
    y, _ = lfilter(b.astype(x.dtype), a.astype(x.dtype), x, zi=np.zeros(1, x.dtype))
    m = min(len(y), int(0.1 * droop.sample_rate))
    if m > 10:
        n = min(len(y), int(np.log(1e-9) / np.log(pr)) + 1)
        decay = pr ** np.arange(n, dtype=np.float64)
        e0 = float(np.mean(y[:m])) / float(np.mean(decay[:m]))
        y[:n] -= (e0 * decay).astype(y.dtype)
    return y


def estimate_droop(x: npt.NDArray, crossings: npt.NDArray[np.int64], sq: npt.NDArray[np.int8],
                   fs: float, guard_samples: float) -> Droop:
    """Fit the high-pass corner to ``x`` ~ a + A * highpass(sq) on samples away from edges.

    Args:
        x: clipped (not smoothed) excerpt of one channel, >= ~0.5 s.
        crossings: coarse edge indices in the excerpt.
        sq: the ideal +-1 square wave of the excerpt.
        fs: sample rate.
        guard_samples: samples on each side of an edge left out of the fit.
    """
    n = len(x)
    skip = min(n // 3, int(0.25 * fs))
    mask = np.ones(n, dtype=bool)
    g = int(math.ceil(guard_samples))
    for d in range(-g, g + 2):
        idx = crossings + d
        mask[idx[(idx >= 0) & (idx < n)]] = False
    mask[:skip] = False
    if mask.sum() < 1000:
        return Droop(corner_hz=0.0, sample_rate=fs)
    y = np.asarray(x, dtype=np.float64)[mask]
    sqf = sq.astype(np.float64)

    def rss(fc: float) -> float:
        u = (highpass(sqf, fc, fs) if fc > 0 else sqf)[mask]
        design = np.stack([np.ones_like(u), u], axis=1)
        coef, res, *_ = np.linalg.lstsq(design, y, rcond=None)
        return float(res[0]) if res.size else float(np.sum((y - design @ coef) ** 2))

    grid = np.geomspace(1.0, min(2000.0, fs / 20), 28)
    scores = np.array([rss(fc) for fc in grid])
    none = rss(0.0)
    i = int(np.argmin(scores))
    best_fc = float(grid[i])
    if 0 < i < len(grid) - 1:  # parabola in log(fc)
        s0, s1, s2 = scores[i - 1:i + 2]
        den = s0 - 2 * s1 + s2
        if den > 0:
            step = 0.5 * (s0 - s2) / den
            best_fc = float(np.exp(np.log(grid[i]) + step * (np.log(grid[1]) - np.log(grid[0]))))
    if scores[i] > 0.9 * none:
        return Droop(corner_hz=0.0, sample_rate=fs)
    return Droop(corner_hz=best_fc, sample_rate=fs)
