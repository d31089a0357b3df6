"""Camera flags when several cameras are off (issue 51, "flags that hold when half the cameras are off"): the
few-camera rig (5 HD cameras, 2 people, the detector whose errors last), ``--off`` of its cameras turned by
``--degrees`` about their own vertical axis in the bundle given to ``reconstruct`` (the detections come from the true
cameras), then ``cameras.json``'s verdict and, per camera, the median reprojection, the share outvoted, cameras.json's
median offset of its inlier detections (with its significance, standard errors, and floor, px) and the mean
residual vector (detection minus the reprojected body over all its used joints, px): a camera that moved shifts its
detections to one side, which detector noise does not.

Run: .venv/bin/python bench/camera_flags.py [--off 2] [--degrees 1.0]
Prints one JSON object per line: the load; the run (flagged cameras); one line per camera.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.bundle import Bundle  # noqa: E402
from dome_calib.bundle_io import write_bundle  # noqa: E402
from dome_calib.recon.openpose_io import read_openpose_folder  # noqa: E402
from dome_calib.recon.people.commands import people_options, reconstruct_folder  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402
from dome_calib.recon.streams import stream_of_camera  # noqa: E402
from dome_calib.rotation import rotvec_to_matrix  # noqa: E402
from dome_calib.skeletons.scenes import read_people  # noqa: E402
from dome_calib.synth.detector import DetectorModel, synth_detections  # noqa: E402
from dome_calib.synth.openpose_write import write_openpose_folder  # noqa: E402
from dome_calib.synth.rig import GROUP_MARGIN_MS, RigOptions, few_camera_rig, rig_group  # noqa: E402


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def mean_residual_px(bundle: Bundle, det, people, cam: str) -> tuple[list[float], int]:
    """The mean of (detection - reprojected body joint) over every used joint of ``cam`` (the detection nearest each
    body, within 60 px median), and how many."""
    _, table = stream_of_camera(bundle, cam)
    time_of = dict(zip(table.index.tolist(), table.univ_time_ms.tolist()))
    res = []
    for frame, kp in det.people[cam].items():
        t = time_of.get(int(frame))
        if t is None or not len(kp):
            continue
        k = int(np.argmin(np.abs(people.times_ms - t)))
        if abs(people.times_ms[k] - t) > 20.0:
            continue
        for track in people.tracks.values():
            row = np.flatnonzero(track.rows == k)
            if not len(row):
                continue
            uv = project_points(view_set(bundle, [cam]), track.X_cm[row[0], :19]).uv_px[0]
            d = np.where(kp[..., :19, 2:] > 0.1, kp[..., :19, :2] - uv[None], np.nan)
            with np.errstate(all="ignore"):
                near = np.nanmedian(np.linalg.norm(d, axis=-1), axis=1)
            if np.isfinite(near).any() and np.nanmin(near) < 60.0:
                res.append(d[int(np.nanargmin(near))])
    R = np.concatenate(res) if res else np.zeros((0, 2))
    R = R[np.isfinite(R).all(1)]
    return np.round(R.mean(0), 1).tolist() if len(R) else [None, None], len(R)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--off", type=int, default=2, help="how many of the 5 cameras are turned")
    ap.add_argument("--degrees", type=float, default=1.0)
    args = ap.parse_args()
    emit(machine={"loadavg": os.getloadavg()[0]})
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        bundle = few_camera_rig(RigOptions(seed=0, duration_ms=2000.0 + GROUP_MARGIN_MS + 100.0))
        truth = rig_group(bundle, n_people=2, seed=3)
        write_openpose_folder(root / "det", synth_detections(bundle, truth, model=DetectorModel(seed=3)),
                              body_model="BODY_25")
        cams = dict(bundle.cameras)
        turned = sorted(cams)[:args.off]
        for name in turned:
            cam = cams[name]
            R = rotvec_to_matrix(np.radians([0.0, args.degrees, 0.0])) @ cam.R
            cams[name] = dataclasses.replace(cam, R=R, t_cm=-R @ (-cam.R.T @ cam.t_cm))
        moved = Bundle(seq=bundle.seq, cameras=cams, calib_data_source="moved", sync=bundle.sync)
        write_bundle(moved, root / "b")
        summary = reconstruct_folder(root / "det", root / "b", root / "out", body_model="BODY_25",
                                     options=people_options())
        report = json.loads((root / "out" / "cameras.json").read_text())
        emit(turned=turned, degrees=args.degrees, flagged=report["flagged"], notes=report["notes"],
             people=summary.people, median_reprojection_px=report["median_reprojection_px"])
        det = read_openpose_folder(root / "det", body_model="BODY_25")
        people = read_people(root / "out")
        for name, c in report["cameras"].items():
            mean, n = mean_residual_px(moved, det, people, name)
            emit(camera=name, turned=name in turned, median_reprojection_px=c["median_reprojection_px"],
                 outvoted_share=c["outvoted_share"], median_offset_px=c["median_offset_px"],
                 offset_z=c["offset_z"], offset_floor_px=c["offset_floor_px"], mean_residual_px=mean,
                 mean_residual_length_px=None if mean[0] is None else round(float(np.hypot(*mean)), 1),
                 joints=n)


if __name__ == "__main__":
    main()
