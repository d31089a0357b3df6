"""Synthetic Kinect depth frames of a known triangulated surface (a tent on the floor), and point-to-surface
distances: the ground truth for checking :mod:`dome_calib.recon.depth` end to end.

Depth is ray-cast through the depth camera's distorted model (ray per pixel centre from
``pixels_to_normalized``), then degraded with the sensor's bias model ``measured = true * (1 + depth_scale) +
depth_bias_mm``, Gaussian noise and 1 mm quantisation, as the Kinect v2 stores it (uint16 mm, 0 = no reading).
"""
from __future__ import annotations

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.recon.depth import MM_PER_CM, depth_rays
from dome_calib.recon.project import depth_from_world, kinect_sensor

KINECT_RANGE_MM = (500.0, 4500.0)


def tent_triangles(*, width_cm: float = 160.0, length_cm: float = 200.0, height_cm: float = 120.0,
                   floor_half_cm: float = 250.0) -> np.ndarray:
    """(F, 3, 3) world triangles (cm): an A-frame tent (ridge along z, height above the floor) on a square floor.

    Panoptic world: floor y = 0, up = -y.
    """
    w, L, H, f = width_cm / 2, length_cm / 2, -height_cm, floor_half_cm
    a, b, c, d = [-w, 0, -L], [w, 0, -L], [w, 0, L], [-w, 0, L]
    r0, r1 = [0, H, -L], [0, H, L]
    tris = [
        [a, r0, r1], [a, r1, d],  # left roof
        [b, c, r1], [b, r1, r0],  # right roof
        [a, b, r0], [d, r1, c],  # gables
        [[-f, 0, -f], [f, 0, -f], [f, 0, f]], [[-f, 0, -f], [f, 0, f], [-f, 0, f]],  # floor
    ]
    return np.asarray(tris, dtype=float)


def ray_cast(origins: np.ndarray, dirs: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Nearest hit parameter t (N,) of rays ``origin + t * dir`` with (F, 3, 3) triangles (Moller-Trumbore); inf
    where nothing is hit."""
    v0, e1, e2 = triangles[:, 0], triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    best = np.full(len(dirs), np.inf)
    for f in range(len(triangles)):  # a handful of triangles; vectorised over the rays
        p = np.cross(dirs, e2[f])
        det = p @ e1[f]
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = origins - v0[f]
        u = (s * p).sum(-1) * inv
        q = np.cross(s, e1[f])
        v = (dirs * q).sum(-1) * inv
        t = (q @ e2[f]) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
        best = np.where(hit & (t < best), t, best)
    return best


def render_depth_mm(bundle: Bundle, node: str, triangles: np.ndarray, *, noise_mm: float = 2.0,
                    rng: np.random.Generator | None = None) -> np.ndarray:
    """(H, W) uint16 depth frame (mm) of the world ``triangles`` seen by Kinect ``node``, with bias, noise and
    quantisation; 0 where nothing is hit or outside the Kinect's 0.5-4.5 m range."""
    sensor = kinect_sensor(bundle, node)
    rng = rng or np.random.default_rng(0)
    rays = depth_rays(sensor)
    h, w = rays.shape[:2]
    R, t = depth_from_world(bundle, node)
    d_cam = np.concatenate([rays.reshape(-1, 2), np.ones((h * w, 1))], axis=1)
    dirs = d_cam @ R  # R^T d: camera-frame z of origin + s * dir grows by s, so s is the depth (cm)
    origin = -R.T @ t
    z_mm = ray_cast(np.broadcast_to(origin, dirs.shape), dirs, triangles) * MM_PER_CM
    measured = z_mm * (1.0 + sensor.depth_scale) + sensor.depth_bias_mm + rng.normal(scale=noise_mm, size=z_mm.shape)
    valid = np.isfinite(z_mm) & (z_mm >= KINECT_RANGE_MM[0]) & (z_mm <= KINECT_RANGE_MM[1])
    return np.where(valid, np.clip(np.round(measured), 1, 65535), 0).astype(np.uint16).reshape(h, w)


def distance_to_triangles(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N,) Euclidean distance from (N, 3) points to the nearest of (F, 3, 3) triangles (same unit)."""
    best = np.full(len(points), np.inf)
    for tri in triangles:
        a, b, c = tri
        n = np.cross(b - a, c - a)
        n = n / np.linalg.norm(n)
        d_plane = (points - a) @ n
        foot = points - d_plane[:, None] * n
        inside = np.ones(len(points), dtype=bool)
        for p, q in ((a, b), (b, c), (c, a)):
            inside &= np.cross(q - p, foot - p) @ n >= 0
        distance_cm = np.where(inside, np.abs(d_plane), np.inf)
        for p, q in ((a, b), (b, c), (c, a)):
            s = np.clip(((points - p) @ (q - p)) / ((q - p) @ (q - p)), 0.0, 1.0)
            distance_cm = np.minimum(distance_cm, np.linalg.norm(points - (p + s[:, None] * (q - p)), axis=1))
        best = np.minimum(best, distance_cm)
    return best
