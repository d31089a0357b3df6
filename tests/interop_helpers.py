"""Helpers of the interop tests: pixel grids over the whole image, world points behind them, projection and ray
gaps between two cameras (px)."""
from __future__ import annotations

import numpy as np

from dome_calib.bundle import Camera
from dome_calib.camera import pixels_to_normalized, project

DEPTHS_CM = (30.0, 300.0, 3000.0)


def grid_px(cam: Camera, n: int = 9) -> np.ndarray:
    """(n*n, 2) OpenCV pixels covering the image edge to edge, the four outer corners included."""
    w, h = cam.resolution
    u, v = np.meshgrid(np.linspace(-0.5, w - 0.5, n), np.linspace(-0.5, h - 0.5, n))
    return np.stack([u.ravel(), v.ravel()], axis=1)


def world_points_cm(cam: Camera, n: int = 9) -> np.ndarray:
    """(3 n^2, 3) world points (cm) on the pinhole rays of the grid pixels, at 30 cm, 3 m and 30 m."""
    xn = (grid_px(cam, n) - cam.intr[2:]) / cam.intr[:2]
    rays = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)
    X_cam = np.concatenate([d * rays for d in DEPTHS_CM])
    return (X_cam - cam.t_cm) @ cam.R  # R^T (X_cam - t), row-wise


def pixels(cam: Camera, X_cm: np.ndarray) -> np.ndarray:
    return project(X_cm, cam.R, cam.t_cm, cam.intr, cam.dist).uv_px


def projection_gap_px(a: Camera, b: Camera) -> float:
    """Largest pixel distance between the two cameras' projections of ``a``'s grid world points."""
    X = world_points_cm(a)
    return float(np.linalg.norm(pixels(a, X) - pixels(b, X), axis=1).max())


def ray_gap_px(a: Camera, b: Camera) -> float:
    """Largest angle (as px at ``a``'s focal length) between the world rays both cameras unproject from the grid
    pixels. Pixels beyond the lens's monotonic range (no ray) must be so for both."""
    rays = []
    for cam in (a, b):
        xn = pixels_to_normalized(grid_px(a), cam.intr, cam.dist)
        d = np.concatenate([xn, np.ones((len(xn), 1))], axis=1) @ cam.R  # world directions R^T x
        rays.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    ok_a, ok_b = np.isfinite(rays[0][:, 0]), np.isfinite(rays[1][:, 0])
    assert np.array_equal(ok_a, ok_b), "one camera unprojects a pixel the other cannot"
    cos = np.clip(np.sum(rays[0][ok_a] * rays[1][ok_a], axis=1), -1, 1)
    sin = np.linalg.norm(np.cross(rays[0][ok_a], rays[1][ok_a]), axis=1)
    return float(np.max(np.arctan2(sin, cos), initial=0.0) * a.intr[:2].max())
