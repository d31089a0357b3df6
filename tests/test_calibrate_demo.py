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

from .test_calibrate import _problem


def test_demo_prints_what_a_technician_needs(tmp_path, monkeypatch, small_product_session):
    """Every pillar's lines, on conftest's small session (one Kinect, 3 s) with SfM and BA stood in by the truth."""
    import shutil

    root, truth = small_product_session

    def fake_synth(session, preset, scenes, seed, progress=True):
        shutil.copytree(root, session)
        return 1.0

    def fake_ba(problem, *, progress=True):
        return BAOutcome(problem=problem, cameras={n: problem.camera(n) for n in problem.camera_names},
                         residuals=residuals_of(problem), inlier=np.ones(problem.n_observations, bool))

    monkeypatch.setattr(demo, "synthesize", fake_synth)
    monkeypatch.setattr(pipeline, "run_sfm_stage", lambda *a, **k: SfmOutcome(problem=_problem(truth)))
    monkeypatch.setattr(pipeline, "run_ba_stage", fake_ba)
    from dome_calib.cli import app

    result = CliRunner().invoke(app, ["demo", "--preset", "tiny", "-o", str(tmp_path / "demo")])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "synthetic 'tiny' dome, 16 cameras" in out
    assert "calibrated 16 of 16 cameras (vga 8/8, hd 5/5, kinect-color 3/3)" in out
    rms_px = float(re.search(r"reprojection RMS ([0-9.]+) px", out).group(1))
    assert rms_px == pytest.approx(0.3, abs=0.02)  # the stand-in's 0.3 px noise per coordinate
    assert "centre error   0.00 mm median" in out  # exact stand-in: the truth comes back
    assert "worst cameras:" in out
    assert f"report: {tmp_path / 'demo' / 'bundle' / 'report'}/index.html (open it in a browser)" in out
    assert (tmp_path / "demo" / "bundle" / "report" / "dome.png").exists()
    # the other pillars: Kinect against the truth, each stream's sync error, the person from every stream
    assert "Kinect depth-to-colour (dome-calib kinect, against the truth):\n  KINECTNODE4  translation" in out
    sync = [ln.split() for ln in out.splitlines() if " frames  error " in ln]
    assert [r[0] for r in sync] == ["vga", "hd", "KINECTNODE4/color", "KINECTNODE4/depth"]
    assert all(r[-1] == "ok" for r in sync), sync
    person = {ln.split("MPJPE")[0].strip(): float(ln.split("MPJPE")[1].split()[0]) for ln in out.splitlines()
              if "MPJPE" in ln}
    # exact cameras: the produced bundle differs from the truth only by its sync tables (from the audio)
    assert person["produced bundle, all streams"] == pytest.approx(person["ground-truth bundle, all"], rel=0.02)
    assert person["produced bundle, all streams"] < person["produced bundle, VGA only"]


def test_demo_bad_preset(dome_calib_cli):
    proc = dome_calib_cli("demo", "--preset", "huge")
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1 and "unknown preset 'huge'" in proc.stderr
