"""LTC through differentiating inputs (impulse trains) against the encoder's exact truth, the reading chosen per
stretch, and the encoder's recorder model (high-pass, rectifier, noise)."""
from __future__ import annotations

import numpy as np
import pytest

from timecode.decode.decoder import decode_samples
from timecode.encoder import EncoderOptions, encode_ltc
from timecode.decode.impulses import pole_offset
from timecode.labels import labels_to_frames
from timecode.rates import RATE_25, RATE_29_97_DF, RATE_30
from timecode.decode.result import Reading

FS = 48000


def _errors_us(ch, enc) -> np.ndarray:
    """Frame-start errors (us) of the decoded frames, each of which must be a true frame at its true place."""
    truth = dict(zip(labels_to_frames(enc.labels, enc.rate).tolist(), enc.frame_start_samples))
    err = np.array([s - truth[n] for n, s in zip(ch.frame_numbers.tolist(), ch.start_samples)])
    assert np.all(np.abs(err) < 1.0), "a decoded frame is not where the truth has it"
    return err / FS * 1e6


def _impulses(tau: float, rectify: bool, snr_db: float | None, n: int = 100, rate=RATE_25, seed: int = 0):
    return encode_ltc("10:00:00:00" if not rate.drop_frame else "10:00:00;00", n, fps=rate, sample_rate=FS,
                      options=EncoderOptions(level_dbfs=-12.0, highpass_tau_samples=tau, rectify=rectify,
                                             noise_snr_db=snr_db, noise_seed=seed, drift_ppm=37.0,
                                             start_offset_samples=333.3))


@pytest.mark.parametrize("tau", [1.0, 2.0, 4.0])
@pytest.mark.parametrize("rectify", [False, True], ids=["alternating", "one_sign"])
def test_impulse_trains_decode_with_the_edges_times(tau, rectify):
    clean = _impulses(tau, rectify, None)
    (ch,) = decode_samples(clean.samples, FS)
    assert len(ch) == 100 and np.all(ch.impulses) and ch.rate is RATE_25
    assert ch.frames()[0].reading is Reading.IMPULSES
    assert ch.impulse_tau_samples == pytest.approx(tau, rel=0.02)  # the input's time constant, fitted
    err = _errors_us(ch, clean)
    # one sign: the rectifier folds each impulse's onset over the tail of the one before (up to 5 % of it at
    # tau 4), which moves the impulse's centre by up to ~0.07 sample
    assert np.median(np.abs(err)) < (0.1 if not rectify else 2.0)
    noisy = _impulses(tau, rectify, 20.0, seed=1)
    (ch,) = decode_samples(noisy.samples, FS)
    assert len(ch) >= 95
    assert np.median(np.abs(_errors_us(ch, noisy))) < 5.0


def test_ringing_and_other_rates():
    """A little ringing after each impulse (a receiver's filter), at 29.97 DF and 30 fps."""
    for rate in (RATE_29_97_DF, RATE_30):
        enc = _impulses(1.0, False, 30.0, n=60, rate=rate)
        rung = np.convolve(enc.samples, [1.0, -0.3, 0.12, -0.05])[: enc.samples.size]
        (ch,) = decode_samples(rung, FS)
        assert len(ch) == 60 and ch.rate is rate and np.all(ch.impulses)
        assert np.median(np.abs(_errors_us(ch, enc))) < 5.0


def test_reading_is_chosen_per_stretch():
    """Square wave, then an impulse train of the same LTC: each stretch read its own way, every frame kept."""
    sq = encode_ltc("01:00:00:00", 120, fps=RATE_25, sample_rate=FS, options=EncoderOptions(start_offset_samples=500))
    imp = encode_ltc("01:00:00:00", 120, fps=RATE_25, sample_rate=FS,
                     options=EncoderOptions(start_offset_samples=500, highpass_tau_samples=2.0, level_dbfs=-12.0))
    half = int(sq.frame_start_samples[60])
    x = np.concatenate([sq.samples[:half], imp.samples[half:]])
    (ch,) = decode_samples(x, FS)
    err = _errors_us(ch, sq)
    assert len(ch) >= 118  # the frame across the switch may go
    switch = np.searchsorted(ch.start_samples, half)
    assert not ch.impulses[:switch - 1].any() and ch.impulses[switch + 1:].all()
    assert np.median(np.abs(err)) < 0.2


def test_square_waves_are_not_read_as_impulses():
    """Noisy, AC-coupled or spiky square waves keep the square-wave reading (and its exactness)."""
    from scipy.signal import butter, lfilter

    enc = encode_ltc("05:00:00:00", 80, fps=RATE_25, sample_rate=FS, options=EncoderOptions(noise_snr_db=10.0))
    b, a = butter(1, 100.0, "highpass", fs=FS)
    for x in (enc.samples, lfilter(b, a, enc.samples)):
        (ch,) = decode_samples(x, FS)
        assert len(ch) == 80 and not ch.impulses.any() and ch.impulse_tau_samples == 0.0


def test_pole_offset_is_the_centroid_of_the_untailed_impulse():
    for tau in (0.5, 1.0, 4.0):
        t = np.linspace(0, 1, 200001)
        w = np.exp(-t / tau)
        assert pole_offset(np.exp(-1 / tau)) == pytest.approx(float((t * w).sum() / w.sum()), abs=1e-5)
    assert pole_offset(0.0) == 0.0


def test_encoder_models_the_recorder():
    enc = _impulses(2.0, False, None, n=20)
    x = enc.samples
    assert np.max(np.abs(x)) == pytest.approx(10 ** (-12 / 20), rel=1e-9)  # the impulses peak at the level
    assert abs(np.mean(x)) < 1e-3 and np.all(np.abs(x[:300]) < 1e-9)  # DC-free, silent before the first edge
    # an analog one-pole high-pass of the step: 2 a exp(-t / tau) long after the edge
    k = int(enc.edge_samples[0]) + 8
    assert x[k + 1] / x[k] == pytest.approx(np.exp(-1 / 2.0), rel=1e-6)
    one = _impulses(2.0, True, None, n=20).samples
    assert np.all(one >= 0) and np.allclose(one, np.abs(x))
    noisy = _impulses(2.0, True, 20.0, n=20).samples
    assert np.std(noisy - one) == pytest.approx(0.1 * 10 ** (-12 / 20), rel=0.02)  # SNR 20 dB vs the peak
