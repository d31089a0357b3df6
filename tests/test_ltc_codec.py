"""LTC codec: exact rates, labels <-> frame counts (drop frame across hours and midnight), 80-bit frames."""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from timecode.frame import (REVERSE_SYNC_BITS, SYNC_BITS, FrameBitsError, LTCFrame, bits_to_frame, frame_to_bits,
                            pack_bits, polarity_bit, unpack_bits)
from timecode.labels import (LabelError, Timecode, frames_to_label, frames_to_labels, label_to_frames,
                             labels_to_frames, labels_valid)
from timecode.rates import (RATE_23_976, RATE_24, RATE_25, RATE_29_97, RATE_29_97_DF, RATE_30, RATES, RateError,
                            parse_rate, rate_from)

from . import libltc_ctypes

DF = RATE_29_97_DF


def test_rates_are_exact_fractions():
    assert RATE_29_97_DF.fps == Fraction(30000, 1001) and RATE_29_97_DF.drop_frame
    assert RATE_23_976.fps == Fraction(24000, 1001) and RATE_23_976.nominal_fps == 24
    assert RATE_25.is_25_layout and not RATE_24.is_25_layout and not RATE_30.is_25_layout
    assert RATE_29_97.samples_per_frame(48000) == pytest.approx(1601.6, abs=1e-12)
    assert RATE_23_976.samples_per_frame(48000) == pytest.approx(2002.0, abs=1e-12)
    assert parse_rate("29.97DF") is RATE_29_97_DF and parse_rate("30000/1001") is RATE_29_97
    assert rate_from(Fraction(30000, 1001), drop_frame=True) is RATE_29_97_DF
    assert rate_from(25.0) is RATE_25
    with pytest.raises(RateError, match="not supported"):
        parse_rate("31")
    with pytest.raises(RateError):
        rate_from(Fraction(25), drop_frame=True)


@pytest.mark.parametrize("rate", list(RATES.values()), ids=list(RATES))
def test_every_label_of_a_day_round_trips(rate):
    counts = np.arange(rate.frames_per_day)
    hmsf = frames_to_labels(counts, rate)
    assert labels_valid(hmsf, rate).all()
    assert np.array_equal(labels_to_frames(hmsf, rate), counts)
    # labels increase strictly, and the day ends at 23:59:59:last
    key = ((hmsf[:, 0] * 60 + hmsf[:, 1]) * 60 + hmsf[:, 2]) * 100 + hmsf[:, 3]
    assert np.all(np.diff(key) > 0)
    assert hmsf[-1].tolist() == [23, 59, 59, rate.nominal_fps - 1]


def test_drop_frame_skips_00_and_01_except_every_tenth_minute():
    assert DF.frames_per_day == 2589408
    assert label_to_frames("00:01:00;02", DF) == 1800
    assert str(frames_to_label(1799, DF)) == "00:00:59;29"
    assert str(frames_to_label(1800, DF)) == "00:01:00;02"
    assert str(frames_to_label(17982, DF)) == "00:10:00;00"  # tenth minute keeps 00 and 01
    assert str(frames_to_label(17983, DF)) == "00:10:00;01"
    assert label_to_frames("01:00:00;00", DF) == 107892  # across the hour: minute 00 keeps its labels
    assert str(frames_to_label(107891, DF)) == "00:59:59;29"
    assert str(frames_to_label(107892 + 1800, DF)) == "01:01:00;02"
    assert label_to_frames("10:00:00;00", DF) == 10 * 107892
    for bad in ("00:01:00;00", "00:01:00;01", "13:59:00;01"):
        with pytest.raises(LabelError, match="dropped"):
            label_to_frames(bad, DF)
    assert label_to_frames("00:01:00:00", RATE_29_97) == 1800  # non-drop keeps every label


def test_midnight_wrap_and_negative_counts():
    last = DF.frames_per_day - 1
    assert str(frames_to_label(last, DF)) == "23:59:59;29"
    assert str(frames_to_label(last + 1, DF)) == "00:00:00;00"
    assert str(frames_to_label(-1, RATE_25)) == "23:59:59:24"
    assert frames_to_labels([RATE_30.frames_per_day + 5], RATE_30)[0].tolist() == [0, 0, 0, 5]


def test_label_parsing_and_validation():
    tc = Timecode.parse("01:02:03;04")
    assert tc == Timecode(1, 2, 3, 4, True) and str(tc) == "01:02:03;04"
    assert str(Timecode.parse("1:02:03:04")) == "01:02:03:04"
    with pytest.raises(LabelError, match="HH:MM:SS:FF"):
        Timecode.parse("1:2:3")
    with pytest.raises(LabelError, match="frame 25 outside 0-24"):
        label_to_frames("00:00:00:25", RATE_25)
    with pytest.raises(LabelError, match="hours 24"):
        label_to_frames("24:00:00:00", RATE_30)
    assert label_to_frames("00:00:01:00", RATE_23_976) == 24  # 23.976 counts labels like 24


def _hand_frame_25() -> np.ndarray:
    """01:23:45:17 at 25 fps, user bits 0x87654321, assembled bit by bit from the SMPTE 12M table."""
    b = np.zeros(80, np.uint8)

    def put(start: int, value: int, width: int) -> None:
        for i in range(width):
            b[start + i] = (value >> i) & 1

    put(0, 7, 4); put(8, 1, 2)  # frames 17
    put(16, 5, 4); put(24, 4, 3)  # seconds 45
    put(32, 3, 4); put(40, 2, 3)  # minutes 23
    put(48, 1, 4); put(56, 0, 2)  # hours 01
    for g, start in enumerate((4, 12, 20, 28, 36, 44, 52, 60)):
        put(start, g + 1, 4)  # user group g+1 holds nibble g of 0x87654321
    b[64:] = [0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 1]
    b[59] = (80 - b.sum()) % 2  # 25 fps: polarity bit 59 makes the zeros even
    return b


def test_frame_bits_match_a_hand_assembled_word():
    frame = LTCFrame(label=Timecode(1, 23, 45, 17), user_bits=0x87654321)
    bits = frame_to_bits(frame, RATE_25)
    assert np.array_equal(bits, _hand_frame_25())
    back, parity_ok = bits_to_frame(bits, RATE_25)
    assert back == frame and parity_ok


@pytest.mark.parametrize("rate", [RATE_24, RATE_25, RATE_29_97_DF, RATE_30], ids=str)
def test_polarity_bit_position_and_flags(rate):
    frame = LTCFrame(label=Timecode(23, 59, 59, 3, rate.drop_frame), user_bits=0xDEADBEEF,
                     drop_frame=rate.drop_frame, color_frame=True, bgf0=True, bgf1=False, bgf2=True)
    bits = frame_to_bits(frame, rate)
    assert (80 - int(bits.sum())) % 2 == 0  # even number of zeros
    p = polarity_bit(rate.is_25_layout)
    assert p == (59 if rate.nominal_fps == 25 else 27)
    flipped = bits.copy()
    flipped[p] ^= 1
    assert not unpack_bits(flipped).parity_ok[0]
    back, ok = bits_to_frame(bits, rate)
    assert ok and back == frame
    assert np.array_equal(bits[64:], SYNC_BITS) and np.array_equal(REVERSE_SYNC_BITS, SYNC_BITS[::-1])


def test_bad_bits_raise_one_line_errors():
    bits = frame_to_bits(LTCFrame(label=Timecode(0, 0, 0, 0)), RATE_30)
    bad_sync = bits.copy()
    bad_sync[70] = 0
    with pytest.raises(FrameBitsError, match="sync word"):
        bits_to_frame(bad_sync, RATE_30)
    bad_bcd = bits.copy()
    bad_bcd[16:20] = [1, 1, 1, 1]  # seconds units 15
    with pytest.raises(FrameBitsError, match="BCD"):
        bits_to_frame(bad_bcd, RATE_30)
    with pytest.raises(FrameBitsError, match="80 bits"):
        bits_to_frame(bits[:79], RATE_30)


@pytest.mark.parametrize("standard,is25,df", [(libltc_ctypes.TV_625_50, True, False),
                                              (libltc_ctypes.TV_525_60, False, True),
                                              (libltc_ctypes.TV_FILM_24, False, False)])
def test_bits_match_libltc_packing(standard, is25, df):
    libltc_ctypes.require()
    rng = np.random.default_rng(4)
    for _ in range(50):
        label = (int(rng.integers(24)), int(rng.integers(60)), int(rng.integers(60)), int(rng.integers(2, 24)))
        ub = int(rng.integers(0, 2**32))
        ours = pack_bits([label], is_25_layout=is25, user_bits=ub, drop_frame=df)[0]
        theirs = libltc_ctypes.pack(label, standard=standard, drop_frame=df, user_bits=ub)
        assert np.array_equal(ours, theirs), (label, hex(ub))
