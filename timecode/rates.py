"""LTC frame rates as exact fractions, with the drop-frame flag and the bit layout that goes with them.

Example:
    >>> rate = parse_rate("29.97df")
    >>> rate.fps, rate.nominal_fps, rate.drop_frame
    (Fraction(30000, 1001), 30, True)
"""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

from timecode.errors import TimecodeError


class RateError(TimecodeError, ValueError):
    """A frame rate name or value that this toolkit does not support."""


@dataclass(frozen=True, kw_only=True)
class FrameRate:
    """An LTC frame rate: exact frames per second and whether labels drop frames (29.97 DF only).

    ``nominal_fps`` is the label rate (frame numbers run 0..nominal_fps-1); ``fps`` the true rate,
    e.g. 23.976 fps labels count 0..23 like 24 fps but frames last 1001/24000 s.
    """

    name: str
    fps: Fraction
    drop_frame: bool = False

    @property
    def nominal_fps(self) -> int:
        """Frames per labelled second: 24, 25 or 30."""
        return int(-(-self.fps.numerator // self.fps.denominator))

    @property
    def is_25_layout(self) -> bool:
        """True for 25 fps, whose binary-group-flag and polarity bits sit at other positions (SMPTE 12M)."""
        return self.nominal_fps == 25

    @property
    def frames_per_day(self) -> int:
        """Labels in 24 hours (00:00:00:00 .. 23:59:59:ff), counting drop-frame skips."""
        per_day = 24 * 3600 * self.nominal_fps
        return per_day - (2 * (24 * 60 - 24 * 6) if self.drop_frame else 0)

    @property
    def frame_duration_s(self) -> Fraction:
        """Exact duration of one frame in seconds."""
        return 1 / self.fps

    def samples_per_frame(self, sample_rate: float) -> float:
        """Audio samples per frame at ``sample_rate`` (float; exact rational values are rarely integers)."""
        return float(sample_rate) * self.fps.denominator / self.fps.numerator

    def __str__(self) -> str:
        return self.name


RATE_23_976 = FrameRate(name="23.976", fps=Fraction(24000, 1001))
RATE_24 = FrameRate(name="24", fps=Fraction(24))
RATE_25 = FrameRate(name="25", fps=Fraction(25))
RATE_29_97_DF = FrameRate(name="29.97df", fps=Fraction(30000, 1001), drop_frame=True)
RATE_29_97 = FrameRate(name="29.97", fps=Fraction(30000, 1001))
RATE_30 = FrameRate(name="30", fps=Fraction(30))

#: Every supported rate by its name (as accepted by ``--fps``).
RATES: dict[str, FrameRate] = {r.name: r for r in (RATE_23_976, RATE_24, RATE_25, RATE_29_97_DF, RATE_29_97, RATE_30)}

_ALIASES = {
    "23.98": "23.976", "24000/1001": "23.976", "29.97ndf": "29.97", "30000/1001": "29.97",
    "29.97-df": "29.97df", "29.97_df": "29.97df", "2997df": "29.97df", "30df": "29.97df",
}


def parse_rate(text: str) -> FrameRate:
    """A rate from its name: ``23.976``, ``24``, ``25``, ``29.97df`` (drop frame), ``29.97``, ``30``."""
    key = text.strip().lower()
    key = _ALIASES.get(key, key)
    if key.endswith(".0"):
        key = key[:-2]
    if key not in RATES:
        raise RateError(f"frame rate {text!r} is not supported; use one of {', '.join(RATES)}")
    return RATES[key]


def rate_from(fps: Fraction | float | int | str | FrameRate, drop_frame: bool = False) -> FrameRate:
    """The supported rate for an exact ``fps`` (Fraction, or a float within 1e-4) and drop-frame flag."""
    if isinstance(fps, FrameRate):
        if drop_frame and not fps.drop_frame:
            raise RateError(f"frame rate {fps} has no drop-frame variant")
        return fps
    if isinstance(fps, str):
        rate = parse_rate(fps)
        return rate_from(rate.fps, drop_frame or rate.drop_frame)
    for rate in RATES.values():
        if rate.drop_frame == drop_frame and abs(float(rate.fps) - float(fps)) < 1e-4:
            return rate
    kind = "drop-frame " if drop_frame else ""
    raise RateError(f"{kind}frame rate {fps} fps is not supported; use one of {', '.join(RATES)}")
