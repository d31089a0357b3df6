"""The calibrate orchestration (dome_calib.pipeline) with the heavy stages replaced by exact stand-ins built from
the tiny nominal dome: resumability, world frame, outputs, change detection vs a prior, one-line errors."""
from __future__ import annotations

import json

import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

import dome_calib.pipeline.full as pipeline
from dome_calib.align import sim3_apply, transform_cameras
from dome_calib.ba.problem import BAProblem
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.camera import project
from dome_calib.executor import default_num_workers
from dome_calib.report.command import report_bundle
from dome_calib.pipeline.stages import observation_residuals, residuals_of
from dome_calib.pipeline.types import BAOutcome, SfmOutcome
from dome_calib.layout import nominal_dome

from .report_data import NO_PLOTS  # no test here reads a plot

SFM_FRAME = pycolmap.Sim3d(0.05, pycolmap.Rotation3d(Rotation.from_rotvec([0.2, 1.3, -0.4]).as_matrix()), [1, 2, 3])
NOISE_PX = 0.3
_TINY = nominal_dome("tiny", seed=0)  # cameras the tests need are asked of the preset, not assumed
UNCERTAIN, CERTAIN = sorted(_TINY.of_type("vga"))[4:6]
FAR = sorted(_TINY.of_type("hd"))[-1]


def _problem(truth, seed=0, noise_px=NOISE_PX):
    """Tent-like points seen by the truth cameras, observed with Gaussian noise, expressed in an SfM-like frame."""
    rng = np.random.default_rng(seed)
    X = rng.uniform([-60, -180, -60], [60, -20, 60], size=(400, 3))
    names = sorted(truth.cameras)
    s = truth.stacked(names)
    proj = project(X, s["R"], s["t_cm"], s["intr"], s["dist"])
    vis = proj.in_image(s["resolution"]) & proj.in_lens
    cam_idx, pt_idx = np.nonzero(vis)
    uv = proj.uv_px[cam_idx, pt_idx] + rng.normal(0, noise_px, size=(len(cam_idx), 2))
    cams = transform_cameras(truth.cameras, SFM_FRAME)
    return BAProblem.from_cameras(cams, {"scene_01": sim3_apply(SFM_FRAME, X)}, camera_index=cam_idx,
                                  point_index=pt_idx, uv_px=uv, camera_names=names)


def test_observation_residuals_are_the_added_noise():
    truth = nominal_dome("tiny", seed=0)
    problem = _problem(truth, noise_px=0.0)
    assert np.abs(observation_residuals(problem)).max() < 1e-6  # px: the frame change keeps pixels
    noisy = _problem(truth)
    res = residuals_of(noisy)
    assert len(res.residual_px) == noisy.n_observations
    assert np.sqrt(np.mean(res.residual_px ** 2)) == pytest.approx(NOISE_PX, rel=0.05)


@pytest.fixture
def capture(tmp_path):
    """A capture folder skeleton (capture.json, ground truth); the stand-in stages never read images."""
    truth = nominal_dome("tiny", seed=0)
    cap = tmp_path / "capture"
    (cap / "scenes" / "scene_01").mkdir(parents=True)
    names = sorted(truth.cameras) + ["01_24"]  # one camera that "saw no tent"
    (cap / "capture.json").write_text(json.dumps({"preset": "tiny", "seed": 0, "scenes": ["scene_01"],
                                                  "cameras": names}))
    write_bundle(truth, cap / "ground_truth")
    return cap, truth


@pytest.fixture
def stand_in_stages(monkeypatch, capture):
    _, truth = capture
    calls = {"sfm": 0, "ba": 0}

    def sfm(capture_dir, work_dir, *, prior, progress=True, scenes=None, executor=None, cameras=None):
        calls["sfm"] += 1
        return SfmOutcome(problem=_problem(truth), failures={"01_24": "saw no tent in any scene"})

    def ba(problem, *, progress=True):
        calls["ba"] += 1
        cams = {n: problem.camera(n) for n in problem.camera_names}
        return BAOutcome(problem=problem, cameras=cams, residuals=residuals_of(problem),
                         inlier=np.ones(problem.n_observations, bool),
                         center_sigma={UNCERTAIN: 2.0 * SFM_FRAME.scale, CERTAIN: 0.01})  # problem units

    monkeypatch.setattr(pipeline, "run_sfm_stage", sfm)
    monkeypatch.setattr(pipeline, "run_ba_stage", ba)
    return calls


def test_calibrate_writes_bundle_and_report_and_resumes(tmp_path, capture, stand_in_stages):
    cap, truth = capture
    out = tmp_path / "bundle"
    result = pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", report=NO_PLOTS))
    bundle = load_bundle(out)
    assert sorted(bundle.cameras) == sorted(truth.cameras)
    for n, c in truth.cameras.items():  # nominal-geometry frame = the synthetic truth frame
        assert np.linalg.norm(bundle.cameras[n].center_cm - c.center_cm) < 1e-6
    rep = json.loads((out / "report" / "report.json").read_text())
    assert rep["world_frame"]["reference"] == "nominal"
    assert {"name": "01_24", "type": None, "reasons": [{"code": "not_calibrated", "text": "not calibrated: saw no tent "
                                                                                  "in any scene"}]} in rep["to_check"]
    flagged = {row["name"]: row["reasons"] for row in rep["to_check"]}
    assert flagged[UNCERTAIN][0]["code"] == "position_uncertain" and CERTAIN not in flagged
    assert "position poorly determined (+-2.0 cm" in flagged[UNCERTAIN][0]["text"]
    assert rep["center_sigma_cm"][UNCERTAIN] == pytest.approx(2.0)
    text = pipeline.format_result(result)
    assert "calibrated 16 of 17 cameras (vga 8/9, hd 5/5, kinect-color 3/3)" in text
    assert "nominal dome geometry" in text and "01_24: not calibrated" in text
    assert stand_in_stages == {"sfm": 1, "ba": 1}
    n = default_num_workers()  # no --scheduler: the local pool (in this process when there is one core)
    assert rep["cluster"] == {"executor": "local", "processes": n, "on_this_machine": ON_THE_HEAD,
                              "description": f"local process pool, {n} processes" if n > 1
                              else "in the calling process (1 worker)"}
    again = pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", report=NO_PLOTS))
    assert stand_in_stages == {"sfm": 1, "ba": 1}  # both taken from the work folder
    assert again.resumed == ["sfm", "ba"]


ON_THE_HEAD = ["mapping", "merge", "bundle adjustment", "normalize"]


def test_scheduler_run_reports_where_each_stage_ran_also_when_resumed(tmp_path, capture, stand_in_stages,
                                                                      monkeypatch):
    """The report's "cluster" section: per stage the workers and their task counts, seconds and MB moved; a
    rerun that takes the SfM from the work folder reports the run that computed it."""
    from distributed import LocalCluster

    from projector.features import FeatureOptions, extract_image

    cap, truth = capture
    names = sorted(truth.cameras)

    def sfm(capture_dir, work_dir, *, prior, progress=True, scenes=None, executor=None, cameras=None):
        stand_in_stages["sfm"] += 1  # feature tasks on images no worker has: per-camera failures, as on one machine
        tasks = [(n, str(capture_dir / "scenes" / "scene_01" / f"{n}.png"), FeatureOptions()) for n in names]
        failed = {r.camera: r.failure for r in executor.map(extract_image, tasks)}
        assert sorted(failed) == names and all("image not found" in f for f in failed.values())
        return SfmOutcome(problem=_problem(truth), failures={"01_24": "saw no tent in any scene"})

    monkeypatch.setattr(pipeline, "run_sfm_stage", sfm)
    out = tmp_path / "bundle"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, protocol="tcp",
                      dashboard_address=":0") as lc:
        options = pipeline.CalibrateOptions(seq="test", scheduler=lc.scheduler_address, report=NO_PLOTS)
        result = pipeline.run_calibration(cap, out, options)
        section = json.loads((out / "report" / "report.json").read_text())["cluster"]
        assert section["executor"] == "dask" and section["scheduler"] == lc.scheduler_address
        assert list(section["stages"]) == ["features"] and section["on_this_machine"] == ON_THE_HEAD
        features = section["stages"]["features"]
        assert features["tasks"] == len(names) == sum(features["workers"].values())
        assert set(features["workers"]) <= {"0", "1"} and features["mb_moved"] > 0
        assert features["wall_s"] >= 0 and features["task_s"] >= 0
        assert f"features: {len(names)} tasks on" in pipeline.format_result(result)
        again = pipeline.run_calibration(cap, out, options)
        assert again.resumed == ["sfm", "ba"] and stand_in_stages["sfm"] == 1
        assert json.loads((out / "report" / "report.json").read_text())["cluster"] == section
    report_bundle(out)  # `dome-calib report` rewrites the report: where the stages ran, known only to calibrate, stays
    assert json.loads((out / "report" / "report.json").read_text())["cluster"] == section


def test_calibrate_with_prior_reports_moved_camera(tmp_path, capture, stand_in_stages):
    cap, truth = capture
    moved = dict(truth.cameras)
    c = moved["01_02"]
    moved["01_02"] = type(c)(**{**c.__dict__, "t_cm": c.t_cm + np.array([0.0, 3.0, 0.0])})
    prior = write_bundle(type(truth)(seq="old", cameras=moved), tmp_path / "prior")
    out = tmp_path / "bundle"
    result = pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(prior=prior, report=NO_PLOTS))
    assert sorted(result.changes) == ["01_02"]
    assert result.normalized.reference == "prior" and result.normalized.alignment.outliers == ["01_02"]
    assert "01_02: moved 3.0 cm" in pipeline.format_result(result)


def test_calibrate_cli_bad_input(tmp_path, dome_calib_cli):
    proc = dome_calib_cli("calibrate", tmp_path / "nope", "-o", tmp_path / "out")
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1 and "nope: not a folder" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_calibrate_cli_only_changed_needs_prior(tmp_path, capture):
    cap, _ = capture
    result = CliRunner().invoke(__import__("dome_calib.cli", fromlist=["app"]).app,
                                ["calibrate", str(cap), "-o", str(tmp_path / "out"), "--only-changed"])
    assert result.exit_code != 0
    assert "--only-changed needs --prior" in str(result.exception)


def test_ba_stage_on_noisy_observations():
    """The real bundle adjustment through the pipeline's adapter: RMS / noise near 1, nothing rejected wrongly."""
    from dome_calib.pipeline.stages import run_ba_stage

    truth = nominal_dome("tiny", seed=0)
    outcome = run_ba_stage(_problem(truth, seed=1))
    rms = np.sqrt(np.mean(outcome.residuals.residual_px ** 2))
    assert 0.8 * NOISE_PX < rms < 1.05 * NOISE_PX  # below sigma by the fitted-parameter share, never above
    assert outcome.stats["n_rejected"] < 0.01 * outcome.problem.n_observations
    assert sorted(outcome.cameras) == sorted(truth.cameras)


def test_prune_problem_drops_unusable_cameras():
    from dome_calib.pipeline.stages import prune_problem

    truth = nominal_dome("tiny", seed=0)
    problem = _problem(truth)
    far = problem.camera_position(FAR)
    problem.camera_params[far, 3:6] += [0.0, 0.0, 5e6]  # SfM put it 50 km away
    few = problem.camera_position("01_01")
    drop = np.nonzero(problem.camera_index == few)[0][10:]
    keep = np.setdiff1d(np.arange(problem.n_observations), drop)
    problem.camera_index, problem.point_index, problem.uv_px = (problem.camera_index[keep],
                                                                problem.point_index[keep], problem.uv_px[keep])
    problem.validate()
    pruned, dropped = prune_problem(problem)
    assert sorted(dropped) == sorted([FAR, "01_01"]) and "only 10 observations" in dropped["01_01"]
    assert FAR not in pruned.camera_names and pruned.n_cameras == problem.n_cameras - 2
    assert np.all(np.bincount(pruned.point_index) >= 2)
    # the remaining observations are the same pixels of the same points through the same cameras
    assert np.abs(observation_residuals(pruned)).max() < 5 * NOISE_PX


def test_center_sigma_flags_absolute_and_relative_to_the_dome():
    """A centre more uncertain than 0.5 cm (1 sigma) is flagged; so is one 5x less determined than the dome's
    median camera (the BA's covariance is only as good as its noise model) unless it is below a millimetre or
    too few cameras were solved to know the typical one (a quick recalibration)."""
    from dome_calib.pipeline.finish import RELATIVE_SIGMA_FLOOR_CM, center_sigma_flags

    options = pipeline.CalibrateOptions()
    dome = {f"01_{k:02d}": 0.08 for k in range(1, 20)}  # median 0.08 cm
    flags = center_sigma_flags(dome | {"50_05": 0.465, "00_15": 0.69, "50_08": 0.175}, options)
    assert sorted(flags) == ["00_15", "50_05"]
    assert {r.code for r in flags.values()} == {"position_uncertain"}
    assert "position poorly determined (+-0.7 cm" in flags["00_15"].text
    assert "much less determined than the other cameras' (+-0.47 cm, 1 sigma, 5.8 x the median 0.080 cm)" in \
        flags["50_05"].text
    tight = {n: s / 10 for n, s in dome.items()}  # a sub-mm dome: 5x its median is still below the floor
    assert center_sigma_flags(tight | {"50_05": 0.9 * RELATIVE_SIGMA_FLOOR_CM}, options) == {}
    assert center_sigma_flags({"50_05": 0.465, "01_01": 0.05, "01_02": 0.05}, options) == {}  # too few to compare
    assert list(center_sigma_flags({"50_05": 0.6, "01_01": 0.05}, options)) == ["50_05"]  # absolute: always
