"""A small labelled group for the reconstruction tests: P walking bodies spread around the dome centre, projected
into cameras at their own stream frame times, with noise, misses, left/right swaps and false people; the truth
identity of each detection is returned beside it (the tests' oracle; the reconstruction never sees it)."""
from __future__ import annotations

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.recon.body_models import MIRROR19
from dome_calib.recon.project import project_points, view_set
from dome_calib.recon.streams import stream_of_camera
from dome_calib.synth.skeleton import skeleton_cm


def group_joints_cm(times_ms: np.ndarray, n_people: int, seed: int = 0) -> np.ndarray:
    """(T,) ms -> (T, P, 19, 3): person k walks a circle of radius 35 cm around its own centre; the centres lie on
    a ring of radius 90-170 cm, at least ~85 cm apart."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_people):
        angle = 2 * np.pi * k / max(n_people, 1) + rng.uniform(-0.2, 0.2)
        ring = 90.0 + 80.0 * (k % 2) if n_people > 4 else 100.0
        centre = np.array([ring * np.cos(angle), 0.0, ring * np.sin(angle)])
        X = skeleton_cm(np.asarray(times_ms, float) + 1700.0 * k, radius_cm=35.0, speed_cm_s=50.0 + 10 * k)
        out.append(X + centre)
    return np.stack(out, axis=1)


def group_detections(bundle: Bundle, cameras: list[str], n_people: int, *, seed: int = 0, noise_px: float = 2.0,
                     miss: float = 0.05, swap: float = 0.02, false_people: float = 0.05,
                     truth_bundle: Bundle | None = None, shared_frames: np.ndarray | None = None):
    """Detections of :func:`group_joints_cm` -> (people, labels): camera -> {frame -> (N, 19, 3)} and camera ->
    {frame -> (N,) truth index, -1 = false person}. Each stream's frames cover its sync table (or
    ``shared_frames`` at 30 fps when the bundle has none)."""
    rng = np.random.default_rng(seed)
    truth = truth_bundle or bundle
    people: dict[str, dict[int, np.ndarray]] = {}
    labels: dict[str, dict[int, np.ndarray]] = {}
    for cam in cameras:
        if bundle.sync is None:
            frames = np.asarray(shared_frames)
            times = frames * 1000.0 / 30.0
        else:
            _, table = stream_of_camera(bundle, cam)
            frames, times = table.index, table.univ_time_ms
        X = group_joints_cm(times, n_people, seed)  # (F, P, 19, 3)
        F = len(frames)
        proj = project_points(view_set(truth, [cam]), X.reshape(-1, 3))
        uv = proj.uv_px[0].reshape(F, n_people, 19, 2) + rng.normal(scale=noise_px, size=(F, n_people, 19, 2))
        vis = proj.visible[0].reshape(F, n_people, 19) & (rng.random((F, n_people, 19)) > miss)
        sw = rng.random((F, n_people)) < swap
        uv[sw] = uv[sw][:, MIRROR19]
        vis[sw] = vis[sw][:, MIRROR19]
        conf = np.where(vis, rng.uniform(0.4, 1.0, vis.shape), 0.0)
        kp = np.concatenate([np.where(vis[..., None], uv, 0.0), conf[..., None]], axis=-1)
        w, h = truth.cameras[cam].resolution
        people[cam], labels[cam] = {}, {}
        for f in range(F):
            seen = np.flatnonzero(vis[f].sum(1) >= 4)
            rows, lab = [kp[f, seen]], [seen]
            if rng.random() < false_people:
                fake = kp[f, rng.integers(n_people)].copy()
                fake[:, :2] = fake[:, :2] - fake[:, :2].mean(0) + rng.uniform([0, 0], [w, h])
                rows.append(fake[None])
                lab.append(np.array([-1]))
            P = np.concatenate(rows)
            L = np.concatenate(lab)
            order = rng.permutation(len(P))
            people[cam][int(frames[f])] = P[order]
            labels[cam][int(frames[f])] = L[order]
    return people, labels
