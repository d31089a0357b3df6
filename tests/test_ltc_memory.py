"""Issue 37: noise through the decoder keeps memory bounded by a block (the edges of blocks without LTC near are
counted, then dropped), and LTC among the noise, across a block seam, decodes to the same frames as before."""
from __future__ import annotations

import numpy as np
import pytest

import timecode.decode.decoder as decoder
from timecode.decode.decoder import DecodeOptions, decode_samples
from timecode.encoder import EncoderOptions, encode_ltc
from timecode.rates import RATE_25

FS = 48000


def _spy(monkeypatch) -> list[int]:
    passed: list[int] = []
    real = decoder.decode_edges

    def spy(t, *args, **kw):
        passed.append(len(t))
        return real(t, *args, **kw)

    monkeypatch.setattr(decoder, "decode_edges", spy)
    return passed


def test_noise_edges_are_counted_but_not_kept(monkeypatch):
    noise = np.random.default_rng(0).normal(0, 0.1, 40 * FS).astype(np.float32)
    passed = _spy(monkeypatch)
    (ch,) = decode_samples(noise, FS, options=DecodeOptions(block_seconds=5.0))
    assert len(ch) == 0
    assert ch.n_edges > 40 * 1000  # noise crosses the thresholds thousands of times a second ...
    assert passed == [0]  # ... and none of those edges is kept for decoding


@pytest.mark.parametrize("ltc_start_s", [20.0, 9.995])  # inside a block; straddling the 10 s block seam
def test_ltc_in_noise_decodes_every_frame_with_bounded_edges(monkeypatch, ltc_start_s):
    n_frames = 100  # 4 s
    enc = encode_ltc("01:00:00:00", n_frames, fps=RATE_25, sample_rate=FS,
                     options=EncoderOptions(level_dbfs=-10.0))
    x = np.random.default_rng(1).normal(0, 0.1, 60 * FS).astype(np.float32)
    at = int(ltc_start_s * FS)
    x[at:at + enc.samples.size] = enc.samples
    passed = _spy(monkeypatch)
    (ch,) = decode_samples(x, FS, options=DecodeOptions(block_seconds=5.0))
    assert len(ch) >= n_frames - 1  # every whole frame (the first may lose its opening edge to the noise)
    np.testing.assert_allclose(ch.start_samples[-n_frames + 1:], enc.frame_start_samples[1:] + at, atol=0.5)
    assert ch.label_strings()[-1] == "01:00:03:24"
    assert passed[0] < ch.n_edges / 2  # the noise blocks far from the LTC were dropped (12 blocks, <= 4 kept)
