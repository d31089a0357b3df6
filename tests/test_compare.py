"""Similarity alignment (dome_calib.align), comparison and change detection (dome_calib.compare), and the
`dome-calib compare` command, on the real Panoptic calibration and perturbed copies."""
from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from dome_calib.align import AlignmentError, AlignOptions, align_cameras, align_points, sim3_apply, transform_cameras
from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.camera import intr_to_K, project
from dome_calib.rotation import rotation_angle_deg
from dome_calib.compare import ChangeOptions, compare_cameras, detect_changes, format_comparison
from dome_calib.reasons import ReasonCode

REAL_CALIBRATION = Path(__file__).parent / "data" / "panoptic" / "calibration_160906_band1.json"

SIM = pycolmap.Sim3d(0.013, pycolmap.Rotation3d(Rotation.from_rotvec([0.4, -1.1, 2.0]).as_matrix()), [3.0, -7.0, 1.5])


def _moved(cam, rng, shift_cm, angle_deg):
    """Camera moved by shift_cm along a random direction and rotated by angle_deg about a random axis."""
    d = rng.normal(size=3)
    axis = rng.normal(size=3)
    dR = Rotation.from_rotvec(np.radians(angle_deg) * axis / np.linalg.norm(axis)).as_matrix()
    R = dR @ cam.R
    center = cam.center_cm + shift_cm * d / np.linalg.norm(d)
    return dataclasses.replace(cam, R=R, t_cm=-R @ center)


def test_align_recovers_known_similarity(real_cameras):
    src = transform_cameras(real_cameras, SIM)  # arbitrary SfM-like frame, scale 0.013
    result = align_cameras(src, real_cameras)
    back = transform_cameras(src, result.tgt_from_src)
    assert len(result.inliers) == len(real_cameras)
    assert result.tgt_from_src.scale == pytest.approx(1 / 0.013, rel=1e-9)
    for name, cam in real_cameras.items():
        assert np.linalg.norm(back[name].center_cm - cam.center_cm) < 1e-6  # cm
        assert rotation_angle_deg(back[name].R, cam.R) < 1e-6


def test_transform_keeps_pixels(real_cameras):
    """Moving world points and cameras by the same similarity leaves every projection unchanged."""
    names = sorted(real_cameras)[:20]
    cams = {n: real_cameras[n] for n in names}
    X = np.random.default_rng(0).uniform(-80, 80, size=(50, 3)) + [0, -100, 0]
    moved = transform_cameras(cams, SIM)
    a, b = Bundle(seq="a", cameras=cams).stacked(names), Bundle(seq="b", cameras=moved).stacked(names)
    uv_a = project(X, a["R"], a["t_cm"], a["intr"], a["dist"]).uv_px
    uv_b = project(sim3_apply(SIM, X), b["R"], b["t_cm"], b["intr"], b["dist"]).uv_px
    np.testing.assert_allclose(uv_b, uv_a, atol=1e-7)  # px


def test_align_ignores_moved_cameras(real_cameras):
    rng = np.random.default_rng(1)
    moved_names = sorted(real_cameras)[100:115]
    cams = {n: (_moved(c, rng, 8.0, 1.0) if n in moved_names else c) for n, c in real_cameras.items()}
    result = align_cameras(transform_cameras(cams, SIM), real_cameras, AlignOptions(max_error_cm=1.0))
    assert sorted(result.outliers) == moved_names
    assert result.inlier_rms < 1e-6


def test_align_rigid_keeps_scale_one(real_cameras):
    rigid = pycolmap.Sim3d(1.0, SIM.rotation, [10.0, 0.0, -4.0])
    result = align_cameras(transform_cameras(real_cameras, rigid), real_cameras, AlignOptions(estimate_scale=False))
    assert result.tgt_from_src.scale == 1.0
    assert result.inlier_rms < 1e-6


def test_align_bad_inputs(real_cameras):
    two = dict(list(real_cameras.items())[:2])
    with pytest.raises(AlignmentError, match="only 2 cameras in common"):
        align_cameras(two, real_cameras)
    with pytest.raises(AlignmentError, match="collinear"):
        align_points(np.outer(np.arange(5.0), [1, 2, 3]), np.outer(np.arange(5.0), [1, 2, 3]))
    with pytest.raises(AlignmentError, match="expected two"):
        align_points(np.zeros((4, 2)), np.zeros((4, 2)))


def test_compare_identical_is_zero(real_cameras):
    cmp = compare_cameras(transform_cameras(real_cameras, SIM), real_cameras)
    s = cmp.summary()["all"]
    assert s["count"] == len(real_cameras)
    assert s["center_cm_max"] < 1e-6 and s["rotation_deg_max"] < 1e-6
    assert s["focal_pct_max"] == 0.0 and s["distortion_px_max"] == 0.0


def test_compare_measures_known_errors(real_cameras):
    cams = dict(real_cameras)
    c = cams["01_01"]
    intr = c.intr * [1.02, 1.02, 1, 1] + [0, 0, 3.0, 4.0]  # focal +2 %, principal point 5 px
    cams["01_01"] = dataclasses.replace(c, K=intr_to_K(intr), dist=c.dist + [0.01, 0, 0, 0, 0])
    cams["00_03"] = _moved(cams["00_03"], np.random.default_rng(2), 3.0, 0.0)
    del cams["50_02"]
    cmp = compare_cameras(cams, real_cameras)
    e = cmp.cameras["01_01"]
    assert e.focal_pct == pytest.approx(2.0, abs=1e-9)
    assert e.principal_px == pytest.approx(5.0, abs=1e-9)
    # k1 + 0.01 displaces the image corner (r ~ 0.57 normalised) by about f * 0.01 * r^3 ~ 1.4 px
    assert 0.5 < e.distortion_px < 3.0
    assert cmp.cameras["00_03"].center_cm == pytest.approx(3.0, abs=0.05)  # one of 519 barely moves the fit
    assert cmp.only_in_reference == ["50_02"]
    assert cmp.worst(1)[0].name == "00_03"
    text = format_comparison(cmp)
    assert "worst: 00_03" in text and "missing from the estimate: 1" in text


def test_detect_changes_finds_exactly_the_changed_panel(real_cameras):
    """Issue 8's quick-recalibration scenario: one panel moved 2-5 cm and rotated 1-2 deg, one camera replaced."""
    rng = np.random.default_rng(3)
    cams = dict(real_cameras)
    panel = sorted(n for n in cams if n.startswith("07_"))
    for n in panel:
        cams[n] = _moved(cams[n], rng, rng.uniform(2, 5), rng.uniform(1, 2))
    replaced = cams["07_05"]
    cams["07_05"] = dataclasses.replace(replaced, K=intr_to_K(replaced.intr * [0.96, 0.96, 1, 1]))
    # the new calibration comes back in an arbitrary rigid frame, plus 0.5 mm noise on the unchanged cameras
    noise = {n: _moved(c, rng, 0.05, 0.01) if n not in panel else c for n, c in cams.items()}
    new = transform_cameras(noise, pycolmap.Sim3d(1.0, SIM.rotation, [20.0, 5.0, -3.0]))
    changes = detect_changes(new, real_cameras, ChangeOptions())
    assert sorted(changes) == panel
    assert ReasonCode.INTRINSICS_CHANGED in [r.code for r in changes["07_05"].reasons]
    assert all(changes[n].reasons[0].code == ReasonCode.MOVED for n in panel)
    assert all(2.0 - 0.1 < changes[n].moved_cm < 5.0 + 0.1 for n in panel)


def test_compare_cli(tmp_path, real_cameras):
    gt = tmp_path / "gt"
    gt.mkdir()
    shutil.copy(REAL_CALIBRATION, gt)
    est = write_bundle(Bundle(seq="est", cameras=transform_cameras(real_cameras, SIM)), tmp_path / "est")
    runner = CliRunner()
    from dome_calib.cli import app

    result = runner.invoke(app, ["compare", str(est), str(gt)])
    assert result.exit_code == 0, result.output
    assert "compared 520 cameras" in result.output
    result = runner.invoke(app, ["compare", str(est), str(gt), "--json"])
    assert result.exit_code == 0 and '"center_cm_max"' in result.output


def test_compare_cli_bad_input(tmp_path, dome_calib_cli):
    (tmp_path / "empty").mkdir()
    proc = dome_calib_cli("compare", tmp_path / "empty", tmp_path / "nope")
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1 and "no calibration_<seq>.json" in proc.stderr


def test_alignment_survives_pickle(real_cameras):
    """Work folders cache results with pickle; pycolmap.Sim3d alone does not round-trip."""
    import pickle

    result = align_cameras(transform_cameras(real_cameras, SIM), real_cameras)
    back = pickle.loads(pickle.dumps(result))
    np.testing.assert_allclose(np.asarray(back.tgt_from_src.matrix()), np.asarray(result.tgt_from_src.matrix()),
                               rtol=1e-12, atol=1e-12)
    assert back.inliers == result.inliers and back.residual == result.residual
