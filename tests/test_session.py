"""`dome-calib session`: calibrate + kinect + sync into one bundle from one small synthetic session.

The spatial calibration's heavy stages are replaced by the exact stand-ins of test_calibrate (the real run is
`make demo` and bench/product.py); the Kinect calibration and the sync run for real on the small session of
conftest.small_product_session: one Kinect (KINECTNODE4 on the dome's 50_04) with 6 good board frames, 3 s of
LTC audio.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

import dome_calib.pipeline.full as pipeline
from dome_calib.ownership import RECORD
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.pipeline.stages import residuals_of
from dome_calib.pipeline.types import BAOutcome, SfmOutcome
from dome_calib.synth.sync_session import load_truth

from .test_calibrate import _problem

VGA_HD_AIM_US = 10.0  # the aim for VGA and HD frame times against the truth


@pytest.fixture
def small_session(small_product_session):
    return small_product_session


@pytest.fixture
def stand_ins(monkeypatch, small_session):
    _, truth = small_session

    def fake_ba(problem, *, progress=True):
        return BAOutcome(problem=problem, cameras={n: problem.camera(n) for n in problem.camera_names},
                         residuals=residuals_of(problem), inlier=np.ones(problem.n_observations, bool))

    monkeypatch.setattr(pipeline, "run_sfm_stage", lambda *a, **k: SfmOutcome(problem=_problem(truth)))
    monkeypatch.setattr(pipeline, "run_ba_stage", fake_ba)


def test_session_end_to_end(small_session, stand_ins, dome_calib_cli, tmp_path):
    root, truth = small_session
    out = tmp_path / "bundle"
    proc = dome_calib_cli("session", root, "-o", out)
    assert proc.returncode == 0, proc.stderr
    for heading in ("calibration (cameras):", "kinect (depth to colour):", "sync (universal time):", "to check:"):
        assert heading in proc.stdout
    assert "calibrated 16 of 16 cameras" in proc.stdout
    # one bundle, every pillar, loadable
    bundle = load_bundle(out)
    assert bundle.seq == "sess" and sorted(bundle.kinect.sensors) == ["KINECTNODE4"]
    assert set(bundle.sync.streams) == {"vga", "hd"} and set(bundle.sync.kinect_color) == {"KINECTNODE4"}
    # the Panoptic toolbox layout: the four files of one seq with the fields its readers take
    names = sorted(p.name for p in out.glob("*.json") if p.name != RECORD)
    assert names == ["calibration_sess.json", "kcalibration_sess.json", "ksynctables_sess.json",
                     "synctables_sess.json"]
    cal = json.loads((out / "calibration_sess.json").read_text())
    assert {"name", "type", "resolution", "K", "distCoef", "R", "t"} <= set(cal["cameras"][0])
    kcal = json.loads((out / "kcalibration_sess.json").read_text())
    assert {"K_depth", "M_depth", "M_color", "M_world2sensor"} <= set(kcal["sensors"][0])
    # sync against the simulated truth: VGA/HD within the aim, Kinect colour within 4 jitter sigmas
    t = load_truth(root / "sync")
    for key in ("vga", "hd"):
        table = bundle.sync.streams[key]
        _, i, j = np.intersect1d(table.index, t.index[key], return_indices=True)
        err_us = (table.univ_time_ms[i] - t.univ_ms[key][j]) * 1e3
        assert i.size > 50 and np.sqrt(np.mean(err_us ** 2)) < VGA_HD_AIM_US
    kc = bundle.sync.kinect_color["KINECTNODE4"]
    _, i, j = np.intersect1d(kc.index, t.index["KINECTNODE4/color"], return_indices=True)
    err_us = (kc.univ_time_ms[i] - t.univ_ms["KINECTNODE4/color"][j]) * 1e3
    assert np.sqrt(np.mean(err_us ** 2)) < 1.5 * np.sqrt(np.mean(t.jitter_us["KINECTNODE4/color"][j] ** 2)) + 50
    # one report, per pillar what was achieved and what to check (the dome's other Kinects have no boards)
    report = json.loads((out / "report" / "session.json").read_text())
    assert set(report["pillars"]) == {"calibration", "kinect", "sync"}
    assert report["pillars"]["calibration"]["to_check"] == []
    assert report["pillars"]["kinect"]["to_check"] == [
        f"{n}: Kinect colour camera without checkerboard pairs (no depth calibration)" for n in ("50_05", "50_09")]
    assert "50_05: Kinect colour camera without checkerboard pairs" in proc.stdout
    assert (out / "report" / "dome.png").exists() and (out / "report" / "sync.json").exists()
    assert not list(tmp_path.glob(".bundle.*"))  # no staging left behind


def _one_line_error(proc, *needles):
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
    for n in needles:
        assert n in proc.stderr, proc.stderr


def test_session_missing_part(tmp_path, dome_calib_cli):
    (tmp_path / "s" / "capture").mkdir(parents=True)
    (tmp_path / "s" / "sync").mkdir()
    _one_line_error(dome_calib_cli("session", tmp_path / "s", "-o", tmp_path / "b"), "kinect", "missing")
    assert not (tmp_path / "b").exists()


def test_session_not_a_folder(tmp_path, dome_calib_cli):
    _one_line_error(dome_calib_cli("session", tmp_path / "nope", "-o", tmp_path / "b"), "session folder not found")


def test_session_output_is_a_file(small_session, dome_calib_cli, tmp_path):
    root, _ = small_session
    (tmp_path / "b").write_text("x")
    _one_line_error(dome_calib_cli("session", root, "-o", tmp_path / "b"), str(tmp_path / "b"), "not a folder")


def test_session_audio_not_audio(small_session, stand_ins, dome_calib_cli, tmp_path):
    """LTC audio that is not audio: refused before the calibration, one line naming file and field."""
    import shutil

    root, truth = small_session
    broken = tmp_path / "sess"
    shutil.copytree(root, broken)
    (broken / "sync" / "ltc.wav").write_bytes(b"not audio at all")
    out = tmp_path / "bundle"
    write_bundle(truth, out)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    _one_line_error(dome_calib_cli("session", broken, "-o", out), "ltc.wav", "ltc.file",
                    "not a readable audio file (Format not recognised.)")
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert not (tmp_path / "bundle.work").exists()  # refused before any work


def test_session_late_failure_keeps_the_old_bundle(small_session, stand_ins, dome_calib_cli, tmp_path):
    """A pillar that fails after the calibration (here the sync: the LTC audio is silence, no timecode on it)
    fails the run with one error line; the bundle already in OUT is left exactly as it was."""
    import shutil

    import soundfile as sf

    root, truth = small_session
    broken = tmp_path / "sess"
    shutil.copytree(root, broken)
    sf.write(broken / "sync" / "ltc.wav", np.zeros((48000, 2), np.float32), 48000)
    out = tmp_path / "bundle"
    write_bundle(truth, out)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    proc = dome_calib_cli("session", broken, "-o", out)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and proc.stderr.splitlines()[-1] == errors[0] and "no LTC" in errors[0], proc.stderr
    assert "dome-calib session: sync" in proc.stderr  # it failed late, after the calibration and the Kinect
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert not list(tmp_path.glob(".bundle.*"))


def test_session_bad_session_json(small_session, dome_calib_cli, tmp_path):
    import shutil

    root, _ = small_session
    broken = tmp_path / "sess"
    shutil.copytree(root, broken)
    doc = json.loads((broken / "sync" / "session.json").read_text())
    doc["ltc"]["vga_rate"] = "17"
    (broken / "sync" / "session.json").write_text(json.dumps(doc))
    _one_line_error(dome_calib_cli("session", broken, "-o", tmp_path / "b"), "session.json")
    assert not (tmp_path / "b").exists()
