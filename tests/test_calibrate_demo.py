"""`dome-calib demo`: wiring and what it prints, with the synthetic capture and the heavy stages replaced by the
exact stand-ins of test_calibrate (the real end-to-end run is `make demo`, timed in bench/dome.py)."""
from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

import dome_calib.demo as demo
import dome_calib.pipeline as pipeline
from dome_calib.bundle_io import write_bundle
from dome_calib.pipeline_stages import BAOutcome, SfmOutcome, residuals_of
from dome_calib.layout import nominal_dome

from .test_calibrate import _problem


def test_demo_prints_what_a_technician_needs(tmp_path, monkeypatch):
    truth = nominal_dome("tiny", seed=0)

    def fake_synth(capture, preset, scenes, seed, progress=True):
        (capture / "scenes" / "scene_01").mkdir(parents=True)
        (capture / "capture.json").write_text(json.dumps({"preset": preset, "seed": seed, "scenes": ["scene_01"],
                                                          "cameras": sorted(truth.cameras)}))
        write_bundle(truth, capture / "ground_truth")
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
    assert "reprojection RMS 0.3" in out  # the stand-in's 0.3 px noise
    assert "centre error   0.00 mm median" in out  # exact stand-in: the truth comes back
    assert "worst cameras:" in out
    assert f"report: {tmp_path / 'demo' / 'bundle' / 'report'}/dome.png" in out
    assert (tmp_path / "demo" / "bundle" / "report" / "dome.png").exists()


def test_demo_bad_preset(dome_calib_cli):
    proc = dome_calib_cli("demo", "--preset", "huge")
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1 and "unknown preset 'huge'" in proc.stderr
