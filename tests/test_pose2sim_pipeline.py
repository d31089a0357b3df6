"""Pose2Sim's and OpenSim's own pipeline on our output (issue 51): the real Pose2Sim trial (4 phone cameras,
BODY_25B, 100 frames at 60 fps; tests/data/pose2sim_balancing) imported, reconstructed and exported by the commands
a user runs, then Pose2Sim 0.10.49's filtering, marker augmentation and kinematics (OpenSim 4.6's inverse
kinematics) on our TRC: no crash, one output per person, and joint angles against Pose2Sim's own run of the same
steps on its own triangulation of the same detections (a peer's result, not a truth).

Before issue 51 the augmentation crashed on our TRC ("Length mismatch"), the legs froze without feet (knee 77 deg
constant against 38 deg), the times were doubled (30 fps assumed) and the pelvis turned a quarter turn."""
from __future__ import annotations

import json
import logging
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from dome_calib.final_place import said

from .pose2sim_pipeline_helpers import ANGLES, angle_rms_deg, pose2sim_on_trcs, pose2sim_reference

DATA = Path(__file__).parent / "data" / "pose2sim_balancing"
CAMERA_MAP = ",".join(f"cam{k:02d}_json=cam_{k:02d}" for k in range(1, 5))
#: Limits (degrees RMS against Pose2Sim's own run), a little above what was measured (docs/export-people.md:
#: knees 3.4 / 2.6, hip flexion 3.0 / 2.9, adduction 1.9 / 2.1, rotation 2.9 / 2.3, pelvis 1.6 / 1.5 / 3.2, ankles
#: 4.7 / 6.9); the hips and the pelvis within the issue's 5 deg: before a joint's views were chosen by the most that
#: agree, a pair of cameras held the left hip on camera 01's side for 15 frames (hip flexion 8.7, pelvis rotation
#: 8.1); the other failures caught are far beyond (frozen knees 39 deg, the pelvis turned 77 deg).
KNEE_LIMIT_DEG = 5.0
HIP_PELVIS_LIMIT_DEG = 5.0
ANY_LIMIT_DEG = 10.0


@pytest.mark.slow
def test_pose2sims_filtering_augmentation_and_kinematics_run_on_our_trc(dome_calib_cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # OpenSim writes its opensim.log into the working folder
    run = dome_calib_cli("import", str(DATA / "calibration" / "Calib_qualisys.toml"), "--from", "pose2sim", "-o",
                         str(tmp_path / "bundle"))
    assert run.returncode == 0, run.stderr
    run = dome_calib_cli("reconstruct", str(DATA / "pose"), "--bundle", str(tmp_path / "bundle"), "--body-model",
                         "BODY_25B", "--camera-map", CAMERA_MAP, "--fps", "60", "-o", str(tmp_path / "people"))
    assert run.returncode == 0, run.stderr
    assert "60 fps from --fps" in run.stdout
    run = dome_calib_cli("export-people", str(tmp_path / "people"), "--to", "trc", "-o", str(tmp_path / "trc"),
                         "--trial", "balancing")
    assert run.returncode == 0, run.stderr
    trcs = sorted((tmp_path / "trc").glob("*.trc"))
    assert [p.name for p in trcs] == ["balancing_P0_0-99.trc"]

    ours = pose2sim_on_trcs(tmp_path / "ours", trcs, model="BODY_25B", fps=60)
    assert [p.name for p in ours] == ["balancing_P0_0-99_filt_butterworth_LSTM.mot"]  # one output per person
    theirs = pose2sim_reference(tmp_path / "pose2sim", DATA / "pose", DATA / "calibration" / "Calib_qualisys.toml",
                                model="BODY_25B", fps=60)
    assert len(theirs) == 1
    rms = angle_rms_deg(ours[0], theirs[0])
    print(json.dumps({"angle_rms_deg": {k: round(v, 2) for k, v in rms.items()}}))
    assert set(rms) == set(ANGLES)
    assert max(rms["knee_angle_r"], rms["knee_angle_l"]) < KNEE_LIMIT_DEG, rms
    assert max(v for k, v in rms.items() if k.startswith(("hip_", "pelvis_"))) < HIP_PELVIS_LIMIT_DEG, rms
    assert max(rms.values()) < ANY_LIMIT_DEG, rms


# ------------------------------------------------------------------------------------- fast: rate, joints, axes
FRAMES = range(0, 24)  # a quarter of the trial: enough people for the joint-order check, seconds to reconstruct


def _detections(tmp_path: Path, model: str = "BODY_25B") -> Path:
    """The first frames of the trial's detections, in ``model``'s joint order made from BODY_25B's (COCO_17: its
    first 17 joints; HALPE_26: those, then HeadTop, the shoulders' and the hips' midpoints as Neck and Hip, and the
    feet in Halpe's order)."""
    out = tmp_path / f"det_{model}"
    for cam in range(1, 5):
        (out / f"cam{cam:02d}_json").mkdir(parents=True)
        for f in FRAMES:
            doc = json.loads((DATA / "pose" / f"cam{cam:02d}_json" / f"cam{cam:02d}.{f:04d}.json").read_text())
            for person in doc["people"]:
                kp = np.asarray(person["pose_keypoints_2d"], float).reshape(25, 3)
                if model == "COCO_17":
                    kp = kp[:17]
                elif model == "HALPE_26":
                    mid = [np.r_[(kp[a, :2] + kp[b, :2]) / 2, min(kp[a, 2], kp[b, 2])] for a, b in ((5, 6), (11, 12))]
                    kp = np.vstack([kp[:17], kp[18], mid[0], mid[1], kp[[19, 22, 20, 23, 21, 24]]])
                person["pose_keypoints_2d"] = kp.ravel().tolist()
            (out / f"cam{cam:02d}_json" / f"cam{cam:02d}.{f:04d}.json").write_text(json.dumps(doc))
    return out


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> Path:
    from dome_calib.interop.convert import import_calibration

    out = tmp_path_factory.mktemp("p2s") / "bundle"
    import_calibration(DATA / "calibration" / "Calib_qualisys.toml", "pose2sim", out)
    return out


def _video(path: Path, fps: float) -> None:
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (32, 32))
    for _ in range(3):
        writer.write(np.zeros((32, 32, 3), np.uint8))
    writer.release()


def test_no_rate_is_assumed_without_sync_tables(bundle, dome_calib_cli, tmp_path, caplog):
    """Without sync tables the rate is --fps, or the videos', or the run is refused (it used to assume 30 fps: this
    60 fps trial came out with every time doubled); the rate is said in the summary line."""
    det = _detections(tmp_path)
    args = ("reconstruct", str(det), "--bundle", str(bundle), "--body-model", "BODY_25B", "--camera-map", CAMERA_MAP)
    run = dome_calib_cli(*args, "-o", str(tmp_path / "none"))
    assert run.returncode == 1 and "no sync tables" in run.stderr and "--fps" in run.stderr and "--videos" in run.stderr
    assert not (tmp_path / "none").exists()
    (tmp_path / "videos").mkdir()
    for cam in range(1, 5):
        _video(tmp_path / "videos" / f"cam{cam:02d}.avi", 60.0)
    caplog.set_level(logging.INFO, logger="dome_calib.skeletons.page")
    run = dome_calib_cli(*args, "--videos", str(tmp_path / "videos"), "-o", str(tmp_path / "people"))
    assert run.returncode == 0, run.stderr
    assert "(shared, 60 fps from the videos)" in run.stdout
    assert f"people page written to {tmp_path / 'people' / 'index.html'} (" in said(caplog.text)  # as the user reads it
    times = [json.loads((tmp_path / "people" / f"body3DScene_{f:08d}.json").read_text())["univTime"] for f in (0, 6)]
    assert times[1] - times[0] == pytest.approx(100.0)  # 6 frames at 60 fps
    _video(tmp_path / "videos" / "cam04.avi", 30.0)
    run = dome_calib_cli(*args, "--videos", str(tmp_path / "videos"), "-o", str(tmp_path / "people"))
    assert run.returncode == 1 and "cam04.avi runs at 30 fps but cam01.avi at 60 fps" in run.stderr
    run = dome_calib_cli(*args, "--fps", "30000/1001", "-o", str(tmp_path / "people"))
    assert run.returncode == 0 and "29.97 fps from --fps" in run.stdout
    from dome_calib.skeletons.scenes import read_people

    assert read_people(tmp_path / "people").fps == Fraction(30000, 1001)  # exact, not measured from the times


@pytest.mark.parametrize("model", ["BODY_25B", "HALPE_26", "COCO_17"])
def test_every_detector_joint_comes_out_under_pose2sims_names(model, bundle, dome_calib_cli, tmp_path):
    """The detector's joints that joints19 lacks (feet, head top, BODY_25B's UpperNeck) are triangulated beside
    joints19 and land on their detections in the images (reprojected through the bundle: median under 12 px, the
    joints19's own figure on this trial); the TRC names every joint as Pose2Sim's tree of that model does, in the
    lab's axes as Pose2Sim writes them (within 8 cm of Pose2Sim's own TRC of these detections per marker, median;
    its left big toe lands 10.6 px from its detections, ours 9.0 px: bench/pose2sim_pipeline.py; 4.3 px with the
    10 px inlier threshold, which then fitted 2 of the 4 views)."""
    from anytree import PreOrderIter
    import Pose2Sim.skeletons as p2s

    from dome_calib.bundle_io import load_bundle
    from dome_calib.recon.body_models import EXTRA_JOINTS, JOINT_NAMES
    from dome_calib.recon.project import project_points, view_set
    from dome_calib.skeletons.scenes import read_people

    det = _detections(tmp_path, model)
    run = dome_calib_cli("reconstruct", str(det), "--bundle", str(bundle), "--camera-map", CAMERA_MAP, "--fps", "60",
                         "-o", str(tmp_path / "people"), *(["--body-model", model] if model == "BODY_25B" else []))
    assert run.returncode == 0, run.stderr
    assert f"({model})" in run.stdout  # COCO_17 and HALPE_26 told by their joint counts
    people = read_people(tmp_path / "people")
    assert people.body_model == model and people.extra == tuple(EXTRA_JOINTS[model]) and people.lab_up == "+z"
    (track,) = people.tracks.values()
    if people.extra:  # every extra joint reconstructed in most frames, on its detections
        X = track.X_cm[:, 19:]
        assert np.isfinite(X).all(-1).mean() > 0.9
        b = load_bundle(bundle)
        gaps = []
        for cam in range(1, 5):
            uv = project_points(view_set(b, [f"cam_{cam:02d}"]), X.reshape(-1, 3)).uv_px[0].reshape(X.shape[:2] + (2,))
            for k, f in enumerate(people.frames[track.rows]):
                doc = json.loads((det / f"cam{cam:02d}_json" / f"cam{cam:02d}.{f:04d}.json").read_text())
                for e, name in enumerate(people.extra):
                    j = JOINT_NAMES[model].index(name)
                    seen = [np.asarray(p["pose_keypoints_2d"]).reshape(-1, 3)[j] for p in doc["people"]]
                    seen = [s[:2] for s in seen if s[2] > 0.3]
                    if seen and np.isfinite(uv[k, e]).all():
                        gaps.append(min(np.linalg.norm(s - uv[k, e]) for s in seen))
        assert np.median(gaps) < 12.0, np.median(gaps)
    run = dome_calib_cli("export-people", str(tmp_path / "people"), "--to", "trc", "-o", str(tmp_path / "trc"))
    assert run.returncode == 0, run.stderr
    (trc,) = (tmp_path / "trc").glob("*.trc")
    from Pose2Sim.common import read_trc

    data, _, _, markers, _ = read_trc(str(trc))
    wanted = {n.name for n in PreOrderIter(getattr(p2s, model)) if n.id is not None}
    assert wanted <= set(markers), sorted(wanted - set(markers))
    theirs, _, _, their_markers, _ = read_trc(str(DATA / "pose2sim_result" / "S00_P00_T01_BalancingTrial_0-100.trc"))
    n = len(FRAMES)
    for m in sorted(set(their_markers) & set(markers) - {"Neck"} if model != "BODY_25B" else
                    set(their_markers) & set(markers)):  # Pose2Sim's Neck is BODY_25B's UpperNeck
        gap_cm = np.linalg.norm(data[m].to_numpy(float)[:n] - theirs[m].to_numpy(float)[:n], axis=-1) * 100
        assert np.nanmedian(gap_cm) < 8.0, (m, np.nanmedian(gap_cm))  # axes turned: a metre off


def test_pose2sims_filtering_keeps_one_file_per_person(dome_calib_cli, tmp_path):
    """Two people of the demo's synthetic group exported to TRC, then Pose2Sim 0.10.49's own filtering: one filtered
    file per person, each the filter of its own person (``person0.trc`` and ``person1.trc`` both became
    ``1-100_filt_butterworth.trc``: one person overwritten, exit 0)."""
    from Pose2Sim.common import read_trc

    from dome_calib.skeletons.scenes import read_people

    from .pose2sim_pipeline_helpers import _agg_backend, pose2sim_config
    from .skeletons_helpers import demo_group_scenes

    folder = demo_group_scenes(tmp_path / "group", seconds=2.0)
    ids = sorted(read_people(folder).tracks)[:2]
    run = dome_calib_cli("export-people", str(folder), "--to", "trc", "-o", str(tmp_path / "project" / "pose-3d"),
                         "--ids", ",".join(map(str, ids)))
    assert run.returncode == 0, run.stderr
    trcs = sorted((tmp_path / "project" / "pose-3d").glob("*.trc"))
    assert len(trcs) == 2
    with _agg_backend():
        from Pose2Sim.filtering import filter_all

        filter_all(pose2sim_config(tmp_path / "project", model="BODY_25", fps=25, multi_person=True))
    filtered = sorted((tmp_path / "project" / "pose-3d").glob("*_filt_butterworth.trc"))
    assert len(filtered) == 2  # one per person
    for trc, out in zip(trcs, filtered):
        assert out.name.startswith(trc.name.rsplit("_", 1)[0] + "_")  # <trial>_P<id>_<range>_filt_butterworth.trc
        raw, filt = read_trc(str(trc))[0].to_numpy(float), read_trc(str(out))[0].to_numpy(float)
        n = min(len(raw), len(filt))
        assert np.nanmedian(np.abs(raw[:n] - filt[:n])) < 0.02  # metres: its own person, smoothed


def test_cameras_are_flagged_when_half_of_them_are_off():
    """Two of four cameras off (their joints mostly outvoted, 22 and 33 px): the relative criteria see nothing (the
    cameras' median is off too), the absolute one (a share outvoted far above the detector's own outlier rate)
    flags both and nobody else."""
    from dome_calib.recon.people.agreement import ERROR_BIN_PX, CameraAgreement
    from dome_calib.recon.people.scene_io import camera_report

    a = CameraAgreement.empty(["c1", "c2", "c3", "c4"])
    a.detected[:] = a.used[:] = 100
    a.judged[:] = 1800
    for v, (px, outvoted) in enumerate([(6.0, 0.03), (7.0, 0.05), (33.0, 0.86), (22.0, 0.52)]):
        a.hist[v, int(px / ERROR_BIN_PX)] = 1000
        a.outvoted[v] = int(outvoted * 1800)
    report = camera_report(a)
    assert report["flagged"] == ["c3", "c4"]
    a.outvoted[:] = 0  # the relative criteria alone
    assert camera_report(a)["flagged"] == []
