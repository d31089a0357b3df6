"""Everything checked before any work (issue 42): a command refuses, in seconds and before its first expensive
stage, what would otherwise fail it minutes later. A session whose LTC recording cannot give the channels (or the
sample rate) its session.json names is refused before the calibration; a Kinect image of the wrong size or depth
before the first board detection. One line naming the file and the field; nothing written."""
from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from dome_calib.bundle_io import write_bundle

from .cli_runner import run_in_process


def _copy(root, tmp_path):
    sess = tmp_path / "sess"
    shutil.copytree(root, sess)
    return sess


def _files(folder):
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _session(sess, out, monkeypatch, capsys):
    from dome_calib.cli import main

    t0 = time.monotonic()
    done = run_in_process(main, "dome-calib", ["session", sess, "-o", out], monkeypatch, capsys)
    return done, time.monotonic() - t0


def _refused_before_the_calibration(done, seconds, *words):
    errors = [ln for ln in done.stderr.splitlines() if "error:" in ln]
    assert done.returncode == 1 and len(errors) == 1, done.stderr
    assert all(w in errors[0] for w in words), errors[0]
    assert "dome-calib session: calibrate" not in done.stderr  # the first stage never started
    assert seconds < 60, seconds  # seconds, not the minutes of a calibration (a loaded 2-core machine included)


@pytest.mark.parametrize("case", ["mono LTC", "LTC at 4 kHz", "Kinect audio channel"])
def test_a_session_whose_audio_cannot_give_what_session_json_names_is_refused_before_the_calibration(
        small_product_session, tmp_path, monkeypatch, capsys, case):
    root, truth = small_product_session
    sess = _copy(root, tmp_path)
    ltc = sess / "sync" / "ltc.wav"
    data, rate = sf.read(ltc, always_2d=True)
    doc = json.loads((sess / "sync" / "session.json").read_text())
    if case == "mono LTC":  # session.json names channel 1 for the HD clock
        sf.write(ltc, data[:, 0], rate)
        words = [f"{sess / 'sync' / 'session.json'}: ltc.hd_channel: 1, but {ltc} has 1 channel(s)"]
    elif case == "LTC at 4 kHz":
        sf.write(ltc, data[::12], 4000)
        words = [f"{ltc}: sample rate 4000 Hz, outside the 8000-192000 Hz", "session.json: ltc.file)"]
    else:
        node = next(iter(doc["kinect"]))
        doc["kinect"][node]["audio_channel"] = 3
        (sess / "sync" / "session.json").write_text(json.dumps(doc))
        words = [f"session.json: kinect.{node}.audio_channel: 3, but", "has 1 channel(s)"]
    out = write_bundle(truth, tmp_path / "bundle")
    before = _files(out)
    done, seconds = _session(sess, out, monkeypatch, capsys)
    _refused_before_the_calibration(done, seconds, *words)
    assert _files(out) == before and not (tmp_path / "bundle.work").exists()


def test_timecode_sync_checks_the_audio_headers_before_decoding(small_product_session, tmp_path, monkeypatch, capsys):
    """A Kinect whose audio lacks its channel: refused up front with --strict-kinect; otherwise NOT SYNCED with the
    same reason, the other streams written. Nothing is decoded when the LTC file itself cannot be."""
    import timecode.sync.pipeline as sync_pipeline
    from timecode.cli import main

    root, _ = small_product_session
    sess = _copy(root, tmp_path)
    doc = json.loads((sess / "sync" / "session.json").read_text())
    node = next(iter(doc["kinect"]))
    doc["kinect"][node]["audio_channel"] = 2
    (sess / "sync" / "session.json").write_text(json.dumps(doc))
    decoded = []
    real = sync_pipeline.decode_frame_starts
    monkeypatch.setattr(sync_pipeline, "decode_frame_starts", lambda *a, **k: decoded.append(a[0]) or real(*a, **k))
    done = run_in_process(main, "timecode", ["sync", sess / "sync", "-o", tmp_path / "strict", "--strict-kinect"],
                          monkeypatch, capsys)
    assert done.returncode == 1 and f"kinect.{node}.audio_channel: 2, but" in done.stderr, done.stderr
    assert decoded == [] and not (tmp_path / "strict").exists()
    done = run_in_process(main, "timecode", ["sync", sess / "sync", "-o", tmp_path / "lenient"], monkeypatch, capsys)
    assert done.returncode == 0, done.stderr
    assert f"{node}" in done.stdout and "NOT SYNCED" in done.stdout and "audio_channel: 2, but" in done.stdout
    sf.write(sess / "sync" / "ltc.wav", np.zeros((100, 2)), 48000)  # a sliver: the header reads, no LTC
    decoded.clear()
    doc["ltc"]["hd_channel"] = 5
    (sess / "sync" / "session.json").write_text(json.dumps(doc))
    done = run_in_process(main, "timecode", ["sync", sess / "sync", "-o", tmp_path / "none"], monkeypatch, capsys)
    assert done.returncode == 1 and "ltc.hd_channel: 5, but" in done.stderr and decoded == []


@pytest.mark.parametrize("case", ["IR size", "colour size", "depth 8-bit", "not an image"])
def test_a_kinect_image_that_cannot_be_used_is_refused_before_any_detection(small_product_session, tmp_path,
                                                                             monkeypatch, capsys, case):
    import cv2

    import dome_calib.kinect.calibrate as kinect_calibrate
    from dome_calib.cli import main

    root, truth = small_product_session
    kinect = tmp_path / "kinect"
    shutil.copytree(root / "kinect", kinect)
    node = sorted(p for p in kinect.iterdir() if p.is_dir())[0]
    frames = sorted(node.glob("ir_*.png"))
    last = frames[-1].name.removeprefix("ir_")
    target = {"IR size": node / f"ir_{last}", "colour size": node / f"color_{last}",
              "depth 8-bit": node / f"depth_{last}", "not an image": node / f"ir_{last}"}[case]
    if case == "IR size":
        cv2.imwrite(str(target), np.zeros((480, 640), np.uint8))
        words = "IR image is 640x480, expected 512x424"
    elif case == "colour size":
        cv2.imwrite(str(target), np.zeros((720, 1280, 3), np.uint8))
        words = "colour image is 1280x720, expected 1920x1080"
    elif case == "depth 8-bit":
        cv2.imwrite(str(target), np.zeros((424, 512), np.uint8))
        words = "not a single-channel 16-bit depth map"
    else:
        target.write_bytes(b"half a PNG")
        words = "cannot read the IR image"
    monkeypatch.setattr(kinect_calibrate, "detect_board", lambda *a, **k: pytest.fail("a board was detected first"))
    out = write_bundle(truth, tmp_path / "bundle")
    before = _files(out)
    done = run_in_process(main, "dome-calib", ["kinect", kinect, "--bundle", out], monkeypatch, capsys)
    errors = [ln for ln in done.stderr.splitlines() if "error:" in ln]
    assert done.returncode == 1 and len(errors) == 1 and f"{target}: {words}" in errors[0], done.stderr
    assert _files(out) == before


def test_timecode_decode_reads_every_header_before_decoding_any(tmp_path, monkeypatch):
    """A folder of takes where a late one is no audio, one has too few channels and one too low a sample rate:
    all three are known from their headers before the first file is decoded; the good one still decodes."""
    import timecode.cli.decode_command as decode_command

    src = Path(__file__).parent / "data" / "ltc" / "ltcsync_ltc.wav"
    folder = tmp_path / "takes"
    folder.mkdir()
    data, rate = sf.read(src, always_2d=True)
    sf.write(folder / "a_good.wav", np.repeat(data, 2, axis=1), rate)
    sf.write(folder / "b_mono.wav", data, rate)
    sf.write(folder / "c_4khz.wav", np.repeat(data[::12], 2, axis=1), 4000)
    (folder / "d_text.wav").write_text("notes, saved under the wrong name")
    events = []
    real_channels, real_decode = decode_command.channels_of, decode_command._decode_with_progress
    monkeypatch.setattr(decode_command, "channels_of", lambda p, *a: events.append(("header", p.name))
                        or real_channels(p, *a))
    monkeypatch.setattr(decode_command, "_decode_with_progress", lambda p, *a: events.append(("decode", p.name))
                        or real_decode(p, *a))
    result = decode_command.run_decode([folder], channel="1", fps="auto", fmt="csv", raw=None)
    first_decode = next(i for i, (what, _) in enumerate(events) if what == "decode")
    assert {name for what, name in events[:first_decode] if what == "header"} == {
        "a_good.wav", "b_mono.wav", "c_4khz.wav", "d_text.wav"}
    assert [name for what, name in events if what == "decode"] == ["a_good.wav"]
    assert result.n_decoded == 1 and len(result.failures) == 3
    text = "\n".join(result.failures)
    assert "b_mono.wav" in text and "--channel 1: the file has 1 channel(s)" in text
    assert "c_4khz.wav: sample rate 4000 Hz is outside the supported 8000-192000 Hz" in text
    assert "d_text.wav: not a readable audio file" in text
