"""SfM front end end to end on a small synthetic capture with broken inputs: a corrupted PNG, a black image and
a camera turned to face away from the tent must be reported per camera while the rest reconstructs."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from dome_calib.bundle_io import load_bundle
from dome_calib.camera import project
from projector.features import FeatureOptions, extract_features
from projector.matching import MatchOptions, match_pairs
from projector.pairs import pairs_exhaustive
from dome_calib.pipeline.stages import problem_from_observations
from projector.sfm import SfmOptions, run_sfm

from .conftest import SFM_CAMERAS as CAMERAS, SFM_SEED
from .report_data import NO_PLOTS  # no test here reads a plot
CORRUPT, BLACK, AWAY = "01_03", "01_04", "01_12"
GOOD = sorted(set(CAMERAS) - {CORRUPT, BLACK, AWAY})
HD = "00_00"  # the one HD camera of CAMERAS


def _render_facing_away(capture: Path, name: str) -> np.ndarray:
    """Image of camera ``name`` turned by 180 degrees about the vertical (it sees the dome, not the tent)."""
    from dome_calib.synth.dome import projectors
    from dome_calib.synth.rays import CameraRays
    from dome_calib.synth.render import RenderOptions, prepare_scene, render_image
    from dome_calib.synth.tent import scene_poses
    from dome_calib.rotation import rotvec_to_matrix
    from projector.patterns import make_patterns

    cam = load_bundle(capture / "ground_truth").cameras[name]
    turn = rotvec_to_matrix(np.array([0.0, np.pi, 0.0]))
    R = cam.R @ turn  # camera rotated about the world vertical through its centre
    away = replace(cam, R=R, t_cm=-R @ cam.center_cm)
    projs = projectors(SFM_SEED)
    options = RenderOptions()
    scene = prepare_scene("scene_01", scene_poses(2, SFM_SEED)[0], projs,
                          make_patterns(SFM_SEED, tuple(sorted(projs))), options)
    return render_image(CameraRays(away), scene, options, SFM_SEED)


@pytest.fixture(scope="module")
def broken_capture(tmp_path_factory, sfm_capture) -> Path:
    import shutil

    capture = tmp_path_factory.mktemp("sfm") / "capture"
    shutil.copytree(sfm_capture, capture)  # conftest's capture of CAMERAS, rendered once per run
    scene = capture / "scenes" / "scene_01"
    (scene / f"{CORRUPT}.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not an image")
    cv2.imwrite(str(scene / f"{BLACK}.png"), np.zeros((480, 640), np.uint8))
    cv2.imwrite(str(scene / f"{AWAY}.png"), _render_facing_away(capture, AWAY))
    # a scene that cannot reconstruct: two views only
    small = capture / "scenes" / "scene_02"
    shutil.rmtree(small)
    small.mkdir()
    for name in ("01_01", "01_02"):
        (small / f"{name}.png").write_bytes((scene / f"{name}.png").read_bytes())
    return capture


@pytest.fixture(scope="module")
def sfm_result(broken_capture, tmp_path_factory):
    prior = load_bundle(broken_capture / "ground_truth")
    work = tmp_path_factory.mktemp("sfm_work")
    return run_sfm(broken_capture, work, SfmOptions(num_workers=2), prior=prior), work


def test_broken_images_are_reported_per_camera(sfm_result):
    result, _ = sfm_result
    failed = {f.camera: f for f in result.failures if f.stage == "features"}
    assert "unreadable" in failed[CORRUPT].reason
    assert "blank" in failed[BLACK].reason
    assert AWAY in result.unregistered  # sees no tent: blank or too few features, never registered
    assert set(result.unregistered) == {CORRUPT, BLACK, AWAY}


def test_a_scene_that_does_not_reconstruct_is_reported(sfm_result):
    result, _ = sfm_result
    scene2 = [f for f in result.failures if f.scene == "scene_02" and f.stage == "mapping"]
    assert {f.camera for f in scene2} == {"01_01", "01_02", ""}  # per camera, plus the scene itself
    assert all(f.reason for f in scene2)
    assert "scene_02" not in result.observations.scene_points_cm


def test_missing_scenes_folder_is_a_one_line_error(tmp_path):
    from dome_calib.errors import CaptureError

    with pytest.raises(CaptureError, match="no scenes/ folder"):
        run_sfm(tmp_path, tmp_path / "work", SfmOptions())


def test_the_rest_registers_with_centres_within_1cm(sfm_result, broken_capture):
    result, _ = sfm_result
    gt = load_bundle(broken_capture / "ground_truth").cameras
    assert sorted(result.cameras) == GOOD
    err_cm = np.array([np.linalg.norm(result.cameras[n].center_cm - gt[n].center_cm) for n in GOOD])
    assert err_cm.max() < 1.0, dict(zip(GOOD, err_cm.round(3)))
    for n in GOOD:  # invariants of the merged rotations
        R = result.cameras[n].R
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0


def test_observations_reproject_in_opencv_pixels(sfm_result):
    """Points and cameras of the SfM's observations reproject onto them (catches a 0.5 px convention slip)."""
    result, _ = sfm_result
    p = problem_from_observations(result.observations)
    assert len(p.uv_px) > 1000 and p.scene_names == ["scene_01"]
    res = []
    for c, name in enumerate(p.camera_names):
        rows = p.camera_index == c
        cam = result.cameras[name]
        uv = project(p.points_cm[p.point_index[rows]], cam.R[None], cam.t_cm[None], cam.intr[None], cam.dist[None]).uv_px[0]
        res.append(np.linalg.norm(uv - p.uv_px[rows], axis=1))
    res = np.concatenate(res)
    assert np.median(res) < 0.5, np.median(res)
    # the same residuals with the COLMAP convention left in are worse: the conversion matters
    shifted = []
    for c, name in enumerate(p.camera_names):
        rows = p.camera_index == c
        cam = result.cameras[name]
        uv = project(p.points_cm[p.point_index[rows]], cam.R[None], cam.t_cm[None], cam.intr[None], cam.dist[None]).uv_px[0]
        shifted.append(np.linalg.norm(uv - (p.uv_px[rows] + 0.5), axis=1))
    assert np.median(np.concatenate(shifted)) > np.median(res)


def test_rerun_reuses_database_and_model(sfm_result, broken_capture):
    result, work = sfm_result
    db = work / "scene_01" / "database.db"
    feats = extract_features(broken_capture / "scenes" / "scene_01", db, options=FeatureOptions())
    assert feats.reused == len(GOOD) + 0 and feats.reused == len(feats.num_features) - 0
    again = match_pairs(db, pairs_exhaustive(feats.num_features), options=MatchOptions())
    assert again.reused == again.num_pairs and again.num_verified_pairs == result.scenes["scene_01"].matches.num_verified_pairs
    second = run_sfm(broken_capture, work, SfmOptions(num_workers=1))
    assert sorted(second.cameras) == GOOD


def test_database_opens_as_a_colmap_database(sfm_result):
    import pycolmap

    result, work = sfm_result
    with pycolmap.Database.open(str(work / "scene_01" / "database.db")) as db:
        names = sorted(im.name for im in db.read_all_images())
        assert names == [f"{n}.png" for n in GOOD]
        assert db.num_verified_image_pairs() > 0 and db.num_frames() == len(GOOD) and db.num_rigs() == len(GOOD)
        _, geometries = db.read_two_view_geometries()
        configs = {g.config for g in geometries if len(g.inlier_matches)}
        # the prior intrinsics make every verified pair a calibrated geometry (E, or H for small baselines)
        assert configs and pycolmap.TwoViewGeometryConfiguration.UNCALIBRATED not in configs


def test_camera_unknown_to_the_prior_is_still_registered(broken_capture, tmp_path):
    """The prior lacks one camera: it is paired with every other (fallback), gets nominal intrinsics, and its
    pose comes from the reconstruction; the others still align to the prior."""
    gt = load_bundle(broken_capture / "ground_truth").cameras
    unknown = "01_05"
    prior = {n: c for n, c in gt.items() if n != unknown}
    result = run_sfm(broken_capture, tmp_path, SfmOptions(num_workers=2, scenes=["scene_01"]),
                     prior=prior)
    assert unknown in result.cameras
    assert np.linalg.norm(result.cameras[unknown].center_cm - gt[unknown].center_cm) < 2.0
    pairs = (tmp_path / "scene_01" / "pairs.txt").read_text().splitlines()
    assert sum(f"{unknown}.png" in line for line in pairs) == len(GOOD) - 1


def test_reduced_image_keypoints_are_in_full_resolution_pixels(broken_capture):
    """An HD image halved for SIFT (the quick path's first round): fewer keypoints, each where the full-resolution
    SIFT finds one (COLMAP's corner-origin pixels scale exactly), at the same scale."""
    from scipy.spatial import cKDTree

    from projector.features import extract_image, reduction_factor

    assert [reduction_factor(w, h, 960) for w, h in ((640, 480), (960, 540), (1920, 1080), (1921, 1080))] == [1, 1, 2, 3]
    assert reduction_factor(1920, 1080, 0) == 1
    path = str(broken_capture / "scenes" / "scene_01" / "00_00.png")
    full = extract_image(("00_00", path, FeatureOptions()))
    half = extract_image(("00_00", path, FeatureOptions(max_image_size_px=960)))
    assert half.failure is None and half.shape == full.shape == (1080, 1920)
    assert 100 < len(half.keypoints) < len(full.keypoints) / 2
    dist_px, nearest = cKDTree(full.keypoints[:, :2]).query(half.keypoints[:, :2])
    assert np.median(dist_px) < 0.3  # px (full resolution)
    close = dist_px < 1.0
    assert close.mean() > 0.7
    assert np.median(half.keypoints[close, 2] / full.keypoints[nearest[close], 2]) == pytest.approx(1.0, abs=0.05)


def test_dropped_features_are_extracted_and_matched_again(sfm_result, broken_capture, tmp_path):
    """drop_features removes images' features and every pair of theirs (either image of a pair: the first and a
    middle one are dropped); extraction and matching then redo exactly those images and pairs, and give what they
    gave the first time, even after the same process matched them from other features in between (the workers'
    feature cache lives for one matching call)."""
    import sqlite3

    import pycolmap

    from projector.database import drop_features

    _, work = sfm_result
    db = tmp_path / "database.db"
    with sqlite3.connect(work / "scene_01" / "database.db") as src, sqlite3.connect(db) as dst:
        src.backup(dst)  # with what is still in the write-ahead log
    src.close(), dst.close()
    pairs = pairs_exhaustive(GOOD)
    hd, middle = "00_00", GOOD[len(GOOD) // 2]
    dropped = (hd, middle)

    def inliers() -> dict:
        with pycolmap.Database.open(str(db)) as d:
            ids = {im.name: im.image_id for im in d.read_all_images()}
            return {p: np.asarray(d.read_two_view_geometry(ids[f"{p[0]}.png"], ids[f"{p[1]}.png"]).inlier_matches
                                  ).tobytes()  # the inlier keypoint pairs themselves (counts stop at 512)
                    for p in pairs if d.exists_two_view_geometry(ids[f"{p[0]}.png"], ids[f"{p[1]}.png"])}

    def redo(options: FeatureOptions) -> None:
        removed = drop_features(db, [hd, middle, "not_a_camera"])
        assert removed == sorted(p for p in pairs if set(p) & set(dropped))
        assert sorted(inliers()) == sorted(p for p in pairs if not set(p) & set(dropped))
        feats = extract_features(broken_capture / "scenes" / "scene_01", db, cameras=list(dropped), options=options)
        assert feats.reused == len(GOOD) - 2 and sorted(feats.num_features) == GOOD  # only those two extracted
        again = match_pairs(db, pairs, options=MatchOptions())
        assert again.reused == sum(not set(p) & set(dropped) for p in pairs)

    before = inliers()
    redo(FeatureOptions(max_image_size_px=960))  # the HD image halved
    assert inliers() != before
    redo(FeatureOptions())
    assert inliers() == before


def _quick_recalibration(capture: Path, root: Path, change: str):
    """calibrate --only-changed on ``capture`` into ``root / "out"``, the prior (written to ``root / "prior"``) being
    the truth with the HD camera turned 1 deg ("turned") or without it ("new").
    Returns (options, prior's cameras, result)."""
    import dataclasses

    from scipy.spatial.transform import Rotation

    import dome_calib.pipeline.full as pipeline
    from dome_calib.bundle import Bundle
    from dome_calib.bundle_io import write_bundle

    truth = load_bundle(capture / "ground_truth")
    cams = dict(truth.cameras)
    c = cams.pop(HD)
    if change == "turned":
        cams[HD] = dataclasses.replace(c, R=Rotation.from_rotvec([0.0, np.radians(1.0), 0.0]).as_matrix() @ c.R)
    prior = write_bundle(Bundle(seq="prior", cameras=cams), root / "prior")
    options = pipeline.CalibrateOptions(prior=prior, only_changed=True, report=NO_PLOTS)
    return options, cams, pipeline.run_calibration(capture, root / "out", options)


@pytest.fixture(scope="module")
def new_camera_run(broken_capture, tmp_path_factory):
    """The quick recalibration with the HD camera new to the prior, run once: its test and the interrupted run's
    (whose uninterrupted reference it is) read it. Returns (root folder, options, prior's cameras, result)."""
    root = tmp_path_factory.mktemp("quick_new")
    return (root, *_quick_recalibration(broken_capture, root, "new"))


@pytest.mark.parametrize("change", ["turned", "new"])
def test_quick_recalibration_gives_a_disturbed_hd_camera_full_resolution(broken_capture, tmp_path, change, request):
    """calibrate --only-changed on rendered images, the prior with the HD camera turned 1 deg (or without it: a
    new camera): it is a suspect from its halved image, extracted again at full resolution with its first-round
    pairs matched again, and re-estimated near the truth; the others keep the prior."""
    from dome_calib.compare import camera_error

    if change == "new":
        root, _, cams, result = request.getfixturevalue("new_camera_run")
    else:
        root = tmp_path
        _, cams, result = _quick_recalibration(broken_capture, root, change)
    truth = load_bundle(broken_capture / "ground_truth")
    assert sorted(result.changes) == [HD]
    assert result.stats["quick"]["full_resolution"] == [HD]
    out = load_bundle(root / "out")
    err = camera_error(out.cameras[HD], truth.cameras[HD])
    # a new camera starts from nominal intrinsics and gets all of them from five VGA partners in one scene:
    # 1.7 cm / 0.21 deg here, the same to the last digit without the halved first round
    within_cm, within_deg = (1.0, 0.05) if change == "turned" else (3.0, 0.4)
    assert err.rotation_deg < within_deg and err.center_cm < within_cm, err
    for n in GOOD:
        if n != HD:
            np.testing.assert_array_equal(out.cameras[n].R, cams[n].R)


def test_quick_recalibration_rerun_after_a_failed_suspect_match(broken_capture, new_camera_run, tmp_path, monkeypatch):
    """The run stops inside suspect_match, after the features of the HD camera (new to the prior) were dropped:
    the rerun resumes after detect, restores its first-round pairs from pairs.txt (a new camera has no other
    partners) and gives the same bundle as a run that never stopped (new_camera_run: the same capture, prior and
    options)."""
    import dome_calib.pipeline.full as pipeline
    import dome_calib.pipeline.quick as quick

    fresh_root, options, _, _ = new_camera_run
    real = quick.extract_features

    def power_cut(*args, **kwargs):
        raise RuntimeError("power cut")

    monkeypatch.setattr(quick, "extract_features", power_cut)
    with pytest.raises(RuntimeError, match="power cut"):
        pipeline.run_calibration(broken_capture, tmp_path / "out", options)
    assert not (tmp_path / "out").exists()
    monkeypatch.setattr(quick, "extract_features", real)
    again = pipeline.run_calibration(broken_capture, tmp_path / "out", options)
    assert again.resumed == ["match", "detect"] and sorted(again.changes) == [HD]
    resumed, fresh = load_bundle(tmp_path / "out").cameras[HD], load_bundle(fresh_root / "out").cameras[HD]
    np.testing.assert_array_equal(resumed.R, fresh.R)
    np.testing.assert_array_equal(resumed.t_cm, fresh.t_cm)
