"""Issue 37: a half-copied FLAC (cut in half, or a header claiming 2^31 samples) is one line naming the file: in a
`timecode decode` batch the good files' output is kept; `session` and `timecode sync` refuse it before any work."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import soundfile as sf

from timecode.encoder import encode_ltc
from timecode.rates import RATE_25

from .cli_runner import run_in_process


@pytest.fixture(scope="module")
def flacs(tmp_path_factory):
    """good.flac (10 s of 25 fps LTC), half.flac (its first half of bytes), claims.flac (header: 2^31 samples)."""
    folder = tmp_path_factory.mktemp("flac")
    enc = encode_ltc("01:00:00:00", 250, fps=RATE_25, sample_rate=48000)
    sf.write(folder / "good.flac", enc.samples, 48000, subtype="PCM_16")
    data = (folder / "good.flac").read_bytes()
    (folder / "half.flac").write_bytes(data[: len(data) // 2])
    b = bytearray(data)
    at = 8 + 13  # STREAMINFO (after 'fLaC' and its block header): total samples in the low 36 bits of bytes 13..17
    total = int.from_bytes(b[at:at + 5], "big")
    b[at:at + 5] = ((total & ~((1 << 36) - 1)) | (1 << 31)).to_bytes(5, "big")
    (folder / "claims.flac").write_bytes(bytes(b))
    return folder


def _session_with_ltc(root, flac, tmp_path):
    """A copy of the small product session whose LTC recording is ``flac`` (session.json names it)."""
    sess = tmp_path / "sess"
    shutil.copytree(root, sess)
    shutil.copy(flac, sess / "sync" / "ltc.flac")
    doc = json.loads((sess / "sync" / "session.json").read_text())
    doc["ltc"]["file"] = "ltc.flac"
    (sess / "sync" / "session.json").write_text(json.dumps(doc))
    return sess


def _timecode(args, monkeypatch, capsys):
    from timecode.cli import main

    return run_in_process(main, "timecode", args, monkeypatch, capsys)


@pytest.mark.parametrize("name", ["half.flac", "claims.flac"])
def test_a_half_copied_flac_is_one_line_and_the_good_files_output_kept(flacs, name, monkeypatch, capsys, tmp_path):
    out = tmp_path / "table.csv"
    done = _timecode(["decode", flacs / name, flacs / "good.flac", "-f", "csv", "-o", out], monkeypatch, capsys)
    assert done.returncode == 1
    errors = done.stderr.strip().splitlines()
    assert len(errors) == 1 and errors[0].startswith(f"timecode: error: {flacs / name}: cut short or damaged")
    rows = out.read_text().splitlines()
    assert len(rows) == 1 + 250 and all(str(flacs / "good.flac") in r for r in rows[1:])


def test_the_reader_names_a_damaged_block(flacs):
    from timecode.audio_io import AudioError, AudioReader

    with AudioReader(flacs / "good.flac") as reader:
        assert len(reader.read(0, 1000)) == 1000
    with pytest.raises(AudioError, match="half.flac: cut short or damaged"):
        AudioReader(flacs / "half.flac")


def test_session_refuses_a_half_copied_ltc_recording_before_the_calibration(small_product_session, flacs, tmp_path,
                                                                             dome_calib_cli):
    sess = _session_with_ltc(small_product_session[0], flacs / "claims.flac", tmp_path)
    done = dome_calib_cli("session", sess, "-o", tmp_path / "out")
    assert done.returncode == 1
    assert "ltc.flac: cut short or damaged" in done.stderr and f"({sess / 'sync' / 'session.json'}: ltc.file)" in done.stderr
    assert "dome-calib session: calibrate" not in done.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.work").exists()


def test_timecode_sync_refuses_a_half_copied_ltc_recording_before_decoding(small_product_session, flacs, tmp_path,
                                                                           monkeypatch, capsys):
    sess = _session_with_ltc(small_product_session[0], flacs / "half.flac", tmp_path)
    done = _timecode(["sync", sess / "sync", "-o", tmp_path / "b"], monkeypatch, capsys)
    assert done.returncode == 1
    assert f"{sess / 'sync' / 'ltc.flac'}: cut short or damaged" in done.stderr and "ltc.file" in done.stderr
    assert done.stderr.count("\n") == 1
    assert not (tmp_path / "b").exists()
