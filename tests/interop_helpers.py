"""Helpers of the interop tests and bench/interop.py: pixel grids over the whole image, world points behind them,
projection and ray gaps between two cameras (px); Pose2Sim's demo data; and the peers that cannot be installed here
(nerfstudio, EasyMocap), their code followed as read."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from dome_calib.bundle import Bundle, Camera
from dome_calib.camera import pixels_to_normalized, project
from dome_calib.interop.common import PANOPTIC_FROM_UP

DEPTHS_CM = (30.0, 300.0, 3000.0)


def _stack(cams: list[Camera]) -> dict[str, np.ndarray]:
    return {"R": np.stack([c.R for c in cams]), "t": np.stack([c.t_cm for c in cams]),
            "intr": np.stack([c.intr for c in cams]), "dist": np.stack([c.dist for c in cams]),
            "wh": np.array([c.resolution for c in cams], dtype=float)}


def grid_px(cams: list[Camera], n: int = 9) -> np.ndarray:
    """(C, n*n, 2) OpenCV pixels covering each image edge to edge, the four outer corners included."""
    s = np.stack(np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n)), axis=-1).reshape(-1, 2)
    return -0.5 + _stack(cams)["wh"][:, None, :] * s[None]


def world_points_cm(cam: Camera | list[Camera], n: int = 9) -> np.ndarray:
    """(3 n^2, 3) world points (cm) on the pinhole rays of the grid pixels at 30 cm, 3 m and 30 m; (C, 3 n^2, 3)
    for a list of cameras."""
    cams = cam if isinstance(cam, list) else [cam]
    k = _stack(cams)
    xn = (grid_px(cams, n) - k["intr"][:, None, 2:]) / k["intr"][:, None, :2]
    rays = np.concatenate([xn, np.ones(xn.shape[:-1] + (1,))], axis=-1)
    X_cam = np.concatenate([d * rays for d in DEPTHS_CM], axis=1)
    X = (X_cam - k["t"][:, None, :]) @ k["R"]  # R^T (X_cam - t), row-wise
    return X if isinstance(cam, list) else X[0]


def pixels(cam: Camera | list[Camera], X_cm: np.ndarray) -> np.ndarray:
    """Our model's pixels of world points: (N, 2) for one camera, (C, N, 2) for a list and (C, N, 3) points."""
    if not isinstance(cam, list):
        return project(X_cm, cam.R, cam.t_cm, cam.intr, cam.dist).uv_px
    k = _stack(cam)
    return project(X_cm, k["R"], k["t"], k["intr"], k["dist"]).uv_px


def gaps_px(a: list[Camera], b: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """Per camera pair (C,): the largest pixel distance between the two cameras' projections of ``a``'s grid world
    points, and the largest angle (as px at ``a``'s focal length) between the world rays both unproject from the
    grid pixels. Pixels beyond the lens's monotonic range (no ray) must be so for both."""
    X = world_points_cm(a)
    proj = np.linalg.norm(pixels(a, X) - pixels(b, X), axis=-1).max(axis=1)
    grid = grid_px(a)
    rays = []
    for cams in (a, b):
        k = _stack(cams)
        xn = pixels_to_normalized(grid, k["intr"][:, None], k["dist"][:, None])
        d = np.concatenate([xn, np.ones(xn.shape[:-1] + (1,))], axis=-1) @ k["R"]  # world directions R^T x
        rays.append(d / np.linalg.norm(d, axis=-1, keepdims=True))
    ok_a, ok_b = np.isfinite(rays[0][..., 0]), np.isfinite(rays[1][..., 0])
    assert np.array_equal(ok_a, ok_b), "one camera unprojects a pixel the other cannot"
    cos = np.sum(rays[0] * rays[1], axis=-1)
    sin = np.linalg.norm(np.cross(rays[0], rays[1]), axis=-1)
    angle = np.where(ok_a, np.arctan2(sin, cos), 0.0)
    return proj, angle.max(axis=1) * _stack(a)["intr"][:, :2].max(axis=1)


def projection_gap_px(a: Camera, b: Camera) -> float:
    return float(gaps_px([a], [b])[0][0])


def ray_gap_px(a: Camera, b: Camera) -> float:
    return float(gaps_px([a], [b])[1][0])


# ------------------------------------------------------------- Pose2Sim's demo: its 3D result and the detections
#: BODY_25B joint index of each TRC marker (Pose2Sim ``skeletons.py``, BODY_25B tree).
BODY_25B = {"Nose": 0, "LShoulder": 5, "RShoulder": 6, "LElbow": 7, "RElbow": 8, "LWrist": 9, "RWrist": 10,
            "LHip": 11, "RHip": 12, "LKnee": 13, "RKnee": 14, "LAnkle": 15, "RAnkle": 16, "Neck": 17, "Head": 18,
            "LBigToe": 19, "LSmallToe": 20, "LHeel": 21, "RBigToe": 22, "RSmallToe": 23, "RHeel": 24}
#: Pose2Sim writes TRC y-up for OpenSim (``common.py: zup2yup``: columns Y, Z, X of its z-up world), so the
#: calibration's world point of a TRC row is (trc_z, trc_x, trc_y).
WORLD_FROM_TRC_AXES = [2, 0, 1]


def read_trc(path) -> tuple[np.ndarray, list[str], np.ndarray]:
    """(frame numbers (F,), marker names (J,), positions (F, J, 3) in the file's axes and unit)."""
    lines = path.read_text().splitlines()
    names = [n for n in lines[3].split("\t")[2:] if n]
    rows = np.array([[float(v) for v in line.split("\t")[:2 + 3 * len(names)]] for line in lines[5:] if line.strip()])
    return rows[:, 0].astype(int), names, rows[:, 2:].reshape(len(rows), len(names), 3)


def read_openpose_person(folder, prefix: str, frames: int) -> np.ndarray:
    """(frames, 25, 3) x, y, confidence of the most confident person per frame (NaN where undetected)."""
    out = np.full((frames, 25, 3), np.nan)
    for f in range(frames):
        people = json.loads((folder / f"{prefix}.{f:04d}.json").read_text())["people"]
        if not people:
            continue
        kp = [np.array(p["pose_keypoints_2d"], dtype=float).reshape(25, 3) for p in people]
        best = max(kp, key=lambda a: float(np.mean(a[a[:, 2] > 0, 2])) if np.any(a[:, 2] > 0) else 0.0)
        best[best[:, 2] <= 0] = np.nan
        out[f] = best
    return out


# ---------------------------------------- peers that cannot be installed here (torch): their code followed as read
def _rotation_a_to_b(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """As nerfstudio's camera_utils.rotation_matrix (the 1e-8 in its denominator included)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    s = np.linalg.norm(v)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * ((1 - c) / (s**2 + 1e-8))


def nerfstudio_round_trip(path: Path) -> tuple[list[str], np.ndarray]:
    """Poses of ``transforms.json`` through nerfstudio's dataparser and back through its dataparser_transforms, in
    float64 (nerfstudio holds poses in float32: ~1e-5 cm at 5 m). Followed as read, copying no code:
    nerfstudio-project/nerfstudio ``nerfstudio/data/dataparsers/nerfstudio_dataparser.py`` @ 01595f7f
    (``_generate_dataparser_outputs``: frames sorted by file name; ``auto_orient_and_center_poses`` with the defaults
    orientation "up", centre "poses"; ``auto_scale_poses``: 1 / max |t|; ``applied_transform`` composed on the right
    of the orientation transform; ``applied_scale`` multiplied into the scale), ``nerfstudio/cameras/camera_utils.py``
    @ 0079b674 (``auto_orient_and_center_poses``, ``rotation_matrix``), ``nerfstudio/data/dataparsers/
    base_dataparser.py`` @ c0464f8a (``transform_poses_to_original_space``: translations divided by the scale, then
    the inverse of the 4x4 transform, OpenCV camera axes). Returns the frames' camera names and (F, 4, 4)
    camera-to-world poses in the original world, OpenCV axes."""
    meta = json.loads(path.read_text())
    frames = [meta["frames"][i] for i in np.argsort([f["file_path"] for f in meta["frames"]])]
    poses = np.array([f["transform_matrix"] for f in frames], dtype=float)
    translation = poses[:, :3, 3].mean(axis=0)
    up = poses[:, :3, 1].mean(axis=0)
    rotation = _rotation_a_to_b(up, np.array([0.0, 0.0, 1.0]))
    transform = np.concatenate([rotation, rotation @ -translation[:, None]], axis=1)  # (3, 4)
    oriented = transform @ poses
    scale = 1.0 / np.abs(oriented[:, :3, 3]).max()
    oriented[:, :3, 3] *= scale
    if "applied_transform" in meta:
        transform = transform @ np.vstack([np.array(meta["applied_transform"]), [0, 0, 0, 1]])
    if "applied_scale" in meta:
        scale *= float(meta["applied_scale"])
    back = np.concatenate([oriented, np.tile([[[0, 0, 0, 1.0]]], (len(oriented), 1, 1))], axis=1)
    back[:, :3, 3] /= scale
    back = np.einsum("ij,bjk->bik", np.linalg.inv(np.vstack([transform, [0, 0, 0, 1]])), back)
    back[:, :3, 1:3] *= -1
    return [f["camera_name"] for f in frames], back


def _easymocap_yaml(path: Path, names: list[str], entries: list[tuple[str, np.ndarray]]) -> None:
    """A FileStorage YAML file as EasyMocap's own FileStorage writer prints it (zju3dv/EasyMocap
    ``easymocap/mytools/camera_utils.py`` @ 0ebb1d25: ``%YAML:1.0``, ``names`` as a list of quoted strings, each
    matrix as ``!!opencv-matrix`` with 6 decimals); followed as read, no code copied."""
    lines = ["%YAML:1.0", "---", "names:", *[f'  - "{n}"' for n in names]]
    for key, m in entries:
        m = np.atleast_2d(m)
        lines += [f"{key}: !!opencv-matrix", f"  rows: {m.shape[0]}", f"  cols: {m.shape[1]}", "  dt: d",
                  f"  data: [{', '.join(f'{v:.6f}' for v in m.ravel())}]"]
    path.write_text("\r\n".join(lines) + "\r\n")


def calib_intri_extri(folder: Path, bundle: Bundle, names: list[str]) -> None:
    """intri.yml as EasyMocap's calib_intri writes it (write_intri: K_ and dist_ only, no H_ / W_) and extri.yml as
    calib_extri writes it (write_extri: R_, Rot_, T_), for our cameras in a z-up world, metres."""
    folder.mkdir(parents=True)
    cams = [bundle.cameras[n] for n in names]
    _easymocap_yaml(folder / "intri.yml", names, [e for n, c in zip(names, cams)
                                                   for e in ((f"K_{n}", c.K), (f"dist_{n}", c.dist[None]))])
    extri = []
    for n, c in zip(names, cams):
        R = c.R @ PANOPTIC_FROM_UP["+z"]
        extri += [(f"R_{n}", cv2.Rodrigues(R)[0]), (f"Rot_{n}", R), (f"T_{n}", c.t_cm[:, None] / 100.0)]
    _easymocap_yaml(folder / "extri.yml", names, extri)


def kalibr_camchain(cams: list[Camera]) -> dict:
    """``camchain.yaml``'s content for our cameras as Kalibr's CameraChainParameters writes it (ethz-asl/kalibr
    ``aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py`` @ ea2791f0: ``cam0``, ``cam1``, ...,
    ``pinhole`` + ``radtan``, ``T_cn_cnm1`` = ``T_cn_w @ inv(T_cnm1_w)`` as ``setExtrinsicsLastCamToHere`` stores
    it, metres; dumped with ``yaml.dump``); followed as read, no code copied. k3 is left out (radtan has 4 terms)
    and each rotation made exact."""
    doc, previous = {}, None
    for i, c in enumerate(cams):
        U, _, Vt = np.linalg.svd(c.R)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = U @ Vt, c.t_cm / 100.0
        entry = {"camera_model": "pinhole", "intrinsics": [float(c.K[0, 0]), float(c.K[1, 1]), float(c.K[0, 2]),
                                                           float(c.K[1, 2])],
                 "distortion_model": "radtan", "distortion_coeffs": [float(v) for v in c.dist[:4]],
                 "resolution": list(c.resolution), "rostopic": f"/{c.name}/image_raw", "cam_overlaps": []}
        if previous is not None:
            entry["T_cn_cnm1"] = (T @ np.linalg.inv(previous)).tolist()
        doc[f"cam{i}"], previous = entry, T
    return doc


def in_cam0_frame(cams: list[Camera]) -> list[Camera]:
    """Our cameras without k3, in the first camera's frame (Kalibr's world: X_cam0 = R0 X + t0), cm."""
    U, _, Vt = np.linalg.svd(cams[0].R)
    R0, t0 = U @ Vt, cams[0].t_cm
    return [Camera(**{**c.__dict__, "dist": np.array([*c.dist[:4], 0.0]), "R": c.R @ R0.T,
                      "t_cm": c.t_cm - c.R @ R0.T @ t0}) for c in cams]


def projection_gap_worst_px(truth: list[Camera], got: list[Camera]) -> float:
    """Worst px between the two lists' projections of the truth's grid points (no ray check: for files whose
    cameras differ a little, written with few digits or without a term)."""
    X = world_points_cm(truth)
    return float(np.linalg.norm(pixels(truth, X) - pixels(got, X), axis=-1).max())


def dlt_columns(cams: list[Camera], height_px: int, unit_cm: float = 0.1, skew_px: float = 0.0) -> np.ndarray:
    """(11, C) easyWand DLT coefficients of pinhole cameras (distortion ignored; ``skew_px`` added to K[0, 1]) with
    lengths in units of ``unit_cm`` cm and pixels from the bottom left of images ``height_px`` high: column k is
    ``P.ravel()[:11]`` of ``P = flip K [R | t]`` scaled so that P[2, 3] = 1."""
    out = []
    for c in cams:
        K = c.K.copy()
        K[0, 1] += skew_px
        P = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, float(height_px)], [0.0, 0.0, 1.0]]) @ K @ np.c_[
            c.R, c.t_cm / unit_cm]
        out.append((P / P[2, 3]).ravel()[:11])
    return np.array(out).T


def dlt_pixels(L: np.ndarray, X: np.ndarray, height_px: int) -> np.ndarray:
    """(N, 2) OpenCV pixels of world points X (N, 3) (the DLT's unit) by the 11 coefficients ``L`` as the DLT defines
    them (u = (L1 x + L2 y + L3 z + L4) / (L9 x + L10 y + L11 z + 1), v alike with L5..L8), v from the bottom left."""
    w = X @ L[8:11] + 1.0
    u = (X @ L[0:3] + L[3]) / w
    v = (X @ L[4:7] + L[7]) / w
    return np.stack([u, height_px - v], axis=1)
