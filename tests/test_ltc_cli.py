"""`timecode decode`: runs on real and synthetic files in every output format, on several files or folders at
once; bad input -> one line, exit 1."""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from timecode.encoder import EncoderOptions, encode_ltc
from timecode.rates import RATE_25, RATE_29_97_DF

from .cli_runner import run_in_process

DATA = Path(__file__).parent / "data" / "ltc"


def _run(args, monkeypatch, capsys) -> tuple[int, str, str]:
    """Run ``timecode ARGS`` in-process through run_cli, as the installed command does."""
    from timecode.cli import main

    done = run_in_process(main, "timecode", args, monkeypatch, capsys)
    return done.returncode, done.stdout, done.stderr


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


def test_batch_of_files_and_folders_makes_one_table(stereo, monkeypatch, capsys, tmp_path):
    """A folder and a file: one CSV with a file column; a file that fails is one line on stderr, the others are
    written, and the exit code is 1."""
    path, truth = stereo
    folder = tmp_path / "takes"
    folder.mkdir()
    imp = encode_ltc("02:00:00:00", 30, fps=RATE_25, sample_rate=48000,
                     options=EncoderOptions(highpass_tau_samples=2.0, rectify=True, level_dbfs=-12.0))
    sf.write(folder / "b_receiver.wav", imp.samples, 48000, subtype="PCM_16")
    sf.write(folder / "a_silent.flac", np.zeros(48000), 48000)
    (folder / "notes.txt").write_text("not audio, not read")
    target = tmp_path / "all.csv"
    code, out, err = _run(["decode", folder, path, "-f", "csv", "-o", target], monkeypatch, capsys)
    assert code == 1 and out == ""
    assert err.splitlines() == [f"timecode: error: {folder / 'a_silent.flac'}: no LTC found on any of its 1 channel(s)"]
    rows = list(csv.DictReader(io.StringIO(target.read_text())))
    by_file = {}
    for r in rows:
        by_file.setdefault(r["file"], []).append(r)
    assert list(by_file) == [str(folder / "b_receiver.wav"), str(path)]  # folder files by name, then the file
    receiver = by_file[str(folder / "b_receiver.wav")]
    assert len(receiver) == 30 and {r["reading"] for r in receiver} == {"impulses"}
    assert np.max(np.abs(np.array([float(r["start_samples"]) for r in receiver]) - imp.frame_start_samples)) < 0.05
    assert len(by_file[str(path)]) == 45 and {r["reading"] for r in by_file[str(path)]} == {"square"}
    code, out, err = _run(["decode", folder / "b_receiver.wav", path, "-c", "1", "-f", "json"], monkeypatch, capsys)
    assert code == 1 and "channel 1: the file has 1 channel(s)" in err  # the mono file has no channel 1
    doc = json.loads(out)
    assert [f["file"] for f in doc["files"]] == [str(path)] and doc["failed"][0]["file"] == str(folder / "b_receiver.wav")
    code, out, err = _run(["decode", folder / "b_receiver.wav"], monkeypatch, capsys)
    assert code == 0 and "30 read from impulses (input time constant 2.0" in out and " IMP " in out


def test_edge_frames_and_bad_samples_in_the_outputs(monkeypatch, capsys, tmp_path):
    enc = encode_ltc("01:00:00:00", 50, fps=RATE_25, sample_rate=48000, options=EncoderOptions(noise_snr_db=40.0))
    x = enc.samples.astype(np.float32)
    a = int(enc.frame_start_samples[1] + 800)  # the file starts 33.3 bits (of 24 samples) into frame 1
    x = x[a:]
    x[::1000] = np.nan
    path = tmp_path / "cut_nan.wav"
    sf.write(path, x, 48000, subtype="FLOAT")
    code, out, err = _run(["decode", path, "-f", "csv"], monkeypatch, capsys)
    assert code == 0
    assert err.strip() == (f"timecode: warning: {path} channel 0: {len(x[::1000])} NaN or infinite samples read as "
                           "gaps (interpolated over)")
    rows = list(csv.DictReader(io.StringIO(out)))
    assert rows[0]["label"] == "01:00:00:01" and rows[0]["extrapolated"] == "start" and rows[0]["bits_missing"] == "34"
    assert float(rows[0]["start_samples"]) == pytest.approx(enc.frame_start_samples[1] - a, abs=0.05)
    assert len(rows) == 49 and all(r["extrapolated"] == "" for r in rows[1:-1])


def test_fps_the_ltc_contradicts_is_refused(monkeypatch, capsys):
    code, out, err = _run(["decode", DATA / "ltcsync_ltc.wav", "--fps", "30"], monkeypatch, capsys)
    assert code == 1 and out == "" and err.count("\n") == 1
    assert "ltcsync_ltc.wav: channel 0: the LTC is not 30 fps: its labels count 24 frames a second" in err
    code, out, err = _run(["decode", DATA / "ltcsync_ltc.wav", "--fps", "24", "-f", "csv"], monkeypatch, capsys)
    assert code == 0 and len(out.splitlines()) == 144
