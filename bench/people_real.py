"""Real OpenPose detections through the group stage, per frame and with the body over time: Pose2Sim's demo
"balancing trial" (4 phone cameras, BODY_25B, 100 frames at 60 fps; see tests/data/pose2sim_balancing/PROVENANCE.md).

    .venv/bin/python bench/people_real.py [--data tests/data/pose2sim_balancing]

Prints one JSON object per line:

- per mode (``per_frame``: the robust triangulation of each time; ``temporal``: the body over time, the default):
  per joint the median distance (cm) to Pose2Sim's own 3D result (its TRC, axes mapped as the test does; a peer's
  result, not a truth), the share of (frame, joint) reconstructed, and per camera the median distance (px) between
  our participant's reprojected joints and that camera's detections; the per-camera noise and outvoted share the
  body over time measured;
- Pose2Sim's own reprojection onto the same detections, per camera (the peer's result, same scorer);
- per mode, cameras.json's verdict (:func:`~dome_calib.recon.people.scene_io.camera_report`): the cameras flagged,
  why, and per camera the median offset of its inlier detections from the body (px, u v), how many, its
  significance (standard errors) and its floor (px).

Camera 03 disagrees with the other three by ~40 px on every joint (flagged by cameras.json; Pose2Sim's own result
reprojects 21 px off there).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from fractions import Fraction
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.recon.body_models import JOINTS19  # noqa: E402
from dome_calib.recon.openpose_io import read_openpose_folder  # noqa: E402
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people  # noqa: E402
from dome_calib.recon.people.scene_io import camera_report  # noqa: E402
from dome_calib.recon.people.sources import people_streams  # noqa: E402
from dome_calib.recon.people.temporal import TemporalOptions  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402
from tests.test_people_real import COMMON, pose2sim_bundle, read_trc_cm  # noqa: E402

CAMS = [f"00_{k:02d}" for k in range(1, 5)]


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def reprojection_px(bundle, X: np.ndarray, det: dict, joints: list[int]) -> dict[str, float]:
    """Median over frames and joints of |projection - detection| of the participant (the detection nearest the
    projection, per frame), per camera. X (F, J, 3) cm in ``joints`` order."""
    out = {}
    for cam in CAMS:
        uv = project_points(view_set(bundle, [cam]), X.reshape(-1, 3)).uv_px[0].reshape(len(X), -1, 2)
        errs = []
        for k, frame in enumerate(sorted(det[cam])):
            people = det[cam][frame][:, joints]
            e = np.where(people[..., 2] > 0, np.linalg.norm(people[..., :2] - uv[k][None], axis=-1), np.nan)
            if np.isfinite(e).any():
                errs.append(e[np.nanargmin(np.nanmean(np.where(np.isfinite(e), e, 1e9), axis=1))])
        out[cam] = round(float(np.nanmedian(errs)), 2)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT / "tests" / "data" / "pose2sim_balancing"))
    args = ap.parse_args()
    data = Path(args.data)
    emit(bench="people_real", load_average_1min=round(os.getloadavg()[0], 1))
    bundle = pose2sim_bundle(data / "calibration" / "Calib_qualisys.toml")
    det = read_openpose_folder(data / "pose", body_model="BODY_25B",
                               camera_map={f"cam{k:02d}_json": f"00_{k:02d}" for k in range(1, 5)})
    streams = people_streams(bundle, det.people, det.files, shared_fps=Fraction(60))
    times = streams[0].table.times_of(streams[0].frame_index)
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    markers, p2s = read_trc_cm(data / "pose2sim_result" / "S00_P00_T01_BalancingTrial_0-100.trc")
    mi = [markers.index(m) for m in COMMON]
    ji = [JOINTS19.index(j) for j in COMMON.values()]
    emit(peer="pose2sim", reprojection_px=reprojection_px(bundle, p2s[:, mi], det.people, ji))
    base = PeopleOptions(shared_fps=Fraction(60))
    for mode, temporal in (("per_frame", TemporalOptions(enabled=False)), ("temporal", TemporalOptions())):
        seq = reconstruct_people(views, streams, times, dataclasses.replace(base, temporal=temporal))
        X = np.full((len(times), 19, 3), np.nan)
        for k, b in enumerate(seq.bodies):
            if len(b.ids):  # the participant: the body seen by most views
                X[k] = b.X_cm[int(np.argmax(b.n_views))]
        dist = np.linalg.norm(X[:, ji] - p2s[:, mi], axis=-1)
        a = seq.cameras
        emit(mode=mode, median_cm_to_pose2sim={m: round(float(np.nanmedian(dist[:, c])), 2)
                                               for c, m in enumerate(COMMON)},
             mean_of_medians_cm=round(float(np.nanmean(np.nanmedian(dist, axis=0))), 2),
             reconstructed_share=round(float(np.isfinite(dist).mean()), 4),
             reprojection_px=reprojection_px(bundle, X[:, ji], det.people, ji),
             outvoted_share={n: (round(float(o / j), 4) if j else None)
                             for n, o, j in zip(a.names, a.outvoted, a.judged)})
        report = camera_report(a, views.subset(a.names).resolution)
        emit(mode=mode, flagged=report["flagged"], notes=report["notes"],
             offset={n: {k: c[k] for k in ("median_offset_px", "offset_joints", "offset_z", "offset_floor_px")}
                     for n, c in report["cameras"].items()})


if __name__ == "__main__":
    main()
