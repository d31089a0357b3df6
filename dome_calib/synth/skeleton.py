"""A synthetic moving skeleton (Panoptic COCO-19 joints) and its 2D detections in every stream, for benches/tests.

The body walks on a circle around the dome centre (~0.6 m/s) with swinging arms and legs, a bobbing torso and a
turning head; joint positions are an analytic function of universal time, so any camera can be sampled at its
own frame times. Detections are the projections at each stream's frame times (from its sync table) plus Gaussian
pixel noise, with a fraction of wrong detections (for left/right joints half are the mirror joint, the typical
detector confusion, the rest uniformly random in the image; midline joints: all random). Self-occlusion is not modelled: a joint is detected where it
projects inside the image.
"""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from dome_calib.bundle import Bundle, SyncTable, SyncTables
from dome_calib.recon.project import project_points, view_set
from dome_calib.recon.streams import StreamTracks, cameras_by_stream

#: Panoptic ``joints19`` order (hdPose3d_stage1_coco19).
JOINTS19 = ["neck", "nose", "body_center", "l_shoulder", "l_elbow", "l_wrist", "l_hip", "l_knee", "l_ankle",
            "r_shoulder", "r_elbow", "r_wrist", "r_hip", "r_knee", "r_ankle", "l_eye", "l_ear", "r_eye", "r_ear"]
#: Index of each joint's left/right mirror (itself for the midline).
MIRROR19 = np.array([0, 1, 2, 9, 10, 11, 12, 13, 14, 3, 4, 5, 6, 7, 8, 17, 18, 15, 16])

#: BODY_25's foot joints in its order (OpenPose: LBigToe, LSmallToe, LHeel, RBigToe, RSmallToe, RHeel).
FEET = ("l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel")


def feet_cm(X: np.ndarray) -> np.ndarray:
    """(..., 19, 3) joints19 (Panoptic, y down) -> (..., 6, 3) feet in :data:`FEET`'s order, rigid with each ankle and
    the hips' frame (forward = down x across): big toe 15 cm forward and 6 cm down, small toe 3.5 cm outward of it,
    heel 5 cm back and 6 cm down; constant bones by construction (the synthetic body has no feet of its own)."""
    across = X[..., JOINTS19.index("l_hip"), :] - X[..., JOINTS19.index("r_hip"), :]
    across = across / np.linalg.norm(across, axis=-1, keepdims=True)
    down = np.zeros_like(across)
    down[..., 1] = 1.0
    forward = np.cross(down, across)
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    out = []
    for side, ankle in ((1.0, JOINTS19.index("l_ankle")), (-1.0, JOINTS19.index("r_ankle"))):
        a = X[..., ankle, :]
        big = a + 15.0 * forward + 6.0 * down
        out += [big, big + side * 3.5 * across, a - 5.0 * forward + 6.0 * down]
    return np.stack(out, axis=-2)


VGA_FPS = Fraction(25)
HD_FPS = Fraction(30000, 1001)
KINECT_FPS = Fraction(30)


def _rot_x(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(angle), np.zeros_like(angle)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def walking_body_local_cm(univ_time_ms: np.ndarray) -> np.ndarray:
    """(T,) universal times (ms) -> (T, 19, 3) the walking body's joints in its own frame, cm: offsets from the body
    centre along (lateral: "left" joints at -x, down, forward). Stride 0.9 Hz, arms raised slowly, head turning;
    :func:`skeleton_cm` places it on its circle, :mod:`dome_calib.synth.group` takes its bone directions."""
    t = np.asarray(univ_time_ms, dtype=float) / 1000.0
    gait = 2 * np.pi * 0.9 * t  # stride frequency 0.9 Hz
    swing = 0.45 * np.sin(gait)
    raise_arm = 0.6 * (1 - np.cos(2 * np.pi * 0.25 * t))  # slow raise of the arms
    local = np.zeros((len(t), 19, 3))
    local[:, 0] = [0, -55, 0]  # neck above the body centre
    local[:, 1] = [0, -67, 8]
    local[:, 15], local[:, 17] = [-3, -71, 7], [3, -71, 7]
    local[:, 16], local[:, 18] = [-7, -69, -2], [7, -69, -2]
    for side, sh, el, wr, hip, kn, an in ((-1, 3, 4, 5, 6, 7, 8), (1, 9, 10, 11, 12, 13, 14)):
        arm = side * swing
        shoulder = np.array([18.0 * side, -50.0, 0.0])
        upper = _rot_x(arm) @ np.array([0.0, 28.0, 0.0])
        lift = raise_arm[:, None] * np.array([side * 20.0, -14.0, 0.0])
        local[:, sh] = shoulder
        local[:, el] = shoulder + upper + lift
        fore = _rot_x(arm - 0.5 - 0.4 * raise_arm) @ np.array([0.0, 25.0, 0.0])
        local[:, wr] = local[:, el] + fore + 1.6 * lift
        leg = -side * swing
        hip_p = np.array([10.0 * side, 0.0, 0.0])
        local[:, hip] = hip_p
        local[:, kn] = hip_p + _rot_x(leg) @ np.array([0.0, 45.0, 0.0])
        knee_bend = 0.3 * np.maximum(np.sin(gait * side), 0.0)
        local[:, an] = local[:, kn] + _rot_x(leg - knee_bend) @ np.array([0.0, 42.0, 0.0])
    # Head turns left/right slowly.
    yaw = 0.5 * np.sin(2 * np.pi * 0.3 * t)
    head = [1, 15, 16, 17, 18]
    hx, hz = local[:, head, 0].copy(), local[:, head, 2].copy()
    local[:, head, 0] = np.cos(yaw)[:, None] * hx + np.sin(yaw)[:, None] * hz
    local[:, head, 2] = -np.sin(yaw)[:, None] * hx + np.cos(yaw)[:, None] * hz
    return local


def skeleton_cm(univ_time_ms: np.ndarray, *, radius_cm: float = 60.0, speed_cm_s: float = 60.0) -> np.ndarray:
    """(T,) universal times (ms) -> (T, 19, 3) joint positions in the Panoptic world (cm, y down, floor y = 0)."""
    t = np.asarray(univ_time_ms, dtype=float) / 1000.0
    phase = speed_cm_s * t / radius_cm  # angle on the circle
    gait = 2 * np.pi * 0.9 * t  # stride frequency 0.9 Hz
    center = np.stack([radius_cm * np.cos(phase), -95.0 - 2.0 * np.cos(2 * gait), radius_cm * np.sin(phase)], -1)
    fwd = np.stack([-np.sin(phase), np.zeros_like(t), np.cos(phase)], -1)  # walking direction
    right = np.cross(fwd, [0.0, -1.0, 0.0])  # lateral axis (up = -y); "left" joints sit at -1 on it
    local = walking_body_local_cm(univ_time_ms)
    down = np.array([0.0, 1.0, 0.0])
    return (center[:, None] + local[..., 0:1] * right[:, None] + local[..., 1:2] * down
            + local[..., 2:3] * fwd[:, None])


def clock_table(fps: Fraction, *, start_ms: float, duration_ms: float, offset_ms: float = 0.0,
                drift_ppm: float = 0.0, first_index: int = 0, dropped: list[int] | None = None) -> SyncTable:
    """Frames of a free-running clock on universal time: ``t_k = offset + k / fps * (1 + drift)`` covering
    [start, start + duration], minus the ``dropped`` frame indices."""
    period_ms = float(1000 / fps) * (1.0 + drift_ppm * 1e-6)
    k0 = int(np.floor((start_ms - offset_ms) / period_ms)) - 1
    k1 = int(np.ceil((start_ms + duration_ms - offset_ms) / period_ms)) + 1
    k = np.arange(k0, k1 + 1)
    index = k - k0 + first_index
    keep = ~np.isin(index, dropped or [])
    return SyncTable(index=index[keep].astype(np.int64), univ_time_ms=offset_ms + k[keep] * period_ms)


def synthetic_sync(bundle: Bundle, *, start_ms: float, duration_ms: float, seed: int = 0) -> SyncTables:
    """VGA 25 fps, HD 30000/1001 fps and every Kinect colour camera's own ~30 fps clock, with offsets and drift.

    Each Kinect loses a few frames (dropped frames widen the bracket). Kinect depth tables share the colour clock
    shifted by half a frame (as a stand-in for the real depth/colour skew).
    """
    rng = np.random.default_rng(seed)
    streams = {
        "vga": clock_table(VGA_FPS, start_ms=start_ms, duration_ms=duration_ms, offset_ms=float(rng.uniform(0, 40)),
                           drift_ppm=float(rng.uniform(-30, 30)), first_index=100),
        "hd": clock_table(HD_FPS, start_ms=start_ms, duration_ms=duration_ms, offset_ms=float(rng.uniform(0, 33)),
                          first_index=120),
    }
    color, depth = {}, {}
    for name in sorted(bundle.of_type("kinect-color")):
        node = f"KINECTNODE{int(name.split('_')[1])}"
        offset, drift = float(rng.uniform(0, 33)), float(rng.uniform(-50, 50))
        n_frames = int(duration_ms / 33.3)
        dropped = sorted(rng.choice(np.arange(5, max(n_frames - 5, 8)), size=3, replace=False).tolist())
        color[node] = clock_table(KINECT_FPS, start_ms=start_ms, duration_ms=duration_ms, offset_ms=offset,
                                  drift_ppm=drift, dropped=dropped)
        depth[node] = clock_table(KINECT_FPS, start_ms=start_ms, duration_ms=duration_ms, offset_ms=offset + 16.7,
                                  drift_ppm=drift)
    return SyncTables(streams=streams, kinect_color=color, kinect_depth=depth)


@dataclass(kw_only=True)
class DetectionNoise:
    """2D detection model: Gaussian noise (px), fraction of wrong detections, confidence range of good ones."""

    noise_px: float = 2.0
    wrong_fraction: float = 0.10
    confidence: tuple[float, float] = (0.5, 1.0)


def synthetic_tracks(bundle: Bundle, cameras: list[str], *, truth_bundle: Bundle | None = None,
                     noise: DetectionNoise | None = None, seed: int = 0) -> list[StreamTracks]:
    """2D tracks of :func:`skeleton_cm` in ``cameras`` at each stream's frame times (from ``bundle.sync``).

    ``truth_bundle`` (default ``bundle``) supplies the cameras that "see" the skeleton, so a perturbed bundle can
    be evaluated against detections made by the true cameras.
    """
    noise = noise or DetectionNoise()
    truth = truth_bundle or bundle
    rng = np.random.default_rng(seed)
    groups, tables = cameras_by_stream(bundle, cameras)
    out = []
    for stream, names in groups.items():
        table = tables[stream]
        X = skeleton_cm(table.univ_time_ms)  # (F, 19, 3)
        F, J = X.shape[:2]
        proj = project_points(view_set(truth, names), X.reshape(-1, 3))
        uv = proj.uv_px.reshape(len(names), F, J, 2).transpose(1, 0, 2, 3).copy()
        vis = proj.visible.reshape(len(names), F, J).transpose(1, 0, 2)
        uv += rng.normal(scale=noise.noise_px, size=uv.shape)
        wrong = rng.random(vis.shape) < noise.wrong_fraction
        mirror = wrong & (rng.random(vis.shape) < 0.5) & (MIRROR19 != np.arange(J))
        uv[mirror] = uv[:, :, MIRROR19][mirror]
        rand = wrong & ~mirror
        wh = np.array([truth.cameras[n].resolution for n in names], dtype=float)[None, :, None, :]
        uv[rand] = (rng.random((*vis.shape, 2)) * wh)[rand]
        conf = np.where(vis, rng.uniform(*noise.confidence, size=vis.shape), 0.0)
        uv[~vis] = np.nan
        out.append(StreamTracks(stream=stream, table=table, cameras=names, frame_index=table.index.copy(),
                                uv_px=uv, conf=conf))
    return out
