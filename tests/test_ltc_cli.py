"""`timecode decode`: runs on real and synthetic files in every output format; bad input -> one line, exit 1."""
from __future__ import annotations

import csv
import io
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from timecode.encoder import EncoderOptions, encode_ltc
from timecode.rates import RATE_29_97_DF

DATA = Path(__file__).parent / "data" / "ltc"


def _run(args, monkeypatch, capsys) -> tuple[int, str, str]:
    """Run ``timecode ARGS`` in-process through run_cli, as the installed command does."""
    from timecode.cli import main

    monkeypatch.setattr(sys, "argv", ["timecode", *map(str, args)])
    capsys.readouterr()
    code = 0
    try:
        main()
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def stereo(tmp_path_factory) -> tuple[Path, np.ndarray]:
    """Stereo WAV: noise on channel 0, 29.97 DF LTC on channel 1 (exact starts returned)."""
    enc = encode_ltc("09:59:59;00", 45, fps=RATE_29_97_DF, sample_rate=48000,
                     options=EncoderOptions(start_offset_samples=250.25, level_dbfs=-12.0))
    noise = np.random.default_rng(0).normal(0, 0.02, enc.samples.size)
    path = tmp_path_factory.mktemp("cli") / "take.wav"
    sf.write(path, np.stack([noise, enc.samples], axis=1), 48000, subtype="PCM_24")
    return path, enc.frame_start_samples


def test_table_for_people(stereo, monkeypatch, capsys):
    path, _ = stereo
    code, out, err = _run(["decode", path], monkeypatch, capsys)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("# channel 0: no LTC frames")
    assert lines[1].startswith("# channel 1: 29.97df fps, 45 frames 09:59:59;00 .. 10:00:00;14")
    assert lines[2].split()[:4] == ["ch", "label", "dir", "start_samples"]
    first = lines[3].split()
    assert first[:3] == ["1", "09:59:59;00", "fwd"] and float(first[3]) == pytest.approx(250.25, abs=0.01)
    assert "DF" in lines[3] and lines[3].rstrip().endswith("*")  # drop frame flag, first frame starts a segment
    assert any(line.split()[1] == "10:00:00;00" for line in lines[3:])


def test_csv_and_json_carry_sub_sample_starts(stereo, monkeypatch, capsys, tmp_path):
    path, truth = stereo
    code, out, err = _run(["decode", path, "--channel", "1", "--format", "csv"], monkeypatch, capsys)
    assert code == 0, err
    rows = list(csv.DictReader(io.StringIO(out)))
    assert len(rows) == 45 and rows[0]["label"] == "09:59:59;00" and rows[0]["direction"] == "forward"
    starts = np.array([float(r["start_samples"]) for r in rows])
    assert np.max(np.abs(starts - truth)) < 0.01
    assert rows[0]["drop_frame"] == "True" and rows[1]["discontinuity"] == "False"
    target = tmp_path / "out" / "frames.json"
    code, out, err = _run(["decode", path, "-c", "1", "-f", "json", "--fps", "29.97df", "-o", target],
                          monkeypatch, capsys)
    assert code == 0 and out == "", err
    doc = json.loads(target.read_text())
    (ch,) = doc["channels"]
    assert ch["rate"] == "29.97df" and ch["fps"] == "30000/1001" and ch["n_frames"] == 45
    assert ch["frames"][2]["label"] == "09:59:59;02"
    assert ch["frames"][2]["start_samples"] == pytest.approx(truth[2], abs=0.01)


def test_real_and_raw_files(monkeypatch, capsys):
    code, out, err = _run(["decode", DATA / "ltcsync_ltc.wav", "-f", "csv"], monkeypatch, capsys)
    assert code == 0, err
    rows = list(csv.DictReader(io.StringIO(out)))
    assert len(rows) == 143 and rows[0]["label"] == "04:49:33:12" and rows[-1]["label"] == "04:49:39:10"
    code, out, err = _run(["decode", DATA / "libltc_timecode.raw", "--raw-format", "u8", "--raw-rate", "22050"],
                          monkeypatch, capsys)
    assert code == 0, err
    assert "# channel 0: 25 fps, 48 frames 00:05:27:16 .. 00:05:29:13" in out  # the first: cut by the file


@pytest.mark.parametrize("args,message", [
    (["decode", "nope.wav"], "nope.wav: no such file"),
    (["decode", DATA / "libltc_timecode.txt"], "not a readable audio file"),
    (["decode", DATA / "libltc_timecode.raw"], "--raw-format and --raw-rate"),
    (["decode", DATA / "libltc_timecode.raw", "--raw-format", "u8"], "needs both --raw-format and --raw-rate"),
    (["decode", DATA / "libltc_timecode.raw", "--raw-format", "u9", "--raw-rate", "22050"], "--raw-format 'u9'"),
    (["decode", DATA / "ltcsync_ltc.wav", "--channel", "2"], "--channel 2: the file has 1 channel(s)"),
    (["decode", DATA / "ltcsync_ltc.wav", "--channel", "left"], "channel number (0 = first) or 'all'"),
    (["decode", DATA / "ltcsync_ltc.wav", "--fps", "31"], "frame rate '31' is not supported"),
    (["decode", DATA / "ltcsync_ltc.wav", "--format", "xml"], "--format must be one of table, csv, json"),
])
def test_bad_input_is_one_line_and_exit_1(args, message, monkeypatch, capsys, tmp_path):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(args, monkeypatch, capsys)
    assert code == 1 and out == ""
    assert err.count("\n") == 1 and err.startswith("timecode: error: ") and message in err, err


def test_no_ltc_on_a_channel(stereo, monkeypatch, capsys, tmp_path):
    path, _ = stereo
    code, _, err = _run(["decode", path, "--channel", "0"], monkeypatch, capsys)
    assert code == 1 and err == f"timecode: error: {path}: no LTC found on channel 0\n"
    silent = tmp_path / "silent.flac"
    sf.write(silent, np.zeros((24000, 2)), 48000)
    code, _, err = _run(["decode", silent], monkeypatch, capsys)
    assert code == 1 and "no LTC found on any of its 2 channel(s)" in err and err.count("\n") == 1
