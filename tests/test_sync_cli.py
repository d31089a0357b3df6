"""`timecode sync` end to end: encoder -> audio files -> real decoder -> clock fits -> bundle files; and its errors."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from typer.testing import CliRunner

from dome_calib.ownership import RECORD
from dome_calib.bundle_io import load_bundle
from dome_calib.panoptic_io import read_ksynctables, read_synctables
from timecode.cli import app
from timecode.encoder import EncoderOptions, encode_ltc_labels
from timecode.labels import frames_to_labels
from timecode.rates import RATE_25
from dome_calib.synth.sync_session import SynthSessionOptions, make_session

CALIBRATION = Path(__file__).parent / "data" / "panoptic" / "calibration_160906_band1.json"
VGA_HD_RMS_US = 10.0  # the sync aim: VGA-HD offsets within 10 us RMS


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, object]:
    folder = tmp_path_factory.mktemp("sync_session")
    truth = make_session(folder, SynthSessionOptions(duration_s=3.0, n_kinects=2, kinect_missing_audio=("KINECTNODE2",),
                                                     vga_start="23:59:58:00", hd_start="23:59:58;00", seed=4))
    return folder, truth


def _cli(*args: str) -> subprocess.CompletedProcess:
    code = "from timecode.cli import main; main()"
    return subprocess.run([sys.executable, "-c", code, "sync", *args], capture_output=True, text=True, timeout=120)


def test_sync_into_existing_calibration_bundle(session, tmp_path):
    folder, truth = session
    bundle = tmp_path / "bundle"
    bundle.mkdir()
    shutil.copy(CALIBRATION, bundle / CALIBRATION.name)
    result = CliRunner().invoke(app, ["sync", str(folder), "-o", str(bundle)])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0].split()[:2] == ["stream", "frames"] and lines[1].split()[0] == "vga"
    assert any(line.startswith("NOT SYNCED: KINECTNODE2") for line in lines)
    b = load_bundle(bundle)  # calibration kept, tables added under the bundle's seq
    assert b.seq == "160906_band1" and len(b.cameras) == 520
    for key in ("vga", "hd"):
        err_us = (b.sync.streams[key].times_of(truth.index[key]) - truth.univ_ms[key]) * 1e3
        assert np.sqrt(np.mean(err_us**2)) < VGA_HD_RMS_US, key
    assert list(b.sync.kinect_color) == ["KINECTNODE1"]
    jitter = np.sqrt(np.mean(truth.jitter_us["KINECTNODE1/color"] ** 2))
    err_us = (b.sync.kinect_color["KINECTNODE1"].univ_time_ms - truth.univ_ms["KINECTNODE1/color"]) * 1e3
    assert np.sqrt(np.mean(err_us**2)) < 1.3 * jitter + 60.0
    report = json.loads((bundle / "report" / "sync.json").read_text())
    assert report["kinect"]["KINECTNODE2"]["status"] == "not synced"
    assert [e["kind"] for e in report["channels"]["hd"]["events"]] == ["midnight"]
    assert report["channels"]["vga"]["residual_rms_us"] < 5.0


def test_sync_into_new_folder_and_seq_mismatch(session, tmp_path):
    folder, truth = session
    result = CliRunner().invoke(app, ["sync", str(folder), "-o", str(tmp_path / "out"), "--seq", "take7"])
    assert result.exit_code == 0, result.output
    streams = read_synctables(tmp_path / "out" / "synctables_take7.json")
    color, depth = read_ksynctables(tmp_path / "out" / "ksynctables_take7.json")
    np.testing.assert_array_equal(streams["vga"].index, truth.index["vga"])
    assert list(depth) == ["KINECTNODE1"]
    assert [p.name for p in (tmp_path / "out").glob(".*")] == [RECORD]  # no temp file left
    shutil.copy(CALIBRATION, tmp_path / "out" / CALIBRATION.name)
    proc = _cli(str(folder), "-o", str(tmp_path / "out"), "--seq", "take8")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1
    assert "holds calibration_160906_band1.json; --seq take8 differs" in proc.stderr


def _variant(session: Path, tmp_path: Path, vga_channel: np.ndarray | None = None, doc_edit=None) -> Path:
    folder = tmp_path / "variant"
    shutil.copytree(session, folder)
    if vga_channel is not None:
        data, fs = sf.read(folder / "ltc.wav", always_2d=True)
        data[:, 0] = vga_channel[: data.shape[0]]
        sf.write(folder / "ltc.wav", data.astype(np.float32), fs, subtype="FLOAT")
    if doc_edit is not None:
        doc = json.loads((folder / "session.json").read_text())
        doc_edit(doc)
        (folder / "session.json").write_text(json.dumps(doc))
    return folder


def _main(monkeypatch, capsys, *args: str) -> tuple[int, str]:
    """Run ``timecode sync ARGS`` in-process through run_cli (as the installed command does): (exit code, stderr)."""
    from timecode.cli import main

    monkeypatch.setattr(sys, "argv", ["timecode", "sync", *args])
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main()
    return int(exc.value.code or 0), capsys.readouterr().err


def test_errors_are_one_line(session, tmp_path, monkeypatch, capsys):
    folder, _ = session
    n = sf.info(str(folder / "ltc.wav")).frames
    rng = np.random.default_rng(0)
    cases = []
    silent = _variant(folder, tmp_path / "a", vga_channel=rng.normal(0, 1e-3, n))
    cases.append((silent, r"ltc.wav channel 0 \(VGA LTC\): no LTC"))
    labels = frames_to_labels(rng.permutation(np.arange(70)) * 97 + 36000 * 25, RATE_25)  # valid but scrambled labels
    scrambled = encode_ltc_labels(labels, fps=RATE_25, sample_rate=48000, options=EncoderOptions(
        start_offset_samples=100.0, level_dbfs=-12.0)).samples
    cases.append((_variant(folder, tmp_path / "b", vga_channel=np.pad(scrambled, (0, n))), "never locks"))
    far = _variant(folder, tmp_path / "c", doc_edit=lambda d: d["streams"]["vga"].update(ref_timecode="08:00:00:00"))
    cases.append((far, "stream vga: .*do not overlap"))
    cases.append((tmp_path / "absent", "not a session folder"))
    wrong = _variant(folder, tmp_path / "d", doc_edit=lambda d: d["ltc"].update(hd_channel=2))
    cases.append((wrong, r"session.json: ltc.hd_channel: 2, but \S*ltc.wav has 2 channel\(s\) \(numbered from 0\)"))
    for path, message in cases:
        out = tmp_path / "out"
        code, err = _main(monkeypatch, capsys, str(path), "-o", str(out))
        assert code == 1, err
        assert err.startswith("timecode: error: ") and err.count("\n") == 1, err
        assert re.search(message, err), err
        assert not out.exists()  # nothing written, not even partially
    code, err = _main(monkeypatch, capsys, str(folder), "-o", str(tmp_path / "strict"), "--strict-kinect")
    assert code == 1 and "KINECTNODE2: no audio recorded" in err
    assert not (tmp_path / "strict").exists()


def test_decoder_end_to_end_jump_restart_dropped_frames(tmp_path):
    from timecode.sync.pipeline import sync_session

    truth = make_session(tmp_path, SynthSessionOptions(duration_s=4.0, n_kinects=1, vga_jump_at_s=1.0,
                                                       hd_jump_at_s=3.0, restart_at_s=2.0, dropped_frames=4,
                                                       hd_timecode_every=0, snr_db=15.0, seed=9))
    result = sync_session(tmp_path)
    assert [e["kind"] for e in sorted(result.vga.events, key=lambda e: e["tick"])] == ["jump", "restart"]
    assert sorted(e["kind"] for e in result.hd.events) == ["jump", "restart"]
    for key in ("vga", "hd"):
        table = result.tables.streams[key]
        np.testing.assert_array_equal(table.index, truth.index[key])
        assert np.sqrt(np.mean(((table.univ_time_ms - truth.univ_ms[key]) * 1e3) ** 2)) < VGA_HD_RMS_US, key
