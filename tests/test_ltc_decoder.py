"""LTC decoder against the encoder's exact truth: rates, sample rates, sub-sample timing, robustness
(noise, DC, AC coupling, spikes, -60 dBFS, speed changes, reverse, polarity), jumps, channels, input types."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, lfilter

from timecode.decode.decoder import DecodeError, DecodeOptions, decode_samples
from timecode.encoder import EncodedLTC, EncoderOptions, encode_ltc, encode_ltc_labels, label_range
from timecode.labels import labels_to_frames
from timecode.rates import RATE_23_976, RATE_24, RATE_25, RATE_29_97, RATE_29_97_DF, RATE_30, RATES
from timecode.decode.result import Direction

A = 10 ** (-6 / 20)  # encoder default peak level


def _match(result, enc: EncodedLTC) -> tuple[int, np.ndarray]:
    """(frames decoded with a label that exists in the truth at the right time, timing errors in samples)."""
    truth = dict(zip(labels_to_frames(enc.labels, enc.rate).tolist(), enc.frame_start_samples))
    err = np.array([s - truth[n] for n, s in zip(result.frame_numbers.tolist(), result.start_samples)
                    if n in truth])
    good = int(np.sum(np.abs(err) < 1.0))
    assert good == len(result), "a decoded label is not where the truth has it"
    return good, err


def _noise(x: np.ndarray, snr_db: float, seed: int) -> np.ndarray:
    """White noise at ``snr_db`` below the power of a square wave of peak A."""
    return x + np.random.default_rng(seed).normal(0.0, A / 10 ** (snr_db / 20), x.shape)


@pytest.mark.parametrize("rate", list(RATES.values()), ids=list(RATES))
def test_every_rate_round_trips_with_sub_sample_timing(rate):
    enc = encode_ltc("23:59:58:00", 80, fps=rate, sample_rate=48000, user_bits=0xC0FFEE42,
                     options=EncoderOptions(start_offset_samples=333.3))
    (ch,) = decode_samples(enc.samples, 48000)
    assert ch.rate is rate
    assert np.array_equal(ch.labels, enc.labels)  # includes the midnight wrap
    assert np.all(ch.user_bits == 0xC0FFEE42)
    assert np.all(ch.drop_frame == rate.drop_frame) and np.all(ch.parity_ok)
    assert ch.discontinuity.tolist() == [True] + [False] * 79
    good, err = _match(ch, enc)
    assert good == 80 and np.max(np.abs(err)) < 0.005  # samples (0.1 us)
    assert np.allclose(ch.end_samples, enc.frame_end_samples, atol=0.005)


@pytest.mark.parametrize("fs", [8000, 11025, 16000, 22050, 44100, 96000, 192000])
def test_every_sample_rate(fs):
    rate = RATE_30 if fs >= 16000 else RATE_24
    enc = encode_ltc("01:00:00:00", 40, fps=rate, sample_rate=fs, options=EncoderOptions(start_offset_samples=77.7))
    (ch,) = decode_samples(enc.samples.astype(np.float32), fs)
    good, err = _match(ch, enc)
    assert good == 40 and ch.rate is rate
    assert np.max(np.abs(err)) < 0.02  # samples


def test_noise_48k_snr20_timing_under_a_microsecond():
    enc = encode_ltc("10:00:00:00", 150, fps=RATE_25, sample_rate=48000)
    (ch,) = decode_samples(_noise(enc.samples, 20, 1), 48000)
    good, err = _match(ch, enc)
    assert good == 150
    assert np.median(np.abs(err)) / 48000 * 1e6 < 1.0  # us
    assert np.nanmedian(ch.jitter_us) < 5.0  # per-edge scatter at SNR 20 dB is ~2 us


def test_kinect_16k_2997_snr20_timing_under_5us():
    enc = encode_ltc("10:00:00;00", 150, fps=RATE_29_97_DF, sample_rate=16000)
    (ch,) = decode_samples(_noise(enc.samples, 20, 2), 16000)
    good, err = _match(ch, enc)
    assert good == 150 and ch.rate is RATE_29_97_DF
    assert np.median(np.abs(err)) / 16000 * 1e6 < 5.0


def test_dc_offset_ac_coupling_spikes_and_low_level():
    fs = 48000
    enc = encode_ltc("05:06:07:08", 100, fps=RATE_24, sample_rate=fs)
    b, a = butter(1, 100.0, "highpass", fs=fs)
    spiky = enc.samples.copy()
    rng = np.random.default_rng(3)
    where = rng.integers(0, spiky.size, 150)
    spiky[where] += rng.choice([-1.0, 1.0], 150) * rng.uniform(0.5, 1.5, 150)
    quiet = np.round((enc.samples * 10 ** (-54 / 20) + rng.normal(0, 10 ** (-100 / 20), enc.samples.size)) * 32767)
    cases = {
        "dc": (enc.samples + 0.4, 0.001),
        "ac": (lfilter(b, a, enc.samples), 0.02),
        "spikes": (spiky, 0.01),
        "-60dBFS int16": (quiet.astype(np.int16), 0.01),
    }
    for name, (x, tol_samples) in cases.items():
        (ch,) = decode_samples(x, fs)
        good, err = _match(ch, enc)
        assert good == 100, name
        assert np.median(np.abs(err)) < tol_samples, name
    (ch,) = decode_samples(cases["ac"][0], fs)
    assert ch.ac_coupling_hz == pytest.approx(100.0, rel=0.2)
    (ch,) = decode_samples(cases["-60dBFS int16"][0], fs)
    assert np.median(ch.level_dbfs) == pytest.approx(-60.0, abs=0.5)


def test_reverse_play_and_inverted_polarity():
    fs = 48000
    enc = encode_ltc("00:10:00:00", 60, fps=RATE_25, sample_rate=fs, options=EncoderOptions(reverse=True, polarity=-1))
    (ch,) = decode_samples(enc.samples, fs)
    good, err = _match(ch, enc)
    assert good == 60 and np.all(ch.reverse) and np.max(np.abs(err)) < 0.005
    assert np.all(ch.start_samples > ch.end_samples)
    assert ch.frames()[0].direction is Direction.REVERSE
    assert ch.label_strings()[0] == "00:10:02:09"  # the last frame encoded is heard first
    assert not ch.discontinuity[1:].any()  # labels counting down in reverse play are continuous


def test_speed_changes_and_drift():
    fs = 48000
    wobble = EncoderOptions(drift_ppm=300.0, time_warp=lambda t: t + 0.08 * np.sin(2 * np.pi * t) / (2 * np.pi))
    enc = encode_ltc("00:00:00:00", 125, fps=RATE_25, sample_rate=fs, options=wobble)  # speed 1 +- 8 % at 1 Hz
    (ch,) = decode_samples(enc.samples, fs)
    good, err = _match(ch, enc)
    assert good == 125 and ch.rate is RATE_25
    assert np.median(np.abs(err)) < 0.01 and np.max(np.abs(err)) < 0.05  # the first frame is extrapolated
    ramp = encode_ltc("00:00:00:00", 125, fps=RATE_29_97, sample_rate=fs,
                      options=EncoderOptions(time_warp=lambda t: t + 0.05 * t * t))  # 10 %/s varispeed
    (ch,) = decode_samples(ramp.samples, fs, options=DecodeOptions(rate=RATE_29_97))
    good, err = _match(ch, ramp)
    assert good == 125 and np.max(np.abs(err[1:])) < 0.01 and abs(err[0]) < 0.2  # first frame: extrapolated


def test_jumps_are_reported_never_bridged():
    rate = RATE_29_97_DF
    labels = np.concatenate([label_range("01:00:00;00", 50, rate), label_range("07:30:00;00", 50, rate)])
    enc = encode_ltc_labels(labels, fps=rate, sample_rate=48000)
    (ch,) = decode_samples(enc.samples, 48000)
    good, err = _match(ch, enc)
    assert good == 100 and np.max(np.abs(err)) < 0.005  # frames on both sides of the jump keep exact times
    assert np.flatnonzero(ch.discontinuity).tolist() == [0, 50]


@pytest.mark.parametrize("cut", [50000, 50800, 51234])
def test_a_splice_mid_frame_mixes_no_frames(cut):
    """Two takes joined at an arbitrary sample: the frame read across the join is dropped, not reported."""
    fs, rate = 48000, RATE_29_97_DF
    a = encode_ltc("10:00:00;00", 60, fps=rate, sample_rate=fs, options=EncoderOptions(start_offset_samples=500))
    b = encode_ltc("11:00:00;00", 60, fps=rate, sample_rate=fs, options=EncoderOptions(start_offset_samples=777.7))
    x = np.concatenate([a.samples[:cut], b.samples[30000:]])
    (ch,) = decode_samples(_noise(x, 30, 6), fs)
    truth = {**dict(zip(labels_to_frames(a.labels, rate).tolist(), a.frame_start_samples)),
             **dict(zip(labels_to_frames(b.labels, rate).tolist(), b.frame_start_samples - 30000 + cut))}
    complete = int(np.sum(a.frame_end_samples < cut - 2)) + int(np.sum(b.frame_start_samples > 30000 + 2))
    assert len(ch) == complete
    err = [s - truth[n] for n, s in zip(ch.frame_numbers.tolist(), ch.start_samples)]
    assert np.max(np.abs(err)) < 0.05  # samples: both sides timed as if the other did not exist
    assert int(ch.discontinuity.sum()) == 2


def test_an_isolated_bad_label_is_dropped_but_a_longer_excursion_is_kept():
    rate = RATE_25
    labels = label_range("02:00:00:00", 60, rate)
    one = labels.copy()
    one[30] = [2, 0, 9, 9]  # one frame that disagrees with both neighbours: bit errors, not a jump
    enc = encode_ltc_labels(one, fps=rate, sample_rate=48000)
    (ch,) = decode_samples(enc.samples, 48000)
    assert len(ch) == 59 and ch.n_rejected == 1 and [2, 0, 9, 9] not in ch.labels.tolist()
    assert not ch.discontinuity[1:].any()  # the hole of one frame is not a jump
    two = labels.copy()
    two[30:32] = [[2, 0, 9, 9], [2, 0, 9, 10]]
    enc = encode_ltc_labels(two, fps=rate, sample_rate=48000)
    (ch,) = decode_samples(enc.samples, 48000)
    assert len(ch) == 60 and np.flatnonzero(ch.discontinuity).tolist() == [0, 30, 32]


def test_channels_input_types_and_blocks():
    fs = 44100
    enc = encode_ltc("12:34:56:07", 60, fps=RATE_23_976, sample_rate=fs)
    noise = np.random.default_rng(5).normal(0, 0.05, enc.samples.size)
    stereo = np.stack([noise, enc.samples], axis=1)
    left, right = decode_samples(stereo, fs)
    assert len(left) == 0 and left.rate is None and len(right) == 60 and right.channel == 1
    ref = right.start_samples
    for x in ((enc.samples * 32767).astype(np.int16), (enc.samples * 2**31 * 0.99).astype(np.int32),
              np.round(128 + enc.samples * 127).astype(np.uint8), enc.samples.astype(np.float32)):
        (ch,) = decode_samples(x, fs)
        assert len(ch) == 60 and np.max(np.abs(ch.start_samples - ref)) < 0.02, x.dtype
    (small,) = decode_samples(enc.samples, fs, options=DecodeOptions(block_seconds=0.3))  # many block seams
    assert np.array_equal(small.labels, right.labels) and np.max(np.abs(small.start_samples - ref)) < 1e-3
    (forced,) = decode_samples(enc.samples, fs, options=DecodeOptions(rate=RATE_24))
    assert forced.rate is RATE_24 and len(forced) == 60


def test_decoder_rejects_bad_requests():
    with pytest.raises(DecodeError, match="outside the supported"):
        decode_samples(np.zeros(1000), 4000)
    with pytest.raises(DecodeError, match="channel 2 does not exist"):
        decode_samples(np.zeros((1000, 2)), 48000, channels=[2])
    with pytest.raises(DecodeError, match="shape"):
        decode_samples(np.zeros((0,)), 48000)
    (silent,) = decode_samples(np.zeros(48000), 48000)
    assert len(silent) == 0 and silent.n_edges == 0


def test_continuity_rules_on_label_sequences():
    from timecode.decode.continuity import continuity

    def run(counts, reverse=None):
        c = np.array(counts)
        rev = np.zeros(len(c), bool) if reverse is None else np.array(reverse)
        keep, disc = continuity(c, rev, np.arange(len(c)) * 10.0 + 5, np.full(len(c), 10.0), 1000)
        return keep.astype(int).tolist(), np.flatnonzero(disc).tolist()

    assert run([0, 1, 2, 3, 4, 99, 6, 7, 8, 500, 501]) == ([1] * 5 + [0] + [1] * 5, [0, 9])  # bad frame, jump
    assert run([77, 1, 2, 3]) == ([0, 1, 1, 1], [1])  # a corrupted first frame
    assert run([5, 17, 3, 90, 44]) == ([1] * 5, [0, 1, 2, 3, 4])  # chaos: every frame kept, every one a jump
    assert run([998, 999, 0, 1]) == ([1] * 4, [0])  # midnight wrap (1000 frames a day here)
    assert run([9, 8, 7, 6], reverse=[True] * 4) == ([1] * 4, [0])  # reverse play counts down
