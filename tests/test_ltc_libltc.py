"""Cross-check with libltc at every rate: we decode libltc's encoder output, libltc decodes ours.

Needs Debian's libltc11 (``make test`` installs it); without it these tests skip, or fail when CI is set.
"""
from __future__ import annotations

import numpy as np
import pytest

from timecode.decode.decoder import decode_samples
from timecode.encoder import EncoderOptions, encode_ltc, label_range
from timecode.rates import RATES
from timecode.decode.result import EXTRAPOLATED, Extrapolated

from . import libltc_ctypes as L

STANDARD = {"23.976": L.TV_FILM_24, "24": L.TV_FILM_24, "25": L.TV_625_50, "29.97df": L.TV_525_60,
            "29.97": L.TV_525_60, "30": L.TV_525_60}
START = (23, 59, 58, 0)


@pytest.fixture(scope="module", autouse=True)
def _libltc():
    L.require()


@pytest.mark.parametrize("fs", [48000, 44100, 16000])
@pytest.mark.parametrize("name", list(RATES))
def test_we_decode_libltc(name, fs):
    rate = RATES[name]
    audio = L.encode(START, 60, sample_rate=fs, fps=float(rate.fps), standard=STANDARD[name],
                     drop_frame=rate.drop_frame, user_bits=0x13579BDF)
    audio = np.concatenate([np.full(64, 128, np.uint8), audio])  # the generator switches on after silence
    (ch,) = decode_samples(audio, fs)
    expect = label_range("23:59:58:00", 60, rate)
    # libltc's stream ends with the last bit of the last frame: that frame has no closing edge, whose time the
    # bit clock extrapolates
    assert ch.rate is rate and len(ch) == 60
    assert np.array_equal(ch.labels, expect) and np.all(ch.user_bits == 0x13579BDF)
    assert np.all(ch.drop_frame == rate.drop_frame)
    assert [EXTRAPOLATED[e] for e in ch.extrapolated[-2:]] == [Extrapolated.NONE, Extrapolated.END]
    # libltc's encoder places each level change on a whole sample; bit 0 of frame j starts at
    # 64 + round-ish(j * samples per frame), so our sub-sample start is within a sample of that
    nominal = 64 + np.arange(61) * rate.samples_per_frame(fs)
    assert np.max(np.abs(ch.start_samples - nominal[:60])) < 1.5
    assert abs(ch.end_samples[-1] - nominal[60]) < 1.5


@pytest.mark.parametrize("fs", [48000, 44100, 16000])
@pytest.mark.parametrize("name", list(RATES))
def test_libltc_decodes_us(name, fs):
    rate = RATES[name]
    enc = encode_ltc("23:59:58:00", 60, fps=rate, sample_rate=fs, user_bits=0x2468ACE0,
                     options=EncoderOptions(level_dbfs=-3.0))
    got = L.decode(enc.samples, fs, float(rate.fps))
    assert len(got.labels) >= 59  # libltc needs one frame to settle only when the first edge is unclear
    assert np.array_equal(got.labels, enc.labels[:len(got.labels)])
    assert np.all(got.user_bits == 0x2468ACE0) and np.all(got.dfbit == rate.drop_frame)
    # libltc's off_start is a whole sample near the edge (where its detector fired on the bit before);
    # it is off our exact edge by up to a few samples, alternately early and late when frames are not a
    # whole number of samples long
    lag = got.off_start[1:] - enc.frame_start_samples[1:len(got.labels)]
    assert np.all(np.abs(lag) < 3.5), lag


def test_libltc_reads_our_reverse_play_as_reverse():
    fs = 48000
    enc = encode_ltc("01:00:00:00", 30, fps=RATES["25"], sample_rate=fs, options=EncoderOptions(reverse=True))
    got = L.decode(enc.samples, fs, 25.0)
    assert len(got.labels) >= 28 and np.all(got.reverse)
    assert np.array_equal(got.labels, enc.labels[::-1][1:len(got.labels) + 1]) or \
        np.array_equal(got.labels, enc.labels[::-1][:len(got.labels)])


def test_a_stream_cut_at_both_ends_keeps_its_first_and_last_frame():
    """libltc's stream with no lead-in and no closing edge: the first frame's opening edge is at sample 0 (not
    seen), the last frame's closing edge after the last sample. Every frame has its sync word in the file:
    all of them (libltc gives all but one; before issue 16 we gave all but two)."""
    audio = L.encode((10, 0, 0, 0), 100, sample_rate=48000, fps=25.0, standard=L.TV_625_50)
    (ch,) = decode_samples(audio, 48000)
    assert len(ch) == 100 and np.array_equal(ch.labels, label_range("10:00:00:00", 100, RATES["25"]))
    assert [EXTRAPOLATED[e] for e in ch.extrapolated[[0, -1]]] == [Extrapolated.START, Extrapolated.END]
    assert len(L.decode(audio, 48000, 25.0).labels) == 99
