"""Real LTC recordings: every frame libltc decodes (its reference decodes, tests/data/ltc), ours decodes with
the same label, at nearly the same place (libltc reports whole samples, late by a level-dependent amount), plus
the frame the file starts inside when its sync word is in the file."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from timecode.audio_io import RawFormat, RawSampleFormat
from timecode.decode.decoder import decode_file
from timecode.rates import RATE_24, RATE_25
from timecode.decode.result import EXTRAPOLATED, Extrapolated

DATA = Path(__file__).parent / "data" / "ltc"
_ROW = re.compile(r"(\d\d):(\d\d):(\d\d)[:;.](\d\d)\s*\|\s*(-?\d+)\s+(-?\d+)")


def _reference(name: str) -> np.ndarray:
    """(N, 6): hours, minutes, seconds, frames, libltc start sample, libltc end sample."""
    rows = [tuple(int(v) for v in m.groups()) for line in (DATA / name).read_text().splitlines()
            if not line.startswith("#") and (m := _ROW.search(line))]
    return np.array(rows, dtype=np.int64)


# (audio, libltc's decode, raw format, rate, the frame the file starts inside whose sync word it holds)
CASES = [
    ("ltcsync_ltc.wav", "ltcsync_ltc.ltcdump.txt", None, RATE_24, None),  # its sync word starts before sample 0
    ("ltcsync_ZOOM0004_Tr1.wav", "ltcsync_ZOOM0004_Tr1.ltcdump.txt", None, RATE_24, (18, 34, 17, 2)),
    ("libltc_timecode.raw", "libltc_timecode.txt", RawFormat(sample_format=RawSampleFormat.U8, sample_rate=22050),
     RATE_25, (0, 5, 27, 16)),
]


@pytest.mark.parametrize("audio,reference,raw,rate,edge", CASES, ids=[c[0] for c in CASES])
def test_every_frame_libltc_decodes_we_decode_with_the_same_label(audio, reference, raw, rate, edge):
    ref = _reference(reference)
    (ch,) = decode_file(DATA / audio, raw=raw)
    assert ch.rate is rate
    ours = {tuple(lab): (s, e) for lab, s, e in zip(ch.labels.tolist(), ch.start_samples, ch.end_samples)}
    missing = [tuple(r[:4]) for r in ref if tuple(r[:4]) not in ours]
    assert not missing, f"libltc decodes {len(missing)} frame(s) we miss, e.g. {missing[:3]}"
    # and nothing libltc does not have but the frame cut by the file's start
    assert len(ch) == len(ref) + (edge is not None)
    if edge is not None:
        assert tuple(ch.labels[0]) == edge and EXTRAPOLATED[ch.extrapolated[0]] is Extrapolated.START
        assert 0 < ch.bits_missing[0] <= 64 and not ch.bits_missing[1:].any() and not ch.extrapolated[1:].any()
        assert ch.start_samples[0] < 0 < ch.end_samples[0]
        assert ch.end_samples[0] == pytest.approx(ch.start_samples[1], abs=0.5)  # two fits of one edge, samples
        period = np.median(np.diff(ch.start_samples[1:]))  # libltc's test file runs 0.3 % slow
        assert ch.end_samples[0] - ch.start_samples[0] == pytest.approx(period, abs=0.6)  # samples
    # same frames at the same place: libltc's whole-sample start is a few samples off ours (its detector
    # fires past half the swing, later on slow or dipping edges); its first frame after a gap is only an
    # estimate, so it is left out
    start = np.array([ours[tuple(r[:4])][0] for r in ref[1:]])
    diff = start - ref[1:, 4]
    assert abs(np.median(diff)) <= 2.5 and np.all(np.abs(diff) <= 5.0), diff
    assert not ch.discontinuity[1:].any() and ch.n_rejected == 0


def test_zoom_recording_is_ac_coupled_and_timed_smoothly():
    (ch,) = decode_file(DATA / "ltcsync_ZOOM0004_Tr1.wav")
    assert 10.0 < ch.ac_coupling_hz < 60.0
    period = np.diff(ch.start_samples)
    assert np.median(period) == pytest.approx(2000.0, abs=0.05)  # 24 fps at 48 kHz
    # between the generator's once-a-second corrections (a jump of ~0.4 sample every 24 frames), frame
    # periods agree to a few thousandths of a sample
    change = np.abs(np.diff(period))
    assert np.median(change) < 0.005 and np.mean(change > 0.05) < 0.15
    assert np.nanmedian(ch.jitter_us) < 1.0
