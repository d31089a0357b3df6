"""Frames at the edges of the audio (the file starts or ends inside a frame) against the encoder's exact truth,
8 kHz at every rate, non-finite samples, and a frame rate the bit stream contradicts."""
from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from timecode.decode.decoder import RateMismatchError, decode_samples
from timecode.encoder import EncodedLTC, EncoderOptions, encode_ltc
from timecode.labels import labels_to_frames
from timecode.rates import RATE_24, RATE_25, RATE_29_97_DF, RATE_30, RATES
from timecode.decode.result import EXTRAPOLATED, Extrapolated

FS = 48000


@functools.cache
def _take(rate_name: str, reverse: bool = False, fs: int = FS) -> EncodedLTC:
    rate = RATES[rate_name]
    return encode_ltc("10:00:00;00" if rate.drop_frame else "10:00:00:00", 30, fps=rate, sample_rate=fs,
                      options=EncoderOptions(start_offset_samples=400.3, drift_ppm=37.0, reverse=reverse,
                                             noise_snr_db=30.0))


def _cut(enc: EncodedLTC, a: int, b: int):
    """Samples a..b-1, and the truth in them: frame numbers, starts and ends (samples from a), and the bit length."""
    s, e = enc.frame_start_samples - a, enc.frame_end_samples - a
    return enc.samples[a:b], labels_to_frames(enc.labels, enc.rate), s, e, np.abs(e - s) / 80


def _check(ch, counts, s, e, bit, n, reverse):
    """Every frame whose sync word is in the file (3 samples of margin: a transition needs samples around it)
    is decoded, nothing else is, each at its true place; the flags say which edge lies outside the audio."""
    first_t = np.minimum(s, e)  # the frame's first edge in time
    # the sync word's first and last edge in time: forward, bit 64's opening edge and bit 79's mid-bit edge (a 1,
    # whose closing edge is the next frame's); reverse, bit 79's mid-bit edge and bit 64's opening one (a 0)
    sync_lo = np.where(reverse, first_t + bit / 2, e - 16 * bit)
    sync_hi = np.where(reverse, first_t + 16 * bit, e - bit / 2)
    must = (sync_lo >= 3) & (sync_hi <= n - 4)
    may = (sync_lo >= -1) & (sync_hi <= n)
    got = dict(zip(ch.frame_numbers.tolist(), range(len(ch))))
    assert set(counts[must].tolist()) <= set(got), "a frame with its sync word in the file is missing"
    assert set(got) <= set(counts[may].tolist()), "a frame without its sync word in the file was reported"
    for j, c in enumerate(counts.tolist()):
        if c not in got:
            continue
        i = got[c]
        flag = EXTRAPOLATED[ch.extrapolated[i]]
        start_out, end_out = not 0 <= s[j] <= n - 1, not 0 <= e[j] <= n - 1
        assert (flag in (Extrapolated.START, Extrapolated.BOTH)) >= start_out  # an edge outside is flagged
        assert (flag in (Extrapolated.END, Extrapolated.BOTH)) >= end_out
        # samples at SNR 30 dB: 1 us, 2 us where extrapolated or where the bit clock is seen on one side only
        tol = 0.1 if flag is not Extrapolated.NONE else 0.05
        assert ch.start_samples[i] == pytest.approx(s[j], abs=tol)
        assert ch.end_samples[i] == pytest.approx(e[j], abs=0.1)
        assert ch.bits_missing[i] == 0 or flag in (Extrapolated.START, Extrapolated.BOTH)


@pytest.mark.parametrize("reverse", [False, True], ids=["forward", "reverse"])
def test_frames_cut_by_the_files_start_and_end(reverse):
    """Forward: the file starts 30 % into a frame (its first 24-25 bits lost: label from the next frame, start
    extrapolated) and ends just after the mid-bit edge of a frame's bit 79 (its closing edge extrapolated).
    Reverse play mirrors it: the sync word comes first in time, so the file starts between a frame's first edge
    and bit 79's mid-bit edge, and ends 30 % before a frame's end."""
    enc = _take("25", reverse)
    first_t = np.sort(np.minimum(enc.frame_start_samples, enc.frame_end_samples))  # frames in time order
    last_t = np.sort(np.maximum(enc.frame_start_samples, enc.frame_end_samples))
    bit = (last_t[0] - first_t[0]) / 80
    if not reverse:
        lo, hi = first_t[2] + 0.3 * 80 * bit, last_t[-3] - bit / 2 + bit / 3
    else:
        lo, hi = first_t[2] + bit / 2 - bit / 3, last_t[-3] - 0.3 * 80 * bit
    a, b = int(np.ceil(lo)), int(np.floor(hi)) + 1
    x, counts, s, e, bits = _cut(enc, a, b)
    (ch,) = decode_samples(x, FS)
    _check(ch, counts, s, e, bits, len(x), reverse)
    flags = [EXTRAPOLATED[v] for v in ch.extrapolated]
    cut_first = 0 if not reverse else -1  # the frame whose first bits are lost
    assert flags[cut_first] is Extrapolated.START and flags[-1 - cut_first] is Extrapolated.END
    assert all(f is Extrapolated.NONE for f in flags[1:-1]) and len(ch) == 26
    assert ch.bits_missing[cut_first] in (24, 25) and not ch.bits_missing[-1 - cut_first]
    assert ch.discontinuity.tolist() == [True] + [False] * 25


@settings(max_examples=40, deadline=None, derandomize=True)
@given(rate=st.sampled_from(["24", "25", "29.97df", "30"]), reverse=st.booleans(),
       a=st.floats(0.0, 1.0), b=st.floats(0.0, 1.0))
def test_any_cut_reports_every_frame_whose_sync_word_it_holds(rate, reverse, a, b):
    enc = _take(rate, reverse)
    n = len(enc.samples)
    start, stop = int(a * 0.3 * n), int(n - b * 0.3 * n)
    x, counts, s, e, bits = _cut(enc, start, stop)
    (ch,) = decode_samples(x, FS)
    _check(ch, counts, s, e, bits, len(x), reverse)


def test_a_label_the_cut_bits_contradict_is_not_inferred():
    """The frame cut by the file's start holds labels bits that disagree with the next frame's label minus one
    (a jump right there): it is not reported."""
    rate = RATE_25
    from timecode.encoder import encode_ltc_labels, label_range

    labels = np.concatenate([label_range("03:00:00:00", 3, rate), label_range("07:00:00:00", 10, rate)])
    enc = encode_ltc_labels(labels, fps=rate, sample_rate=FS, options=EncoderOptions(start_offset_samples=300.0))
    a = int(enc.frame_start_samples[2] + 20 * 2 * 960 / 80 * 2)  # 20 bits into frame 2 (03:00:00:02)
    (ch,) = decode_samples(enc.samples[a:], FS)
    assert ch.label_strings()[0] == "07:00:00:00"  # 03:00:00:02's hours and minutes are in the file


@pytest.mark.parametrize("rate", [RATE_24, RATE_25, RATE_29_97_DF, RATE_30], ids=str)
@pytest.mark.parametrize("phase", [0.0, 0.5])
def test_8k_every_rate(rate, phase):
    """8 kHz (a telephone rate): at 25 fps a half-bit is 2 samples, and with edges on whole samples the level
    percentiles used to see one level only ("no LTC found")."""
    fs = 8000
    enc = encode_ltc("10:00:00;00" if rate.drop_frame else "10:00:00:00", 100, fps=rate, sample_rate=fs,
                     options=EncoderOptions(start_offset_samples=100.0 + phase, noise_snr_db=30.0))
    (ch,) = decode_samples(enc.samples.astype(np.float32), fs)
    truth = dict(zip(labels_to_frames(enc.labels, rate).tolist(), enc.frame_start_samples))
    err = np.array([st - truth[c] for c, st in zip(ch.frame_numbers.tolist(), ch.start_samples)])
    assert ch.rate is rate and len(ch) >= 99 and np.all(np.abs(err) < 0.5)
    assert np.median(np.abs(err)) / fs * 1e6 < 10.0  # us


def test_nan_samples_are_gaps():
    """A float recording with a NaN every 1,000 samples (and an inf): every frame, the bad samples counted."""
    enc = encode_ltc("01:00:00:00", 50, fps=RATE_25, sample_rate=FS, options=EncoderOptions(noise_snr_db=40.0))
    x = enc.samples.astype(np.float32)
    x[::1000] = np.nan
    x[5555] = np.inf
    (ch,) = decode_samples(x, FS)
    assert len(ch) == 50 and ch.n_nonfinite == len(x[::1000]) + 1
    truth = enc.frame_start_samples
    assert np.median(np.abs(ch.start_samples - truth)) < 0.01  # samples
    (silent,) = decode_samples(np.full(FS, np.nan, np.float32), FS)
    assert len(silent) == 0 and silent.n_nonfinite == FS


def test_a_rate_the_bit_stream_contradicts_is_refused():
    enc = encode_ltc("01:00:00:00", 60, fps=RATE_25, sample_rate=FS)
    for wrong in (RATE_30, RATE_24, RATE_29_97_DF):
        with pytest.raises(RateMismatchError, match="channel 0: the LTC is not"):
            decode_samples(enc.samples, FS, options=_opts(wrong))
    (ch,) = decode_samples(enc.samples, FS, options=_opts(RATE_25))
    assert len(ch) == 60
    short = encode_ltc("01:00:00:00", 12, fps=RATE_25, sample_rate=FS)  # no label wrap: the frame period tells
    with pytest.raises(RateMismatchError, match="per second"):
        decode_samples(short.samples, FS, options=_opts(RATE_30))


def _opts(rate):
    from timecode.decode.decoder import DecodeOptions

    return DecodeOptions(rate=rate)
