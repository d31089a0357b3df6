"""Later scenes triangulated with the cameras held at the reference scene's poses (projector.known_scene), against
the same scenes mapped with GLOMAP, and the fallback to GLOMAP when the known-pose model is too poor."""
from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dome_calib.bundle_io import load_bundle
from projector.known_scene import KNOWN_FILTER_MAX_REPROJ_ERROR_PX, KnownPoseOptions, map_known_scene
from projector.known_poses import PNP_MAX_ERROR_PX
from projector.sfm import SfmOptions, known_scene_pairs, report_dict, run_sfm, select_pairs

from .conftest import SFM_CAMERAS as CAMERAS
ONLY_LATER = "01_05"  # not in scene_01 (the reference): registered by absolute pose in scene_02
ONLY_FIRST = "01_12"  # not in scene_02, so both scenes have 8 images and scene_01 wins the tie by name
CENTRE_TOL_CM = 1.0  # SfM centres after the similarity to the (ground-truth) prior, before the bundle adjustment
TOL_PX = 1e-6
FOCAL_TOL = 0.01  # reference's refined focal length against the truth (relative), before the bundle adjustment


@pytest.fixture(scope="module")
def capture(tmp_path_factory, sfm_capture) -> Path:
    capture = tmp_path_factory.mktemp("known") / "capture"
    shutil.copytree(sfm_capture, capture)  # conftest's two scenes of CAMERAS, rendered once per run
    (capture / "scenes" / "scene_01" / f"{ONLY_LATER}.png").unlink()
    (capture / "scenes" / "scene_02" / f"{ONLY_FIRST}.png").unlink()
    return capture


def _copy_databases(work: Path, to: Path) -> None:
    """The matched scene databases of ``work`` into a fresh work folder ``to`` (features and matches reused)."""
    for scene in ("scene_01", "scene_02"):
        (to / scene).mkdir(parents=True)
        shutil.copy(work / scene / "database.db", to / scene / "database.db")


def _run(capture: Path, work: Path, **known) -> object:
    options = SfmOptions(num_workers=2)
    options.known_poses.min_images = 0  # these 8-image scenes are below the size from which known poses are used
    for k, v in known.items():
        setattr(options.known_poses, k, v)
    return run_sfm(capture, work, options, prior=load_bundle(capture / "ground_truth"))


@pytest.fixture(scope="module")
def runs(capture, tmp_path_factory):
    """The known-pose run, then a GLOMAP-only run on a copy of its databases (features and matches reused)."""
    work = tmp_path_factory.mktemp("known_work")
    known = _run(capture, work, enabled=True)
    glomap_work = tmp_path_factory.mktemp("glomap_work")
    _copy_databases(work, glomap_work)
    glomap = _run(capture, glomap_work, enabled=False)
    return known, glomap, work


def test_later_scene_takes_the_known_pose_path(runs):
    known, glomap, work = runs
    scenes = report_dict(known)["scenes"]
    assert scenes["scene_01"]["mapping"] == "glomap"
    assert scenes["scene_02"]["mapping"] == "known poses (from scene_01)"
    assert "fallback" not in scenes["scene_02"]
    assert (work / "scene_02" / "known" / "model").is_dir() and not (work / "scene_02" / "sparse").exists()
    assert all(s["mapping"] == "glomap" for s in report_dict(glomap)["scenes"].values())
    # the camera the reference lacks is registered by absolute pose; every camera ends up calibrated
    assert ONLY_LATER in known.scenes["scene_02"].model.registered
    assert sorted(known.cameras) == sorted(CAMERAS) and not known.unregistered


def test_cameras_points_and_observations_match_a_glomap_run(runs, capture):
    known, glomap, _ = runs
    gt = load_bundle(capture / "ground_truth").cameras
    for result in (known, glomap):
        err_cm = {n: float(np.linalg.norm(result.cameras[n].center_cm - gt[n].center_cm)) for n in CAMERAS}
        assert max(err_cm.values()) < CENTRE_TOL_CM, err_cm
    a, b = report_dict(known)["scenes"]["scene_02"], report_dict(glomap)["scenes"]["scene_02"]
    assert a["registered"] == b["registered"] == len(CAMERAS) - 1
    # the bundle adjustment gets about the same observation set as from GLOMAP's own scene
    assert 0.8 < a["observations"] / b["observations"] < 1.25, (a, b)
    assert 0.8 < a["points"] / b["points"] < 1.25, (a, b)
    # the known-pose scene is in the reference's frame: the merge's alignment is the identity
    al = known.scene_alignment["scene_02"]
    assert abs(al.scale - 1) < 1e-3 and np.allclose(al.rotation, np.eye(3), atol=1e-3)


def test_every_observation_within_the_filter_thresholds(runs):
    """Invariant of the known-pose model: triangulated observations within the filter's error, absolute-pose
    observations within the RANSAC threshold; tracks of at least 2 views. (A track may hold two keypoints of one
    image, as GLOMAP's do: about 6 % of the points on the panel bench, either way.)"""
    known, _, _ = runs
    rec = known.scenes["scene_02"].model.reconstruction
    limit = max(KNOWN_FILTER_MAX_REPROJ_ERROR_PX, PNP_MAX_ERROR_PX) + TOL_PX
    worst = 0.0
    for p in rec.points3D.values():
        assert len({el.image_id for el in p.track.elements}) >= 2
        for el in p.track.elements:
            image = rec.image(el.image_id)
            uv = rec.camera(image.camera_id).img_from_cam(image.cam_from_world() * p.xyz)
            worst = max(worst, float(np.linalg.norm(uv - image.points2D[el.point2D_idx].xy)))
    assert 0 < worst <= limit


def test_forced_fallback_maps_with_glomap_and_says_why(capture, runs, tmp_path):
    _copy_databases(runs[2], tmp_path)
    result = _run(capture, tmp_path, enabled=True, min_registered_fraction=1.01)
    s2 = report_dict(result)["scenes"]["scene_02"]
    assert s2["mapping"] == "glomap" and "known poses registered only" in s2["fallback"]
    assert (tmp_path / "scene_02" / "sparse" / "0").is_dir()
    assert sorted(result.cameras) == sorted(CAMERAS)
    saved = json.loads((tmp_path / "sfm_report.json").read_text())
    assert saved["scenes"]["scene_02"]["fallback"] == s2["fallback"]


def test_small_captures_map_every_scene_with_glomap(capture, runs, tmp_path):
    """Below ``min_images`` in the reference scene, known poses are not used (they only save time, and a small
    capture's GLOMAP runs take seconds): every scene is mapped with GLOMAP on the prior's pairs."""
    _copy_databases(runs[2], tmp_path)
    result = _run(capture, tmp_path, min_images=9)  # scene_01 has 8 images with features
    scenes = report_dict(result)["scenes"]
    assert [scenes[s]["mapping"] for s in ("scene_01", "scene_02")] == ["glomap", "glomap"]
    assert not scenes["scene_02"].get("fallback")
    assert sorted(result.cameras) == sorted(CAMERAS)


def test_rerun_reuses_the_model_only_for_the_same_reference(runs, capture):
    known, _, work = runs
    reference = known.scenes["scene_01"].model
    stamp = work / "scene_02" / "known" / "reference.json"
    before = stamp.read_text()
    model_file = work / "scene_02" / "known" / "model" / "points3D.bin"
    mtime = model_file.stat().st_mtime_ns
    args = (work / "scene_02" / "database.db", capture / "scenes" / "scene_02", work / "scene_02" / "known")
    again, why = map_known_scene(*args, reference, KnownPoseOptions(), scene="scene_02")
    assert why is None and model_file.stat().st_mtime_ns == mtime and stamp.read_text() == before
    assert again.registered == known.scenes["scene_02"].model.registered
    # another reference (one camera fewer held): the model is made again and registers that camera by pose
    other = type(reference)(scene=reference.scene, reconstruction=reference.reconstruction,
                            registered=[n for n in reference.registered if n != "01_01"])
    redone, why = map_known_scene(*args, other, KnownPoseOptions(), scene="scene_02")
    assert why is None and stamp.read_text() != before and "01_01" in redone.registered


def test_the_reference_refines_focal_lengths_only_for_the_known_pose_path(runs, capture):
    """With known poses the reference scene's GLOMAP refines focal lengths (the later scenes are triangulated with
    them); mapping every scene with GLOMAP keeps the prior's."""
    known, glomap, _ = runs
    gt = load_bundle(capture / "ground_truth").cameras
    for result, refined in ((known, True), (glomap, False)):
        rec = result.scenes["scene_01"].model.reconstruction
        for name in result.scenes["scene_01"].model.registered:
            fx = rec.camera(rec.find_image_with_name(f"{name}.png").camera_id).params[0]
            if refined:
                assert fx != gt[name].K[0, 0] and abs(fx / gt[name].K[0, 0] - 1) < FOCAL_TOL, name
            else:
                assert fx == gt[name].K[0, 0], name


def test_later_scene_pairs_follow_the_reference_not_the_prior(runs, capture):
    """known_scene_pairs places the cameras where the reference found them: a prior with two cameras' poses
    swapped gives other pairs on its own, the reference's pairs are those of the true layout."""
    known, _, _ = runs
    gt = dict(load_bundle(capture / "ground_truth").cameras)
    options = SfmOptions()
    options.pairs.exhaustive_below = 2  # 9 cameras: choose by geometry, not all pairs
    options.pairs.k_nearest = 1
    options.known_poses.pairs_per_camera = 2
    names = sorted(CAMERAS)
    reference = known.scenes["scene_01"].model
    swapped = dict(gt)
    a, b = "01_02", "01_06"
    swapped[a] = replace(gt[b], name=a)
    swapped[b] = replace(gt[a], name=b)
    limited = replace(options.pairs, max_pairs_per_camera=2)
    truth_pairs = select_pairs(names, gt, limited)
    assert select_pairs(names, swapped, limited) != truth_pairs
    # the reference registered both swapped cameras: their partners come from its poses
    assert {a, b} <= set(reference.registered)
    assert known_scene_pairs(names, swapped, reference, options) == truth_pairs
    # every camera keeps a partner
    pairs = known_scene_pairs(names, gt, reference, options)
    count = {n: sum(n in p for p in pairs) for n in names}
    assert min(count.values()) >= 1


def _pairs_in_database(path: Path) -> set[tuple[str, str]]:
    import pycolmap

    from projector.database import camera_of_image

    with pycolmap.Database.open(str(path)) as db:
        names = {im.image_id: camera_of_image(im.name) for im in db.read_all_images()}
        pair_ids, _ = db.read_two_view_geometry_num_inliers()
        return {tuple(sorted(names[i] for i in pycolmap.pair_id_to_image_pair(pid))) for pid in pair_ids}


def test_a_likely_reference_that_is_not_the_reference_leaves_no_trace(capture, tmp_path):
    """scene_01 has as many images as scene_02 and the first name, so it is matched and mapped early; one of its
    images is blank, so scene_02 has more images with features and is the reference. scene_01's early matches and
    model are dropped: it is matched on the reference's pairs alone and triangulated at its poses, as in a run that
    maps nothing early."""
    import cv2

    from projector.database import drop_matches

    shutil.copytree(capture, tmp_path / "capture")
    cap = tmp_path / "capture"
    shutil.copy(capture / "scenes" / "scene_01" / f"{ONLY_FIRST}.png", cap / "scenes" / "scene_02" / f"{ONLY_FIRST}.png")
    shutil.copy(capture / "scenes" / "scene_02" / f"{ONLY_LATER}.png", cap / "scenes" / "scene_01" / f"{ONLY_LATER}.png")
    blank = cap / "scenes" / "scene_01" / "01_03.png"
    cv2.imwrite(str(blank), np.full(cv2.imread(str(blank), cv2.IMREAD_GRAYSCALE).shape, 128, np.uint8))
    results = {}
    for early in (True, False):
        options = SfmOptions(num_workers=2, map_reference_early=early)
        options.known_poses.min_images = 0
        options.pairs.exhaustive_below = 0  # pairs by the geometry, so that ...
        options.known_poses.pairs_per_camera = 2  # ... scene_01 has fewer than as a reference: an early one shows
        work = tmp_path / f"work_{early}"
        if not early:  # the first run's features, none of its matches: this run matches and maps on its own
            _copy_databases(tmp_path / "work_True", work)
            for scene in ("scene_01", "scene_02"):
                drop_matches(work / scene / "database.db")
        results[early] = run_sfm(cap, work, options, prior=load_bundle(capture / "ground_truth"))
        scenes = report_dict(results[early])["scenes"]
        assert scenes["scene_02"]["mapping"] == "glomap"
        assert scenes["scene_01"]["mapping"] == "known poses (from scene_02)"
        assert not (work / "scene_01" / "sparse").exists() and not list((work / "scene_01").glob(".sparse.*"))
        pairs = {tuple(sorted(line.replace(".png", "").split())) for line in
                 (work / "scene_01" / "pairs.txt").read_text().splitlines()}
        assert _pairs_in_database(work / "scene_01" / "database.db") <= pairs  # no pair of the early matching left
    early, late = results[True], results[False]
    assert early.scenes["scene_01"].pairs < early.scenes["scene_02"].pairs
    # a rerun finds every scene's features first: it knows the reference and maps nothing early again
    before = _pairs_in_database(tmp_path / "work_True" / "scene_01" / "database.db")
    options = SfmOptions(num_workers=2)
    options.known_poses.min_images = 0
    options.pairs.exhaustive_below = 0
    options.known_poses.pairs_per_camera = 2
    again = run_sfm(cap, tmp_path / "work_True", options, prior=load_bundle(capture / "ground_truth"))
    assert _pairs_in_database(tmp_path / "work_True" / "scene_01" / "database.db") == before
    assert again.scenes["scene_01"].matches.reused == again.scenes["scene_01"].pairs
    assert not (tmp_path / "work_True" / "scene_01" / "sparse").exists()
    assert _pairs_in_database(tmp_path / "work_True" / "scene_01" / "database.db") == \
        _pairs_in_database(tmp_path / "work_False" / "scene_01" / "database.db")
    assert sorted(early.cameras) == sorted(late.cameras) and "01_03" in early.failures[0].camera
    assert early.scenes["scene_01"].pairs == late.scenes["scene_01"].pairs


def test_an_error_in_the_later_scenes_triangulation_is_raised(capture, runs, tmp_path, monkeypatch):
    """The later scenes are triangulated together once all are matched: an error there reaches the caller (the
    known-pose run's features and matches reused: the triangulation is what is broken)."""
    import projector.scene as scene

    def broken(*args, **kwargs):
        raise RuntimeError("triangulator exploded")

    _copy_databases(runs[2], tmp_path)
    monkeypatch.setattr(scene, "map_known_scenes", broken)
    with pytest.raises(RuntimeError, match="triangulator exploded"):
        _run(capture, tmp_path, enabled=True)
