"""`dome-calib demo`: wiring and what it prints, with the synthetic capture and the heavy stages replaced by the
exact stand-ins of test_calibrate (the real end-to-end run is `make demo`, timed in bench/dome.py)."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

import dome_calib.pipeline.demo as demo
import dome_calib.pipeline.full as pipeline
from dome_calib.pipeline.stages import residuals_of
from dome_calib.pipeline.types import BAOutcome, SfmOutcome
from dome_calib.synth.detector import DetectorModel
from dome_calib.synth.group import GroupOptions
from dome_calib.synth.group_session import GroupSessionOptions, make_group_session, session_span_ms

from .test_calibrate import _problem


def test_demo_prints_what_a_technician_needs(tmp_path, monkeypatch, small_product_session):
    """Every pillar's lines, on conftest's small session (one Kinect, 3 s) with SfM and BA stood in by the truth."""
    import shutil

    root, truth = small_product_session

    def fake_synth(session, preset, scenes, seed, progress=True, people=0):
        shutil.copytree(root, session)
        assert people == 5  # --people reaches the synthesis
        start_ms, duration_ms = session_span_ms(truth)  # the group as dome_calib.synth.session writes it
        make_group_session(session / "group", truth, GroupSessionOptions(
            group=GroupOptions(n_people=people, scenario="mixed", start_ms=start_ms, duration_ms=duration_ms,
                               seed=seed), detector=DetectorModel(seed=seed),
            cameras=[n for n, c in truth.cameras.items() if c.type != "kinect-color" or n == "50_04"]))
        return 1.0

    def fake_ba(problem, *, progress=True):
        return BAOutcome(problem=problem, cameras={n: problem.camera(n) for n in problem.camera_names},
                         residuals=residuals_of(problem), inlier=np.ones(problem.n_observations, bool))

    monkeypatch.setattr(demo, "synthesize", fake_synth)
    monkeypatch.setattr(pipeline, "run_sfm_stage", lambda *a, **k: SfmOutcome(problem=_problem(truth)))
    monkeypatch.setattr(pipeline, "run_ba_stage", fake_ba)
    from dome_calib.cli import app

    result = CliRunner().invoke(app, ["demo", "--preset", "tiny", "--people", "5", "-o", str(tmp_path / "demo")])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "synthetic 'tiny' dome, 16 cameras" in out
    assert "calibrated 16 of 16 cameras (vga 8/8, hd 5/5, kinect-color 3/3)" in out
    rms_px = float(re.search(r"reprojection RMS ([0-9.]+) px", out).group(1))
    assert rms_px == pytest.approx(0.3, abs=0.02)  # the stand-in's 0.3 px noise per coordinate
    assert "centre error   0.00 mm median" in out  # exact stand-in: the truth comes back
    assert "worst cameras:" in out
    assert f"report: {tmp_path / 'demo' / 'bundle' / 'report'}/index.html (open it in a browser)" in out
    assert (tmp_path / "demo" / "bundle" / "report" / "index.html").exists()
    # the other pillars: Kinect against the truth, each stream's sync error, the person from every stream
    assert "Kinect depth-to-colour (dome-calib kinect, against the truth):\n  KINECTNODE4  translation" in out
    sync = [ln.split() for ln in out.splitlines() if " frames  error " in ln]
    assert [r[0] for r in sync] == ["vga", "hd", "KINECTNODE4/color", "KINECTNODE4/depth"]
    assert all(r[-1] == "ok" for r in sync), sync
    person = {ln.split("MPJPE")[0].strip(): float(ln.split("MPJPE")[1].split()[0]) for ln in out.splitlines()
              if "MPJPE" in ln and "mm session-aligned" in ln}
    # exact cameras: the produced bundle differs from the truth only by its sync tables (from the audio)
    assert person["produced bundle, all streams"] == pytest.approx(person["ground-truth bundle, all"], rel=0.02)
    assert person["produced bundle, all streams"] < person["produced bundle, VGA only"]
    _check_group(out, tmp_path / "demo")


def _check_group(out: str, demo_dir):
    """The group's lines against the truth: 5 people of the "mixed" scenario (two walking past each other, a
    conversation, one crouching: none leaves), reconstructed with the produced bundle from 14 cameras' OpenPose
    files (8 VGA, 5 HD, the one synced Kinect)."""
    from dome_calib.recon.people.matching import skeleton_distance_cm
    from dome_calib.body3d_scene import read_scene

    head = re.search(r"group \(5 people, scenario mixed; OpenPose BODY_25 detections of 14 cameras, no ids; "
                     r"dome-calib reconstruct with the produced bundle, (\d+) VGA frames", out)
    assert head, out
    frames = int(head.group(1))
    assert frames >= 40  # the 3 s session's VGA frames inside every stream's span
    per = re.search(r"people per frame +([0-9.]+) found of ([0-9.]+) true \(mean; (\d+) of (\d+) body-frames\), "
                    r"all found in (\d+) of (\d+) frames; (\d+) ids", out)
    found, true, matched, true_frames, all_found, n, ids = (float(x) for x in per.groups())
    assert true == 5.0 and true_frames == 5 * frames and n == frames  # everybody stays in the dome
    assert matched >= 0.95 * true_frames and all_found >= 0.8 * frames
    assert found == pytest.approx(matched / frames, abs=0.005)
    assert ids == 5  # one id per person, none given twice
    f8 = re.search(r"found where >= 8 views see the person: ([0-9.]+) % of (\d+) body-frames \(oracle ([0-9.]+) %\)",
                   out)
    # few views per joint: the misses are bodies with a few gross joints (> 20 cm mean), the oracle's too
    assert float(f8.group(1)) >= 97.0 and float(f8.group(1)) >= float(f8.group(3)) - 1.0
    mp = re.search(r"MPJPE ([0-9.]+) cm session-aligned, oracle ([0-9.]+) cm: ratio ([0-9.]+) \(aim <= 1.10\)  ok;  "
                   r"world ([0-9.]+) cm", out)
    ours, oracle, ratio, world = (float(x) for x in mp.groups())
    # 14 views: a few cm (1.5 with the body over time). The ratio is printed from the unrounded values: the two
    # printed to 0.01 cm bound it within 0.005 (1 + ours / oracle) / oracle, the ratio's own 3 decimals 0.0005 more
    rounding = 0.005 * (1.0 + ours / oracle) / oracle + 0.0005
    assert 0.5 < ours < 8.0 and ratio == pytest.approx(ours / oracle, abs=rounding)
    assert world >= ours - 0.01  # the alignment only takes the produced world's placement out
    assert re.search(r"false bodies \d+ body-frames, 0 lasting over 3 frames \(aim 0\)  ok", out)
    assert "identity switches 0 (0.0 per 1,000 body-frames, aim <= 1)  ok" in out
    # the files themselves, against the truth: every true person has a body within 10 cm (median joint distance)
    # in most frames; the produced world is the truth's (exact stand-in cameras)
    truth = json.loads((demo_dir / "session" / "group" / "group_truth.json").read_text())
    close = total = 0
    for f in truth["frames"]:
        _, bodies = read_scene(demo_dir / "people" / f"body3DScene_{f['frame']:08d}.json")
        X = np.array([np.where(b[:, 3:4] >= 0, b[:, :3], np.nan) for b in bodies.values()]).reshape(-1, 19, 3)
        T = np.array([b["joints19"] for b in f["bodies"]])
        d = skeleton_distance_cm(T, X).min(axis=1) if len(X) else np.full(len(T), np.inf)
        close += int((d < 10.0).sum())
        total += len(T)
    assert total == true_frames and close >= 0.97 * total
    cams = json.loads((demo_dir / "people" / "cameras.json").read_text())
    assert len(cams["cameras"]) == 14 and cams["flagged"] == []



def test_demo_bad_preset(dome_calib_cli):
    proc = dome_calib_cli("demo", "--preset", "huge")
    assert proc.returncode == 1
    assert proc.stderr == 'dome-calib: error: --preset "huge": expected "tiny" or "panel" or "full"\n'


def test_demo_bad_group_size(dome_calib_cli, tmp_path):
    proc = dome_calib_cli("demo", "--people", "11", "-o", str(tmp_path / "demo"))
    assert proc.returncode == 1
    assert proc.stderr == "dome-calib: error: --people 11: expected an integer >= 0 and <= 10\n"
    assert not (tmp_path / "demo").exists()
