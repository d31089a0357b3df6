"""Frame-rate detection and label continuity of decoded frames.

Rate: the label rate (24, 25 or 30 frames per labelled second) comes from the frame number at which labels
wrap to the next second (without a wrap, from the rates whose labels reach the largest frame number seen, the
frame period choosing); drop frame from the DF flag; 1000/1001 or integer from the measured frame period
(0.1 % apart, far more than any generator's clock error).

Continuity: a frame continues the previous one when its label equals the previous label plus the number
of frame periods elapsed between them (in the play direction), so frames lost to noise are not jumps but
a re-jammed generator or an edit is, and is reported as a discontinuity, never bridged. A frame whose
label continues neither neighbour, next to a continuous stretch, is dropped as corrupted (bit errors that
still form a valid label, or a frame read across an audio splice), so a jump costs no frame but a
one-frame excursion is not reported.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

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


@dataclass(frozen=True, kw_only=True)
class RateEvidence:
    """What decoded frames say about their rate."""

    nominal: int | None  # labels per second, from where they wrap to the next second (None: no wrap seen)
    top_frame: int  # largest frame number seen
    drop_frame: bool  # the DF bit is set in most frames
    fps_measured: float  # frames per second from the frame period
    period_samples: float


def rate_evidence(hmsf: npt.NDArray[np.int64], dfbit: npt.NDArray[np.bool_], period_samples: npt.NDArray[np.float64],
                  contiguous_next: npt.NDArray[np.bool_], sample_rate: float,
                  start_samples: npt.NDArray[np.float64] | None = None) -> RateEvidence:
    """Label wraps, largest frame number, DF majority and measured rate of frames in time order (see
    ``detect_rate`` for the arguments)."""
    period = (mean_period(start_samples, period_samples, contiguous_next) if start_samples is not None
              else float(np.median(period_samples)))
    nominal: int | None = None
    k = np.flatnonzero(contiguous_next[:-1])
    sec = (hmsf[:, 0] * 60 + hmsf[:, 1]) * 60 + hmsf[:, 2]
    step = np.abs(sec[k + 1] - sec[k])
    next_second = (step == 1) | (step == 86399)  # (midnight)
    # a wrap: frame 0 of a second next to the last frame of the one before (either play direction)
    wraps = k[next_second & (hmsf[k + 1, 3] == 0) & (hmsf[k, 3] > 0)]
    rev_wraps = k[next_second & (hmsf[k, 3] == 0) & (hmsf[k + 1, 3] > 0)]
    last = np.concatenate([hmsf[wraps, 3], hmsf[rev_wraps + 1, 3]])  # the last frame of a second
    if last.size:
        nominal = int(np.argmax(np.bincount(last + 1)))
    return RateEvidence(nominal=nominal, top_frame=int(np.max(hmsf[:, 3])) if len(hmsf) else -1,
                        drop_frame=bool(np.mean(dfbit) > 0.5), fps_measured=sample_rate / period,
                        period_samples=period)


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
    ev = rate_evidence(hmsf, dfbit, period_samples, contiguous_next, sample_rate, start_samples)
    # the label rate from a wrap; without one (under a second of LTC), any rate whose labels reach the largest
    # frame number seen, the frame period choosing
    candidates = [r for r in RATES.values() if r.drop_frame == ev.drop_frame
                  and (r.nominal_fps == ev.nominal if ev.nominal is not None else r.nominal_fps > ev.top_frame)]
    if not candidates:
        candidates = [r for r in RATES.values() if r.drop_frame == ev.drop_frame] or list(RATES.values())
    best = min(candidates, key=lambda r: abs(float(r.fps) - ev.fps_measured))
    if abs(float(best.fps) / ev.fps_measured - 1) > 0.02:
        logger.info("frame period %.2f samples is %.1f %% off %s fps (speed change or varispeed)",
                    ev.period_samples, 100 * (ev.fps_measured / float(best.fps) - 1), best)
    return best


#: Without a label wrap to go by, a given rate is refused when the frames come this much faster or slower.
MAX_SPEED_OFF = 0.15


def rate_contradiction(rate: FrameRate, ev: RateEvidence) -> str | None:
    """Why the bit stream contradicts ``rate`` (one line), or None if it is consistent with it.

    Contradictions: the labels wrap at another frame count, or count past the rate's last frame; the
    drop-frame bit disagrees (29.97 DF vs the others); with no wrap seen (under a second of LTC), the frames
    come over ``MAX_SPEED_OFF`` faster or slower than the rate (where labels wrap, speed is not held against a
    rate: varispeed and shuttle are allowed). 29.97 against 30 (and 23.976 against 24) is not decided here:
    0.1 % is as much as a speed change, so that choice is the caller's.
    """
    if ev.nominal is not None and ev.nominal != rate.nominal_fps:
        return (f"its labels count {ev.nominal} frames a second (frame numbers wrap after {ev.nominal - 1}), "
                f"not {rate.nominal_fps}")
    if ev.top_frame >= rate.nominal_fps:
        return f"its labels reach frame {ev.top_frame}, past the last frame {rate.nominal_fps - 1} of {rate} fps"
    if ev.drop_frame != rate.drop_frame:
        return (f"its drop-frame bit is {'set' if ev.drop_frame else 'clear'}, and {rate} fps is "
                f"{'' if rate.drop_frame else 'not '}drop frame")
    off = ev.fps_measured / float(rate.fps) - 1
    if ev.nominal is None and abs(off) > MAX_SPEED_OFF:
        return f"its frames come at {ev.fps_measured:.2f} per second, {100 * off:+.0f} % off {rate} fps"
    return None


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
