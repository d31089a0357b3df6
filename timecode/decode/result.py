"""What the decoder returns: per channel, columns of per-frame values (numpy arrays), and row views.

Time convention: ``start_samples`` is the time of the edge that opens bit 0 of the frame (SMPTE's frame
start), in samples from the first sample of the file (0.0 = the first sample's instant), as a float with
sub-sample precision. ``end_samples`` is the edge closing bit 79 (the next frame's start). In reverse
play a frame's bits arrive 79 first, so its start comes after its end in the file. Where an edge is not in
the audio (``extrapolated``), its time is the bit clock's, extrapolated from the frame's other edges.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from timecode.labels import Timecode, format_labels
from timecode.rates import FrameRate


class Direction(StrEnum):
    FORWARD = "forward"
    REVERSE = "reverse"


class Reading(StrEnum):
    """How a frame's transitions were read from the audio."""

    SQUARE = "square"  # a square wave (the LTC as generated, maybe filtered or AC-coupled)
    IMPULSES = "impulses"  # an impulse train (a differentiating recorder or receiver input)


class Extrapolated(StrEnum):
    """Which edge of a frame is not in the audio (the file, or the LTC, starts or ends inside the frame); its
    time comes from the bit clock of the frame's other edges."""

    NONE = ""
    START = "start"  # the edge opening bit 0
    END = "end"  # the edge closing bit 79
    BOTH = "both"


#: ``ChannelDecode.extrapolated`` codes, in order.
EXTRAPOLATED = (Extrapolated.NONE, Extrapolated.START, Extrapolated.END, Extrapolated.BOTH)


@dataclass(frozen=True, kw_only=True)
class DecodedFrame:
    """One decoded frame (a row of ChannelDecode)."""

    label: Timecode
    frame_number: int  # frames since 00:00:00:00 at the decoded rate
    user_bits: int
    drop_frame: bool
    color_frame: bool
    bgf: tuple[bool, bool, bool]  # binary group flags BGF0, BGF1, BGF2 at this rate's bit positions
    parity_ok: bool
    direction: Direction
    start_samples: float
    end_samples: float
    level_dbfs: float
    jitter_us: float  # RMS of edge times around the fitted local bit clock (quality; nan = too few edges)
    discontinuity: bool  # first frame, or label does not follow the previous frame
    reading: Reading = Reading.SQUARE
    extrapolated: Extrapolated = Extrapolated.NONE
    bits_missing: int = 0  # bits outside the audio (label from the neighbouring frame, checked on the others)


def _empty(dtype: type | str) -> npt.NDArray:
    return np.zeros(0, dtype=dtype)


@dataclass(kw_only=True)
class ChannelDecode:
    """Every frame decoded from one channel, in time order, as columns."""

    channel: int  # 0-based
    sample_rate: int
    rate: FrameRate | None  # None when no frame was found
    labels: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    frame_numbers: npt.NDArray[np.int64] = field(default_factory=lambda: _empty(np.int64))
    user_bits: npt.NDArray[np.uint32] = field(default_factory=lambda: _empty(np.uint32))
    drop_frame: npt.NDArray[np.bool_] = field(default_factory=lambda: _empty(bool))
    color_frame: npt.NDArray[np.bool_] = field(default_factory=lambda: _empty(bool))
    bgf: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros((0, 3), bool))
    parity_ok: npt.NDArray[np.bool_] = field(default_factory=lambda: _empty(bool))
    reverse: npt.NDArray[np.bool_] = field(default_factory=lambda: _empty(bool))
    start_samples: npt.NDArray[np.float64] = field(default_factory=lambda: _empty(np.float64))
    end_samples: npt.NDArray[np.float64] = field(default_factory=lambda: _empty(np.float64))
    level_dbfs: npt.NDArray[np.float64] = field(default_factory=lambda: _empty(np.float64))
    jitter_us: npt.NDArray[np.float64] = field(default_factory=lambda: _empty(np.float64))
    discontinuity: npt.NDArray[np.bool_] = field(default_factory=lambda: _empty(bool))
    impulses: npt.NDArray[np.bool_] = field(default_factory=lambda: _empty(bool))  # read from an impulse train
    extrapolated: npt.NDArray[np.int8] = field(default_factory=lambda: _empty(np.int8))  # EXTRAPOLATED codes
    bits_missing: npt.NDArray[np.int64] = field(default_factory=lambda: _empty(np.int64))
    n_edges: int = 0
    n_rejected: int = 0  # frames with a sync word but impossible labels, or corrupted
    ac_coupling_hz: float = 0.0  # fitted input high-pass corner that was undone (0 = none)
    impulse_tau_samples: float = 0.0  # time constant of the differentiating input of impulse stretches (0: none)
    n_nonfinite: int = 0  # NaN or infinite samples, read as gaps (interpolated over)

    def __len__(self) -> int:
        return len(self.frame_numbers)

    def label_strings(self) -> list[str]:
        return format_labels(self.labels, self.drop_frame)

    def frames(self) -> list[DecodedFrame]:
        """Row view (builds one object per frame; prefer the columns for long recordings)."""
        out = []
        for i in range(len(self)):
            h, m, s, f = (int(v) for v in self.labels[i])
            out.append(DecodedFrame(
                label=Timecode(h, m, s, f, bool(self.drop_frame[i])), frame_number=int(self.frame_numbers[i]),
                user_bits=int(self.user_bits[i]), drop_frame=bool(self.drop_frame[i]),
                color_frame=bool(self.color_frame[i]),
                bgf=(bool(self.bgf[i, 0]), bool(self.bgf[i, 1]), bool(self.bgf[i, 2])),
                parity_ok=bool(self.parity_ok[i]),
                direction=Direction.REVERSE if self.reverse[i] else Direction.FORWARD,
                start_samples=float(self.start_samples[i]), end_samples=float(self.end_samples[i]),
                level_dbfs=float(self.level_dbfs[i]), jitter_us=float(self.jitter_us[i]),
                discontinuity=bool(self.discontinuity[i]),
                reading=Reading.IMPULSES if self.impulses[i] else Reading.SQUARE,
                extrapolated=EXTRAPOLATED[int(self.extrapolated[i])], bits_missing=int(self.bits_missing[i]),
            ))
        return out
