"""Timecode labels (HH:MM:SS:FF) and exact conversion to and from frame counts since midnight.

Drop-frame (29.97 DF) labels skip frame numbers 00 and 01 at the start of every minute except
minutes 00, 10, 20, 30, 40 and 50, so that the label clock keeps up with real time. Frame counts are
integers counted from 00:00:00:00 of the same day; labels wrap at midnight (count modulo
``rate.frames_per_day``).

Example:
    >>> from timecode.rates import RATE_29_97_DF
    >>> label_to_frames(Timecode.parse("00:01:00;02"), RATE_29_97_DF)
    1800
    >>> str(frames_to_label(1800, RATE_29_97_DF))
    '00:01:00;02'
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from timecode.errors import TimecodeError
from timecode.rates import FrameRate

# Drop-frame arithmetic (29.97 DF): 2 labels dropped in 9 of every 10 minutes.
_DF_PER_MIN = 60 * 30 - 2  # 1798 frames in a minute that drops
_DF_PER_10MIN = 10 * 60 * 30 - 9 * 2  # 17982 frames per ten minutes

_LABEL_RE = re.compile(r"^\s*(\d{1,2})[:.](\d{2})[:.](\d{2})([:;.,])(\d{2})\s*$")


class LabelError(TimecodeError, ValueError):
    """A timecode label that is malformed or does not exist at the given rate."""


@dataclass(frozen=True, order=True)
class Timecode:
    """A timecode label: hours 0-23, minutes 0-59, seconds 0-59, frames 0..nominal_fps-1.

    ``drop_frame`` only changes how the label prints (``;`` before the frames, the usual DF notation).
    """

    hours: int
    minutes: int
    seconds: int
    frames: int
    drop_frame: bool = False

    @classmethod
    def parse(cls, text: str, drop_frame: bool | None = None) -> Timecode:
        """Parse ``HH:MM:SS:FF`` (or ``HH:MM:SS;FF`` which also means drop frame)."""
        m = _LABEL_RE.match(text)
        if not m:
            raise LabelError(f"timecode label {text!r} is not of the form HH:MM:SS:FF")
        h, mi, s, sep, f = m.groups()
        df = (sep in ";,") if drop_frame is None else drop_frame
        return cls(int(h), int(mi), int(s), int(f), df)

    def __str__(self) -> str:
        sep = ";" if self.drop_frame else ":"
        return f"{self.hours:02d}:{self.minutes:02d}:{self.seconds:02d}{sep}{self.frames:02d}"

    def as_tuple(self) -> tuple[int, int, int, int]:
        return (self.hours, self.minutes, self.seconds, self.frames)


def label_problem(hours: int, minutes: int, seconds: int, frames: int, rate: FrameRate) -> str | None:
    """Why a label does not exist at ``rate`` (one line), or None if it is valid."""
    if not 0 <= hours <= 23:
        return f"hours {hours} outside 0-23"
    if not 0 <= minutes <= 59:
        return f"minutes {minutes} outside 0-59"
    if not 0 <= seconds <= 59:
        return f"seconds {seconds} outside 0-59"
    if not 0 <= frames < rate.nominal_fps:
        return f"frame {frames} outside 0-{rate.nominal_fps - 1} at {rate} fps"
    if rate.drop_frame and seconds == 0 and frames < 2 and minutes % 10 != 0:
        return f"frame {frames} at second 00 of minute {minutes:02d} is dropped in drop-frame timecode"
    return None


def label_to_frames(label: Timecode | str, rate: FrameRate) -> int:
    """Frame count since 00:00:00:00 of ``label`` at ``rate``; raises LabelError for labels that do not exist."""
    tc = Timecode.parse(label) if isinstance(label, str) else label
    problem = label_problem(*tc.as_tuple(), rate)
    if problem:
        raise LabelError(f"timecode {tc}: {problem}")
    return int(labels_to_frames(np.array([tc.as_tuple()]), rate)[0])


def frames_to_label(count: int, rate: FrameRate) -> Timecode:
    """The label of frame ``count`` (since 00:00:00:00; wraps at midnight, negative counts wrap back)."""
    h, m, s, f = (int(v) for v in frames_to_labels(np.array([count]), rate)[0])
    return Timecode(h, m, s, f, rate.drop_frame)


def labels_to_frames(hmsf: npt.ArrayLike, rate: FrameRate) -> npt.NDArray[np.int64]:
    """Vectorised label -> frame count. ``hmsf``: (N, 4) hours, minutes, seconds, frames. No validation."""
    a = np.asarray(hmsf, dtype=np.int64).reshape(-1, 4)
    h, m, s, f = a.T
    n = ((h * 60 + m) * 60 + s) * rate.nominal_fps + f
    if rate.drop_frame:
        total_min = h * 60 + m
        n = n - 2 * (total_min - total_min // 10)
    return n


def frames_to_labels(counts: npt.ArrayLike, rate: FrameRate) -> npt.NDArray[np.int64]:
    """Vectorised frame count -> label as (N, 4) hours, minutes, seconds, frames (wrapping at midnight)."""
    n = np.mod(np.asarray(counts, dtype=np.int64).ravel(), rate.frames_per_day)
    if rate.drop_frame:
        tens, rem = np.divmod(n, _DF_PER_10MIN)
        # in each ten-minute block, minute 0 has 1800 labels and minutes 1-9 have 1798 each
        extra = np.where(rem < 2, 0, 2 * ((rem - 2) // _DF_PER_MIN))
        n = n + 18 * tens + extra
    fps = rate.nominal_fps
    secs, f = np.divmod(n, fps)
    mins, s = np.divmod(secs, 60)
    h, m = np.divmod(mins, 60)
    return np.stack([h, m, s, f], axis=1)


def labels_valid(hmsf: npt.ArrayLike, rate: FrameRate) -> npt.NDArray[np.bool_]:
    """Vectorised ``label_problem(...) is None`` for (N, 4) labels."""
    a = np.asarray(hmsf, dtype=np.int64).reshape(-1, 4)
    h, m, s, f = a.T
    ok = (h >= 0) & (h <= 23) & (m >= 0) & (m <= 59) & (s >= 0) & (s <= 59) & (f >= 0) & (f < rate.nominal_fps)
    if rate.drop_frame:
        ok &= ~((s == 0) & (f < 2) & (m % 10 != 0))
    return ok


def format_labels(hmsf: npt.ArrayLike, drop_frame: bool | npt.ArrayLike = False) -> list[str]:
    """Labels as ``HH:MM:SS:FF`` strings (``;`` before the frames where ``drop_frame``)."""
    a = np.asarray(hmsf, dtype=np.int64).reshape(-1, 4)
    df = np.broadcast_to(np.asarray(drop_frame, dtype=bool), (len(a),))
    return [f"{h:02d}:{m:02d}:{s:02d}{';' if d else ':'}{f:02d}" for (h, m, s, f), d in zip(a.tolist(), df.tolist())]
