"""Frame-rate detection and label continuity of decoded frames.

Rate: the label rate (24, 25 or 30 frames per labelled second) comes from the frame number at which labels
wrap to the next second (or the largest frame number seen); drop frame from the DF flag; 1000/1001 or
integer from the measured frame period (0.1 % apart, far more than any generator's clock error).

Continuity: a frame continues the previous one when its label equals the previous label plus the number
of frame periods elapsed between them (in the play direction), so frames lost to noise are not jumps but
a re-jammed generator or an edit is, and is reported as a discontinuity, never bridged. A frame whose
label continues neither neighbour, next to a continuous stretch, is dropped as corrupted (bit errors that
still form a valid label, or a frame read across an audio splice), so a jump costs no frame but a
one-frame excursion is not reported.
"""
from __future__ import annotations

import logging

import numpy as np
import numpy.typing as npt

from timecode.labels import labels_to_frames
from timecode.rates import RATES, FrameRate

logger = logging.getLogger(__name__)


def mean_period(start_samples: npt.NDArray[np.float64], period_samples: npt.NDArray[np.float64],
                contiguous_next: npt.NDArray[np.bool_], span: int = 50) -> float:
    """Frame period from the slope of start times over chains of contiguous frames (median over chains
    of ``span`` frames), which averages out edge jitter; the median single-frame period if no chain."""
    m = min(span, len(start_samples) - 1)
    if m >= 4:
        gap = np.concatenate([[0], np.cumsum(~contiguous_next[:-1])])
        k = np.flatnonzero(gap[m:] == gap[:-m])
        if k.size:
            return float(np.median(np.abs(start_samples[k + m] - start_samples[k]) / m))
    return float(np.median(period_samples))


def detect_rate(hmsf: npt.NDArray[np.int64], dfbit: npt.NDArray[np.bool_], period_samples: npt.NDArray[np.float64],
                contiguous_next: npt.NDArray[np.bool_], sample_rate: float,
                start_samples: npt.NDArray[np.float64] | None = None) -> FrameRate:
    """The supported rate that best explains the labels and the measured frame period.

    Args:
        hmsf: (F, 4) labels in time order.
        dfbit: (F,) drop-frame flag bits.
        period_samples: (F,) measured frame durations.
        contiguous_next: (F,) frame k+1 starts where frame k ends (same play direction).
        sample_rate: samples per second.
        start_samples: (F,) frame start times (for a jitter-free period over chains of frames).
    """
    period = (mean_period(start_samples, period_samples, contiguous_next) if start_samples is not None
              else float(np.median(period_samples)))
    fps_meas = sample_rate / period
    drop = bool(np.mean(dfbit) > 0.5)
    nominal: int | None = None
    k = np.flatnonzero(contiguous_next[:-1])
    wraps = k[(hmsf[k + 1, 3] == 0) & (hmsf[k, 3] > 0) & (hmsf[k + 1, 2] != hmsf[k, 2])]
    if wraps.size:
        votes = np.bincount(hmsf[wraps, 3] + 1)
        nominal = int(np.argmax(votes))
    elif len(hmsf):
        top = int(np.max(hmsf[:, 3])) + 1
        nominal = 30 if top > 25 else (25 if top == 25 else None)
    candidates = [r for r in RATES.values() if r.drop_frame == drop and (nominal is None or r.nominal_fps == nominal)]
    if not candidates:
        candidates = [r for r in RATES.values() if r.drop_frame == drop] or list(RATES.values())
    best = min(candidates, key=lambda r: abs(float(r.fps) - fps_meas))
    if abs(float(best.fps) / fps_meas - 1) > 0.02:
        logger.info("frame period %.2f samples is %.1f %% off %s fps (speed change or varispeed)",
                    period, 100 * (fps_meas / float(best.fps) - 1), best)
    return best


def continuity(counts: npt.NDArray[np.int64], reverse: npt.NDArray[np.bool_], mid_samples: npt.NDArray[np.float64],
               period_samples: npt.NDArray[np.float64], frames_per_day: int) -> tuple[npt.NDArray[np.bool_],
                                                                                      npt.NDArray[np.bool_]]:
    """(keep, discontinuity) for frames in time order.

    Args:
        counts: (F,) frame numbers since midnight of each label.
        reverse: (F,) reverse play.
        mid_samples: (F,) time of the middle of each frame.
        period_samples: (F,) frame durations.
        frames_per_day: label wrap.
    """
    f = len(counts)
    keep = np.ones(f, dtype=bool)
    if f == 0:
        return keep, np.zeros(0, bool)

    def follows(a: npt.NDArray[np.int64], b: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
        """Frame b continues frame a (a earlier in time)."""
        same_dir = reverse[a] == reverse[b]
        step = np.rint((mid_samples[b] - mid_samples[a]) / period_samples[a]).astype(np.int64)
        sign = np.where(reverse[a], -1, 1)
        expect = np.mod(counts[a] + sign * step, frames_per_day)
        return same_dir & (step >= 1) & (expect == counts[b])

    idx = np.arange(f)
    if f >= 2:
        # a frame whose label continues neither neighbour is corrupted: bit errors that still form a valid
        # label, or a frame read across an audio splice (its first bits from one take, the rest from the
        # next). Its neighbours are then compared with each other.
        # (Only next to a continuous stretch: where no label follows another the whole stream is chaos,
        # and every frame is kept and reported as a discontinuity.)
        cont = np.concatenate([[False, False], follows(idx[:-1], idx[1:]), [False, False]])  # [i+2]: i -> i+1
        alone = ~cont[1:f + 1] & ~cont[2:f + 2]  # k continues neither k-1 nor into k+1
        beside_good = cont[0:f] | cont[3:f + 3]  # k-1 continues k-2, or k+1 continues into k+2
        keep = ~(alone & beside_good)
        if not keep.all():
            logger.info("dropped %d frame(s) whose labels continue neither neighbour", int((~keep).sum()))
    kept = np.flatnonzero(keep)
    disc = np.ones(len(kept), dtype=bool)
    if len(kept) > 1:
        disc[1:] = ~follows(kept[:-1], kept[1:])
    out = np.zeros(f, bool)
    out[kept] = disc
    return keep, out


def frame_counts(hmsf: npt.NDArray[np.int64], rate: FrameRate) -> npt.NDArray[np.int64]:
    """Frame numbers since midnight (no validation; see ``labels.labels_valid``)."""
    return labels_to_frames(hmsf, rate)
