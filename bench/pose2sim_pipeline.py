"""Pose2Sim's own pipeline on our export (issue 51): the real Pose2Sim trial imported, reconstructed and exported as
a user would (`dome-calib import --from pose2sim`, `reconstruct --videos`, `export-people --to trc`), then Pose2Sim
0.10.49's filtering, marker augmentation (its LSTM, onnxruntime) and kinematics (OpenSim 4.6's scaling and inverse
kinematics) on our TRC, against the same steps on Pose2Sim's own triangulation of the same detections.

Run: .venv/bin/python bench/pose2sim_pipeline.py [--data ../shared/data/multiview/pose2sim_balancing] [--per-frame]
[--keep DIR] [--correct-offsets] [--cameras-only] (stop after reconstruct: cameras.json's flags and per-camera offsets, the ``cameras_json`` line)
Prints one JSON object per line:
- ``machine``: load average at the start;
- ``ours``: the reconstruct summary line, the TRC files, the seconds of each stage;
- ``angle_rms_deg``: per OpenSim coordinate (pelvis, hips, knees, ankles), the RMS difference in degrees between
  the two runs' joint angles over the frames both hold; ``mean_deg``: each run's mean (ours, Pose2Sim's);
- ``reprojection_px``: per marker, the median pixel distance between each run's TRC markers reprojected through the
  imported bundle and the participant's detections (confidence > 0.3), over the 4 cameras and 100 frames: which run
  lands on the images;
- ``per_camera_px``: the same per camera (the participant: the detected person nearest both runs' markers);
  ``agreeing_cameras``: per marker, the frames where 3 of the 4 cameras agree within 15 px and how often each camera
  is the odd one; ``px_on_agreeing_cameras_filtered``: each run's TRC after Pose2Sim's filtering (what its
  kinematics reads) against the detections of the cameras that agree, median px: which run the images side with;
- ``two_people`` (``--two-people``): two people of a synthetic group seen by the demo's tiny dome through the
  synthetic detector with BODY_25 feet, reconstructed, exported to TRC and through Pose2Sim's three steps in its
  multi-person mode: the ``.mot`` files (one per person) and per person the joint angles' RMS against the same
  steps on the truth's own joints.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.bundle_io import load_bundle  # noqa: E402
from dome_calib.lab_world import PANOPTIC_FROM_UP  # noqa: E402
from dome_calib.recon.openpose_io import read_openpose_folder  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402
from dome_calib.skeletons.joints import Y_UP_FROM_Z_UP_LAB  # noqa: E402
from tests.pose2sim_pipeline_helpers import (ANGLES, angle_rms_deg, pose2sim_on_trcs, pose2sim_reference,  # noqa: E402
                                             read_mot)

DATA = ROOT.parent / "shared" / "data" / "multiview" / "pose2sim_balancing"
CAMERA_MAP = ",".join(f"cam{k:02d}_json=cam_{k:02d}" for k in range(1, 5))
#: BODY_25B index of each TRC marker compared by reprojection (Pose2Sim's skeletons.py ids).
BODY_25B_ID = {"LHip": 11, "RHip": 12, "LKnee": 13, "RKnee": 14, "LAnkle": 15, "RAnkle": 16, "LShoulder": 5,
               "RShoulder": 6, "Neck": 17, "LBigToe": 19, "LHeel": 21, "RBigToe": 22, "RHeel": 24}


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def dome_calib(*args: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", "from dome_calib.cli import main; main()", *args], env=env,
                          capture_output=True, text=True, check=False)
    if done.returncode:
        raise SystemExit(f"dome-calib {args[0]}: {done.stderr.strip()}")
    return done.stdout.strip().splitlines()[-1]


def trc_world_cm(path: Path) -> tuple[list[str], np.ndarray]:
    """A TRC of a z-up lab's trial (Pose2Sim's axes) -> (markers, (F, M, 3) in the imported bundle's world, cm)."""
    from Pose2Sim.common import read_trc

    data, _, _, markers, _ = read_trc(str(path))
    X = data.to_numpy(dtype=float).reshape(len(data), len(markers), 3)
    return markers, (X @ Y_UP_FROM_Z_UP_LAB) @ PANOPTIC_FROM_UP["+z"].T * 100.0


def reprojection_px(bundle, trc: Path, det) -> dict[str, float]:
    """Per marker, the median over cameras and frames of the distance between the TRC's marker reprojected and the
    nearest detection of that joint (confidence > 0.3)."""
    markers, X = trc_world_cm(trc)
    out = {}
    for m, j in BODY_25B_ID.items():
        errs = []
        for cam in bundle.cameras:
            frames = sorted(det.people[cam])[: len(X)]
            uv = project_points(view_set(bundle, [cam]), X[: len(frames), markers.index(m)]).uv_px[0]
            for k, f in enumerate(frames):
                kp = raw_keypoints(cam, f)
                seen = kp[kp[:, j, 2] > 0.3, j, :2] if len(kp) else np.zeros((0, 2))
                if len(seen) and np.isfinite(uv[k]).all():
                    errs.append(float(np.min(np.linalg.norm(seen - uv[k], axis=-1))))
        out[m] = round(float(np.median(errs)), 1)
    return out


def participant_detections(bundle, det, trcs: list[Path]) -> tuple[list[str], np.ndarray]:
    """The participant's detection in every camera and frame: the detected person nearest (median over the compared
    joints) to the runs' markers reprojected, averaged over the runs ``trcs``. -> cameras, (F, V, 25, 3) BODY_25B
    keypoints (confidence 0 where none)."""
    cams = sorted(bundle.cameras)
    runs = [trc_world_cm(t) for t in trcs]
    F = min(len(X) for _, X in runs)
    out = np.zeros((F, len(cams), 25, 3))
    ids = list(BODY_25B_ID.values())
    for v, cam in enumerate(cams):
        frames = sorted(det.people[cam])[:F]
        uv = np.mean([project_points(view_set(bundle, [cam]), X[:len(frames), [mk.index(m) for m in BODY_25B_ID]]
                                     .reshape(-1, 3)).uv_px[0].reshape(len(frames), len(ids), 2)
                      for mk, X in runs], axis=0)
        for k, f in enumerate(frames):
            kp = raw_keypoints(cam, f)
            if not len(kp):
                continue
            d = np.where(kp[:, ids, 2] > 0.3, np.linalg.norm(kp[:, ids, :2] - uv[k][None], axis=-1), np.nan)
            score = np.array([np.nanmedian(r) if np.isfinite(r).any() else np.inf for r in d])
            if np.isfinite(score).any():
                out[k, v] = kp[int(np.argmin(score))]
    return cams, out


def per_camera_px(bundle, trc: Path, cams: list[str], kp: np.ndarray) -> dict[str, dict[str, float]]:
    """marker -> camera -> median px between the TRC's marker reprojected and the participant's detection
    (confidence > 0.3)."""
    markers, X = trc_world_cm(trc)
    out: dict[str, dict[str, float]] = {}
    for m, j in BODY_25B_ID.items():
        out[m] = {}
        for v, cam in enumerate(cams):
            uv = project_points(view_set(bundle, [cam]), X[:len(kp), markers.index(m)]).uv_px[0]
            d = np.where(kp[:, v, j, 2] > 0.3, np.linalg.norm(uv - kp[:, v, j, :2], axis=-1), np.nan)
            out[m][cam] = round(float(np.nanmedian(d)), 1) if np.isfinite(d).any() else None
    return out


def agreeing_cameras(bundle, cams: list[str], kp: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """marker -> ((F,) frames where 3 of the 4 cameras agree, (F, V) those cameras): per frame, the best of the
    3-camera triangulations of the participant's detections (the smallest worst reprojection, no outlier rejection),
    if that worst is within 15 px (3 sigma of this detector's noise); the fourth camera is then the odd one."""
    import itertools

    from dome_calib.recon.triangulate import TriangulationOptions, triangulate

    views = view_set(bundle, cams)
    loose = TriangulationOptions(inlier_threshold_px=1e6, min_views=2)
    out = {}
    F, V = kp.shape[:2]
    for m, j in BODY_25B_ID.items():
        conf = np.where(kp[:, :, j, 2] > 0.3, np.minimum(kp[:, :, j, 2], 1.0), 0.0)
        uv = np.where(conf[..., None] > 0, kp[:, :, j, :2], np.nan)
        best, agree = np.full(F, np.inf), np.zeros((F, V), bool)
        for three in itertools.combinations(range(V), 3):
            c = np.zeros_like(conf)
            c[:, three] = conf[:, three]
            X = triangulate(views, uv, c, loose).X_cm
            r = np.stack([np.linalg.norm(project_points(view_set(bundle, [cams[v]]), X).uv_px[0] - uv[:, v], axis=-1)
                          for v in three], axis=1)
            worst = np.where(np.isfinite(r).all(1), r.max(1), np.inf)
            better = worst < best
            best[better] = worst[better]
            agree[better] = np.isin(np.arange(V), three)
        out[m] = (best < 15.0, agree)
    return out


def on_agreeing_cameras(bundle, trc: Path, cams: list[str], kp: np.ndarray, agreeing) -> dict[str, float]:
    """marker -> median px between the TRC's marker reprojected and the participant's detections in the cameras
    that agree (:func:`agreeing_cameras`)."""
    markers, X = trc_world_cm(trc)
    F = min(len(X), len(kp))  # Pose2Sim's filtered file holds 99 of the 100 frames (from frame 0)
    out = {}
    for m, j in BODY_25B_ID.items():
        ok, agree = agreeing[m]
        d = np.stack([np.linalg.norm(project_points(view_set(bundle, [cam]), X[:F, markers.index(m)]).uv_px[0]
                                     - kp[:F, v, j, :2], axis=-1) for v, cam in enumerate(cams)], axis=1)
        d = d[ok[:F, None] & agree[:F]]
        out[m] = round(float(np.nanmedian(d)), 1) if np.isfinite(d).any() else None
    return out


_RAW: dict = {}


def raw_keypoints(cam: str, frame: int) -> np.ndarray:
    """The BODY_25B keypoints of camera ``cam`` (``cam_01``) at ``frame``: (N, 25, 3)."""
    key = (cam, frame)
    if key not in _RAW:
        n = cam[-2:]
        doc = json.loads((DATA_USED / "pose" / f"cam{n}_json" / f"cam{n}.{frame:04d}.json").read_text())
        _RAW[key] = np.array([p["pose_keypoints_2d"] for p in doc["people"]], dtype=float).reshape(-1, 25, 3)
    return _RAW[key]


DATA_USED = DATA


def main() -> None:
    global DATA_USED
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--per-frame", action="store_true", help="reconstruct --per-frame (no body over time)")
    ap.add_argument("--two-people", action="store_true", help="also two synthetic people through Pose2Sim")
    ap.add_argument("--only-two-people", action="store_true", help="only the two synthetic people")
    ap.add_argument("--keep", type=Path, default=None,
                    help="work in this folder and keep it (the runs' TRC and .mot files, for a closer look)")
    ap.add_argument("--correct-offsets", action="store_true", help="reconstruct --correct-offsets")
    ap.add_argument("--cameras-only", action="store_true",
                    help="stop after reconstruct: cameras.json's verdict on the real trial only")
    args = ap.parse_args()
    if args.only_two_people:
        with tempfile.TemporaryDirectory() as tmp:
            two_people(Path(tmp))
        return
    DATA_USED = data = args.data
    if args.keep is not None and args.keep.exists() and any(args.keep.iterdir()):
        raise SystemExit(f"--keep {args.keep}: not empty (the runs are made there from nothing)")
    emit(machine={"loadavg": os.getloadavg()[0]})
    with (contextlib.nullcontext(str(args.keep)) if args.keep else tempfile.TemporaryDirectory()) as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        dome_calib("import", str(data / "calibration" / "Calib_qualisys.toml"), "--from", "pose2sim", "-o",
                   str(tmp / "bundle"))
        extra = (["--per-frame"] if args.per_frame else []) + (["--correct-offsets"] if args.correct_offsets else [])
        line = dome_calib("reconstruct", str(data / "pose"), "--bundle", str(tmp / "bundle"), "--body-model",
                          "BODY_25B", "--camera-map", CAMERA_MAP, "--videos", str(data / "videos"), "-o",
                          str(tmp / "people"), *extra)
        t1 = time.perf_counter()
        report = json.loads((tmp / "people" / "cameras.json").read_text())
        emit(cameras_json={"flagged": report["flagged"], "notes": report["notes"],
                           "cameras": {n: {k: c[k] for k in ("median_reprojection_px", "outvoted_share",
                                                             "median_offset_px", "offset_joints", "offset_z",
                                                             "offset_floor_px", "offset_corrected_px")}
                                       for n, c in report["cameras"].items()}})
        if args.cameras_only:
            return
        dome_calib("export-people", str(tmp / "people"), "--to", "trc", "-o", str(tmp / "trc"), "--trial",
                   "balancing")
        trcs = sorted((tmp / "trc").glob("*.trc"))
        ours = pose2sim_on_trcs(tmp / "ours", trcs, model="BODY_25B", fps=60)
        t2 = time.perf_counter()
        theirs = pose2sim_reference(tmp / "pose2sim", data / "pose", data / "calibration" / "Calib_qualisys.toml",
                                    model="BODY_25B", fps=60)
        t3 = time.perf_counter()
        emit(ours={"reconstruct": line, "trc": [p.name for p in trcs], "mot": [p.name for p in ours],
                   "seconds": {"import_reconstruct": round(t1 - t0, 1), "export_and_pose2sim": round(t2 - t1, 1),
                               "pose2sim_reference": round(t3 - t2, 1)}})
        rms = angle_rms_deg(ours[0], theirs[0])
        a, b = read_mot(ours[0]), read_mot(theirs[0])
        emit(angle_rms_deg={k: round(v, 2) for k, v in rms.items()},
             mean_deg={k: [round(float(a[k].mean()), 1), round(float(b[k].mean()), 1)] for k in ANGLES})
        bundle = load_bundle(tmp / "bundle")
        det = read_openpose_folder(data / "pose", body_model="BODY_25B",
                                   camera_map={f"cam{k:02d}_json": f"cam_{k:02d}" for k in range(1, 5)})
        ref_trc = next((tmp / "pose2sim" / "pose-3d").glob("*_0-99.trc"))
        emit(reprojection_px={"ours": reprojection_px(bundle, trcs[0], det),
                              "pose2sim": reprojection_px(bundle, ref_trc, det)})
        cams, kp = participant_detections(bundle, det, [trcs[0], ref_trc])
        agreeing = agreeing_cameras(bundle, cams, kp)
        filtered = {"ours": next((tmp / "ours" / "pose-3d").glob("*_filt_butterworth.trc")),
                    "pose2sim": next((tmp / "pose2sim" / "pose-3d").glob("*_filt_butterworth.trc"))}
        emit(per_camera_px={"ours": per_camera_px(bundle, trcs[0], cams, kp),
                            "pose2sim": per_camera_px(bundle, ref_trc, cams, kp)},
             agreeing_cameras={m: {"frames": int(ok.sum()),
                                   "odd_camera_frames": {c: int((ok & ~agree[:, v]).sum()) for v, c in enumerate(cams)}}
                               for m, (ok, agree) in agreeing.items()},
             px_on_agreeing_cameras_filtered={k: on_agreeing_cameras(bundle, t, cams, kp, agreeing)
                                             for k, t in filtered.items()})
        if args.two_people:
            two_people(tmp)


def two_people(tmp: Path) -> None:
    """Two people of a synthetic group (scenario "crouch": one crouches, one talks) seen by the demo's tiny dome (16
    cameras as built, sync tables) through the synthetic OpenPose detector with BODY_25 feet
    (:func:`~dome_calib.synth.detector.feet_detections`), reconstructed and exported as a user would, then
    Pose2Sim's three steps in its multi-person mode; the same steps on the truth's own joints (the group's joints19
    and :func:`~dome_calib.synth.skeleton.feet_cm`, exported alike); per person the RMS of the joint angles, ours
    against the truth's run."""
    from dome_calib.bundle_io import write_bundle
    from dome_calib.recon.people.commands import people_options, reconstruct_folder
    from dome_calib.skeletons.export import ExportPeopleOptions, export_people
    from dome_calib.skeletons.scenes import read_people
    from dome_calib.synth.detector import feet_detections, synth_detections
    from dome_calib.synth.dome import as_built_dome
    from dome_calib.synth.group import GroupOptions, make_group
    from dome_calib.synth.openpose_write import write_openpose_folder
    from dome_calib.synth.skeleton import FEET, feet_cm, synthetic_sync
    from tests.skeletons_helpers import write_scenes

    t0 = time.perf_counter()
    root = tmp / "two"
    bundle = as_built_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=5000.0, seed=0)
    write_bundle(bundle, root / "bundle")
    truth = make_group(GroupOptions(n_people=2, start_ms=500.0, duration_ms=4000.0, scenario="crouch", seed=1))
    det, ids = synth_detections(bundle, truth, with_ids=True)
    write_openpose_folder(root / "det", det, body_model="BODY_25", extras=feet_detections(bundle, truth, det, ids))
    line = reconstruct_folder(root / "det", root / "bundle", root / "people", body_model="BODY_25",
                              options=people_options())
    ours = read_people(root / "people")
    # Pose2Sim's scaling needs a person's standing frames: tracks over half the span (a person lost behind another
    # for longer than the tracker waits comes back under a new id, by design)
    long = [pid for pid, t in ours.tracks.items() if len(t.rows) >= len(ours.frames) // 2]
    export_people(root / "people", "trc", root / "trc_ours", ExportPeopleOptions(trial="ours", ids=long))
    times = ours.times_ms
    X, present = truth.joints_cm(times)
    bodies = [{int(truth.ids[p]): np.concatenate([np.concatenate([X[k, p], feet_cm(X[k, p])]),
                                                  np.full((25, 1), 0.9)], axis=1)
               for p in np.flatnonzero(present[k])} for k in range(len(times))]
    write_scenes(root / "truth", ours.frames, times, bodies, extra=FEET, body_model="BODY_25")
    export_people(root / "truth", "trc", root / "trc_truth", ExportPeopleOptions(trial="truth"))
    t1 = time.perf_counter()
    fps = round(float(ours.fps))
    mots = pose2sim_on_trcs(root / "p_ours", sorted((root / "trc_ours").glob("*.trc")), model="BODY_25", fps=fps)
    ref = pose2sim_on_trcs(root / "p_truth", sorted((root / "trc_truth").glob("*.trc")), model="BODY_25", fps=fps)
    # each of our people is the true person whose body centre is nearest (median over the frames both hold)
    pairs = {}
    for pid, track in ((p, ours.tracks[p]) for p in long):
        rows = np.searchsorted(ours.frames, ours.frames[track.rows])
        gap = [np.nanmedian(np.linalg.norm(track.X_cm[:, 2] - X[rows, p, 2], axis=-1)) for p in range(len(truth.ids))]
        pairs[pid] = (int(truth.ids[int(np.argmin(gap))]), round(float(np.min(gap)), 2))
    by_id = lambda paths, pid: next(p for p in paths if f"_P{pid}_" in p.name)  # noqa: E731
    spans = {str(p): [int(ours.frames[t.rows[0]]), int(ours.frames[t.rows[-1]])] for p, t in ours.tracks.items()}
    emit(two_people={"reconstruct": str(line), "tracks": spans,
                     "trc": sorted(p.name for p in (root / "trc_ours").glob("*.trc")),
                     "mot": [p.name for p in mots], "matched_truth_id_and_centre_cm": pairs,
                     "angle_rms_deg": {str(pid): {k: round(v, 2) for k, v in
                                                  angle_rms_deg(by_id(mots, pid), by_id(ref, t)).items()}
                                       for pid, (t, _) in pairs.items()},
                     "seconds": {"synthesis_reconstruct_export": round(t1 - t0, 1),
                                 "pose2sim_both": round(time.perf_counter() - t1, 1)}})


if __name__ == "__main__":
    main()
