"""LTC encoder: every edge at its exact sub-sample time, rise time, level, polarity, drift, reverse, jumps."""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from dome_calib.errors import OptionsError
from timecode.encoder import EncoderError, EncoderOptions, encode_ltc, encode_ltc_labels, label_range
from timecode.frame import unpack_bits
from timecode.labels import labels_to_frames
from timecode.rates import RATE_24, RATE_25, RATE_29_97, RATE_29_97_DF, RATE_30


def test_frame_starts_are_exact_fractions_of_the_sample_rate():
    enc = encode_ltc("10:00:00:00", 40, fps=Fraction(30000, 1001), sample_rate=48000,
                     options=EncoderOptions(start_offset_samples=123.25))
    assert enc.rate is RATE_29_97
    expect = 123.25 + np.arange(40) * 1601.6  # 48000 * 1001 / 30000
    assert np.max(np.abs(enc.frame_start_samples - expect)) < 1e-9
    assert np.max(np.abs(enc.frame_end_samples - (expect + 1601.6))) < 1e-9
    # every frame opens with an edge, and frame j's first edge is edge number sum(80 + ones) of earlier frames
    per_frame = 80 + enc.bits.sum(axis=1).astype(np.int64)
    first = np.concatenate([[0], np.cumsum(per_frame)[:-1]]).astype(np.int64)
    assert np.array_equal(enc.edge_samples[first], enc.frame_start_samples)
    assert np.all(per_frame % 2 == 0)  # parity: every frame starts with the same polarity


def test_half_level_crossing_is_at_each_edge_time():
    """At 96 kHz the signal is well sampled: its interpolated value at every true edge time is ~0."""
    enc = encode_ltc("01:00:00:00", 10, fps=RATE_25, sample_rate=96000,
                     options=EncoderOptions(start_offset_samples=50.37))
    spline = CubicSpline(np.arange(enc.samples.size), enc.samples)
    amp = 10 ** (-6 / 20)
    assert np.max(np.abs(spline(enc.edge_samples))) < 2e-3 * amp


def test_rise_time_level_and_polarity():
    fs = 192000
    enc = encode_ltc("00:00:00:00", 3, fps=RATE_24, sample_rate=fs,
                     options=EncoderOptions(rise_time_us=40.0, level_dbfs=-12.0, polarity=-1))
    assert enc.edge_sigma_samples * 2.5631 / fs * 1e6 == pytest.approx(40.0, rel=1e-3)
    amp = 10 ** (-12 / 20)
    assert np.max(np.abs(enc.samples)) == pytest.approx(amp, rel=1e-6)
    first = int(np.ceil(enc.frame_start_samples[0]))
    assert enc.samples[first + 20] < 0 < enc.samples[first - 20]  # polarity -1: frames start falling
    # measured 10-90 % rise of the first edge, on the fine sample grid
    x = enc.samples[first - 40:first + 40] / amp
    t = np.arange(first - 40, first + 40)
    t10, t90 = np.interp([0.8, -0.8], -x, t) if x[0] > 0 else np.interp([-0.8, 0.8], x, t)
    assert abs(t90 - t10) / fs * 1e6 == pytest.approx(40.0, abs=1.0)


def test_edges_are_band_limited_at_low_sample_rates():
    enc = encode_ltc("00:00:00:00", 2, fps=RATE_30, sample_rate=16000)
    sigma = enc.edge_sigma_samples
    assert np.exp(-((np.pi * sigma) ** 2) / 2) == pytest.approx(10 ** (-30 / 20), rel=1e-6)  # -30 dB at fs/2
    assert sigma * 2.5631 / 16000 * 1e6 > 40.0  # wider than SMPTE's 40 us, as an anti-alias filter makes it


def test_drift_and_time_warp_move_edges_as_specified():
    fs = 48000
    plain = encode_ltc("00:00:00:00", 50, fps=RATE_25, sample_rate=fs, options=EncoderOptions(start_offset_samples=10))
    fast = encode_ltc("00:00:00:00", 50, fps=RATE_25, sample_rate=fs,
                      options=EncoderOptions(start_offset_samples=10, drift_ppm=100.0))
    assert np.allclose(np.diff(fast.frame_start_samples), 1920.0 / 1.0001, atol=1e-9)
    warp = encode_ltc("00:00:00:00", 50, fps=RATE_25, sample_rate=fs,
                      options=EncoderOptions(start_offset_samples=10, time_warp=lambda t: t + 0.01 * t * t))
    t_nominal = (plain.frame_start_samples - 10) / fs
    assert np.allclose(warp.frame_start_samples, 10 + (t_nominal + 0.01 * t_nominal ** 2) * fs, atol=1e-9)


def test_reverse_play_mirrors_the_frames():
    fs = 48000
    fwd = encode_ltc("00:00:10:00", 20, fps=RATE_25, sample_rate=fs, options=EncoderOptions(start_offset_samples=100))
    rev = encode_ltc("00:00:10:00", 20, fps=RATE_25, sample_rate=fs,
                     options=EncoderOptions(start_offset_samples=100, reverse=True))
    assert np.all(rev.frame_start_samples > rev.frame_end_samples)
    assert rev.frame_start_samples[0] == pytest.approx(100 + 20 * 1920)  # first frame's bit 0 is heard last
    assert rev.frame_start_samples[-1] == pytest.approx(100 + 1920)
    # the reversed edge pattern is the forward one mirrored in time
    span = fwd.edge_samples[-1] + fwd.edge_samples[0]
    assert np.allclose(np.sort(span - fwd.edge_samples), rev.edge_samples, atol=1e-9)


def test_label_lists_encode_jumps_on_one_continuous_clock():
    rate = RATE_29_97_DF
    labels = np.concatenate([label_range("09:59:59;28", 4, rate), label_range("12:00:00;00", 3, rate)])
    enc = encode_ltc_labels(labels, fps=rate, sample_rate=48000, user_bits=np.arange(7))
    decoded = unpack_bits(enc.bits)
    assert decoded.hmsf.tolist() == [[9, 59, 59, 28], [9, 59, 59, 29], [10, 0, 0, 0], [10, 0, 0, 1],
                                     [12, 0, 0, 0], [12, 0, 0, 1], [12, 0, 0, 2]]
    assert decoded.user_bits.tolist() == list(range(7))
    assert np.all(enc.bits[:, 10] == 1)  # drop-frame flag
    assert np.allclose(np.diff(enc.frame_start_samples), 1601.6, atol=1e-9)
    assert np.array_equal(labels_to_frames(enc.labels, rate), labels_to_frames(labels, rate))


def test_encoder_rejects_impossible_requests():
    with pytest.raises(EncoderError, match="dropped in drop-frame"):
        encode_ltc_labels(["00:01:00;00"], fps=RATE_29_97_DF, sample_rate=48000)
    with pytest.raises(OptionsError, match="polarity 0: expected 1 or -1"):
        encode_ltc("00:00:00:00", 2, fps=RATE_25, sample_rate=48000, options=EncoderOptions(polarity=0))
    with pytest.raises(EncoderError, match="n_frames"):
        encode_ltc("00:00:00:00", 0, fps=RATE_25, sample_rate=48000)
    with pytest.raises(EncoderError, match="no room"):
        encode_ltc("00:00:00:00", 2, fps=RATE_25, sample_rate=48000, options=EncoderOptions(start_offset_samples=0))
    with pytest.raises(EncoderError, match="time_warp"):
        encode_ltc("00:00:00:00", 2, fps=RATE_25, sample_rate=48000, options=EncoderOptions(time_warp=lambda t: -t))
