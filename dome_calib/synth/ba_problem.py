"""Synthetic bundle-adjustment problems like the dome's, with ground truth (for tests and bench/ba.py).

Points lie on a tent-like surface (the upper part of an ellipsoid about 1.6 m x 2 m x 1.3 m standing on the
floor near the dome centre), one placement per scene. A point is visible in a camera when it projects into
the image inside the lens's valid range and the surface faces the camera; each visible pair is kept with a
probability that gives the requested number of observations (feature matching never finds all of them).
Pixels get Gaussian noise and a fraction are replaced by gross outliers (uniform over the image).
The start is perturbed like an SfM result: centres off by a few cm, rotations by a fraction of a degree,
focal lengths by a few %, distortion zero, points off by a cm or so.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.ba.problem import BAProblem
from dome_calib.bundle import Camera
from dome_calib.camera import project
from dome_calib.rotation import matrix_to_rotvec, rotvec_to_matrix
from dome_calib.options import AtLeast, UnitInterval, options
from dome_calib.schema import NonNegFinite

TENT_CENTRE_CM = np.array([0.0, -95.0, 0.0])  # ellipsoid centre in the tent frame (y down, floor at y = 0)
TENT_RADII_CM = np.array([80.0, 105.0, 65.0])


@options
class SyntheticOptions:
    n_points: AtLeast(1) = 100_000  # over all scenes, before dropping points seen fewer than twice
    n_scenes: AtLeast(1) = 3
    target_observations: AtLeast(1) = 1_000_000
    noise_px: NonNegFinite = 0.5
    outlier_fraction: UnitInterval = 0.01
    center_noise_cm: NonNegFinite = 3.0  # per axis
    rotation_noise_deg: NonNegFinite = 0.2  # per axis
    focal_noise: NonNegFinite = 0.02  # relative, same factor for fx and fy
    principal_point_noise_px: NonNegFinite = 2.0
    point_noise_cm: NonNegFinite = 1.0
    seed: AtLeast(0) = 0
    #: where each scene's tent stands (cm, world frame; one per scene, ``n_scenes`` of them): None, near the dome
    #: centre (the first at it, the others within 40 cm); given, each scene's tent at its place, turned at random
    scene_centres_cm: tuple[tuple[float, float, float], ...] | None = None


@dataclass(kw_only=True)
class SyntheticProblem:
    """truth: true parameters with the noisy observations; start: the perturbed initial problem (same
    observations); is_outlier (M,) bool: gross outliers; noise_px: the Gaussian sigma used."""

    truth: BAProblem
    start: BAProblem
    is_outlier: np.ndarray
    noise_px: float


def tent_points(n: int, rng: np.random.Generator, *, yaw_rad: float, offset_cm: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) points on the tent surface above the floor in the world frame, and their (n, 3) outward normals."""
    pts, nrm = [], []
    while sum(len(p) for p in pts) < n:
        d = rng.normal(size=(2 * n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        X = TENT_CENTRE_CM + d * TENT_RADII_CM
        keep = X[:, 1] < -5.0
        pts.append(X[keep])
        nrm.append((d / TENT_RADII_CM)[keep])
    X, N = np.concatenate(pts)[:n], np.concatenate(nrm)[:n]
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    Ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    N = N @ Ry.T
    return X @ Ry.T + offset_cm, N / np.linalg.norm(N, axis=1, keepdims=True)


def _visible_pairs(cams: list[Camera], X: np.ndarray, normals: np.ndarray, chunk: int = 48
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All (camera, point) pairs where the point is seen: (K,) cam, (K,) point, (K, 2) true pixels."""
    out_c, out_p, out_uv = [], [], []
    centers = np.stack([c.center_cm for c in cams])
    for s in range(0, len(cams), chunk):
        sub = cams[s:s + chunk]
        proj = project(X, np.stack([c.R for c in sub]), np.stack([c.t_cm for c in sub]),
                       np.stack([c.intr for c in sub]), np.stack([c.dist for c in sub]))
        vis = proj.in_image(np.array([c.resolution for c in sub]))
        facing = np.einsum("pk,cpk->cp", normals, centers[s:s + chunk, None, :] - X[None]) > 0
        ci, pi = np.nonzero(vis & facing)
        out_c.append(ci + s)
        out_p.append(pi)
        out_uv.append(proj.uv_px[ci, pi])
    return np.concatenate(out_c), np.concatenate(out_p), np.concatenate(out_uv)


def make_problem(cameras: list[Camera], options: SyntheticOptions | None = None) -> SyntheticProblem:
    """A seeded synthetic problem over ``cameras`` (ground truth) with noisy observations and a perturbed start."""
    o = options or SyntheticOptions()
    if o.scene_centres_cm is not None and len(o.scene_centres_cm) != o.n_scenes:
        raise ValueError(f"scene_centres_cm has {len(o.scene_centres_cm)} places for {o.n_scenes} scenes")
    rng = np.random.default_rng(o.seed)
    per_scene = np.full(o.n_scenes, o.n_points // o.n_scenes)
    per_scene[: o.n_points - per_scene.sum()] += 1
    scenes, cam_l, pt_l, uv_l, offset = {}, [], [], [], 0
    for s, n in enumerate(per_scene):
        yaw = rng.uniform(0, 2 * np.pi)
        off = np.array([rng.uniform(-40, 40), 0.0, rng.uniform(-40, 40)]) if s else np.zeros(3)
        if o.scene_centres_cm is not None:
            off = np.asarray(o.scene_centres_cm[s], dtype=float)
        X, N = tent_points(int(n), rng, yaw_rad=yaw, offset_cm=off)
        ci, pi, uv = _visible_pairs(cameras, X, N)
        scenes[f"scene_{s + 1:02d}"] = X
        cam_l.append(ci)
        pt_l.append(pi + offset)
        uv_l.append(uv)
        offset += len(X)
    cam, pt, uv = np.concatenate(cam_l), np.concatenate(pt_l), np.concatenate(uv_l)
    keep = rng.random(len(cam)) < min(1.0, o.target_observations / max(len(cam), 1))
    counts = np.bincount(pt[keep], minlength=offset)
    keep &= counts[pt] >= 2
    cam, pt, uv = cam[keep], pt[keep], uv[keep]
    uv = uv + rng.normal(scale=o.noise_px, size=uv.shape)
    is_out = rng.random(len(cam)) < o.outlier_fraction
    wh = np.array([cameras[c].resolution for c in cam[is_out]], dtype=float).reshape(-1, 2)
    uv[is_out] = rng.random((int(is_out.sum()), 2)) * wh - 0.5
    truth = BAProblem.from_cameras(cameras, scenes, camera_index=cam, point_index=pt, uv_px=uv,
                                   camera_names=[c.name for c in cameras])
    start = truth.copy()
    p = start.camera_params
    C = len(cameras)
    R_true = rotvec_to_matrix(p[:, 0:3])
    centers = -np.einsum("cji,cj->ci", R_true, p[:, 3:6]) + rng.normal(scale=o.center_noise_cm, size=(C, 3))
    R = rotvec_to_matrix(np.radians(rng.normal(scale=o.rotation_noise_deg, size=(C, 3)))) @ R_true
    p[:, 0:3] = matrix_to_rotvec(R)
    p[:, 3:6] = -np.einsum("cij,cj->ci", R, centers)
    p[:, 6:8] *= (1.0 + rng.normal(scale=o.focal_noise, size=(C, 1)))
    p[:, 8:10] += rng.normal(scale=o.principal_point_noise_px, size=(C, 2))
    p[:, 10:15] = 0.0
    start.points_cm = start.points_cm + rng.normal(scale=o.point_noise_cm, size=start.points_cm.shape)
    return SyntheticProblem(truth=truth, start=start, is_outlier=is_out, noise_px=o.noise_px)
