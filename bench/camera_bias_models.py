"""What a camera's disagreement is made of (issue 51): per camera, the participant's detections against the other
cameras' triangulation of them, and how much of the distance each model of a camera error takes away on frames it
was not fitted to.

Reads a folder kept by ``bench/pose2sim_pipeline.py --keep DIR`` (the imported bundle, both runs' TRC, used to pick
the participant's detection in each camera and frame). Per camera: the other cameras' detections (confidence > 0.3)
triangulated (``dome_calib.recon.triangulate``, its defaults), then the models fitted on even frames (and on the first
half) and judged on odd frames (the second half), median px: ``none``; ``shift`` (the median offset: what
``--correct-offsets`` takes out); ``rotation`` (the camera turned about its centre), ``pose`` (6 dof), ``pose_focal``,
``pose_focal_k1`` (robust least squares, soft-L1 at 10 px); ``shift_per_joint`` (a median offset per joint: a detector
that puts each joint of this view its own way); and the median offset per joint. Also the lag: the median distance with
the others' points taken ``lag`` frames later (a camera out of sync).

Run: .venv/bin/python bench/camera_bias_models.py DIR [--data ../shared/data/multiview/pose2sim_balancing]
Prints one JSON object per line, one per camera.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import pose2sim_pipeline as p2p  # noqa: E402

from dome_calib.bundle_io import load_bundle  # noqa: E402
from dome_calib.recon.openpose_io import read_openpose_folder  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402
from dome_calib.recon.triangulate import triangulate  # noqa: E402

#: BODY_25B's joint names, in its order (Pose2Sim's skeletons.py).
JOINTS = ["Nose", "LEye", "REye", "LEar", "REar", "LShoulder", "RShoulder", "LElbow", "RElbow", "LWrist", "RWrist",
          "LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle", "UpperNeck", "HeadTop", "LBigToe", "LSmallToe",
          "LHeel", "RBigToe", "RSmallToe", "RHeel"]
MODELS = {"rotation": 3, "pose": 6, "pose_focal": 7, "pose_focal_k1": 8}


def others_points(bundle, cams: list[str], kp: np.ndarray, c: int) -> np.ndarray:
    """(F, J, 3) the joints triangulated from every camera but ``c`` (NaN where not)."""
    F, V, J, _ = kp.shape
    rest = [v for v in range(V) if v != c]
    conf = np.where(kp[:, rest, :, 2] > 0.3, np.minimum(kp[:, rest, :, 2], 1.0), 0.0).transpose(0, 2, 1)
    uv = kp[:, rest, :, :2].transpose(0, 2, 1, 3)
    tri = triangulate(view_set(bundle, [cams[v] for v in rest]), uv.reshape(-1, len(rest), 2),
                      conf.reshape(-1, len(rest)))
    return tri.X_cm.reshape(F, J, 3)


def project(cam, p: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Camera ``cam`` changed by ``p`` (rotation vector, translation cm, log focal scale, k1 added) -> (N, 2) px."""
    rv = cv2.Rodrigues(cam.R)[0].ravel() + p[:3]
    t = cam.t_cm + p[3:6] if len(p) > 3 else -cv2.Rodrigues(rv)[0] @ cam.center_cm
    K, d = cam.K.copy(), cam.dist.copy()
    if len(p) > 6:
        K[0, 0] *= np.exp(p[6])
        K[1, 1] *= np.exp(p[6])
    if len(p) > 7:
        d[0] += p[7]
    return cv2.projectPoints(X.astype(float), rv, t, K, d)[0][:, 0]


def judge(cam, X: np.ndarray, uv: np.ndarray, ok: np.ndarray, train: np.ndarray) -> dict:
    """Median px on the held-out detections, each model fitted on ``train``."""
    test = ok & ~train
    fit, held = ok & train, test
    r = uv - project_points_cam(cam, X)  # read where ok only (X finite there)
    out = {"none": float(np.median(np.linalg.norm(r[held], axis=1)))}
    shift = np.median(r[fit], axis=0)
    out["shift"] = float(np.median(np.linalg.norm(r[held] - shift, axis=1)))
    for name, n in MODELS.items():
        sol = least_squares(lambda p: (uv[fit] - project(cam, p, X[fit])).ravel(), np.zeros(n), loss="soft_l1",
                            f_scale=10.0)
        out[name] = float(np.median(np.linalg.norm(uv[held] - project(cam, sol.x, X[held]), axis=1)))
    per_joint = np.array([np.median(r[fit[:, j], j], axis=0) if fit[:, j].sum() > 3 else shift
                          for j in range(X.shape[1])])
    out["shift_per_joint"] = float(np.median(np.linalg.norm((r - per_joint[None])[held], axis=1)))
    return {k: round(v, 1) for k, v in out.items()}


def project_points_cam(cam, X: np.ndarray) -> np.ndarray:
    flat = np.nan_to_num(X.reshape(-1, 3))
    return project(cam, np.zeros(6), flat).reshape(X.shape[:-1] + (2,))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a folder kept by bench/pose2sim_pipeline.py --keep")
    ap.add_argument("--data", type=Path, default=p2p.DATA)
    args = ap.parse_args()
    p2p.DATA_USED = args.data
    bundle = load_bundle(args.run / "bundle")
    det = read_openpose_folder(args.data / "pose", body_model="BODY_25B",
                               camera_map={f"cam{k:02d}_json": f"cam_{k:02d}" for k in range(1, 5)})
    trcs = [next((args.run / "trc").glob("*.trc")), next((args.run / "pose2sim" / "pose-3d").glob("*_0-99.trc"))]
    cams, kp = p2p.participant_detections(bundle, det, trcs)
    F, V, J, _ = kp.shape
    frame = np.arange(F)[:, None] * np.ones((1, J), int)
    for c, name in enumerate(cams):
        X = others_points(bundle, cams, kp, c)
        cam = bundle.cameras[name]
        uv = kp[:, c, :, :2]
        ok = np.isfinite(X).all(-1) & (kp[:, c, :, 2] > 0.3)
        r = uv - project_points_cam(cam, X)
        lag = {}
        for k in range(-6, 7, 2):
            f = np.arange(max(0, -k), min(F, F - k))
            seen = (kp[f, c, :, 2] > 0.3) & np.isfinite(X[f + k]).all(-1)
            d = np.linalg.norm(uv[f] - project_points_cam(cam, X[f + k]), axis=-1)[seen]
            lag[str(k)] = round(float(np.median(d)), 1)
        p2p.emit(camera=name, detections=int(ok.sum()),
                 even_odd_px=judge(cam, X, uv, ok, frame % 2 == 0), halves_px=judge(cam, X, uv, ok, frame < F // 2),
                 median_offset_per_joint_px={JOINTS[j]: np.round(np.median(r[ok[:, j], j], axis=0), 1).tolist()
                                             for j in range(J) if ok[:, j].sum() > 5},
                 lag_frames_median_px=lag)


if __name__ == "__main__":
    main()
