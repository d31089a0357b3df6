"""Synthetic Kinect depth frames of a group in the dome: the people's bodies (their 12 capsules each,
:mod:`dome_calib.synth.body_volume`) in front of the floor and the dome's inner wall, seen by each Kinect's depth
camera at its own depth-stream frame times, so that the depth witness (:mod:`dome_calib.recon.people.depth_witness`)
is measured on what it would see.

Per depth pixel: the ray through its undistorted pixel centre (``pixels_to_normalized`` of the depth lens), the
nearest hit of any present person's capsule (ray against capsule: the cylinder between its end points, then the
two end spheres), else of the floor (y = 0), else of the dome's sphere from inside (its far side). Depth is the
camera-frame z of the hit. The sensor's model (``measured = true * (1 + depth_scale) + depth_bias_mm``), axial
noise ``sigma_1m_mm * (a + b z_m^2)`` (the witness's own noise model, Kinect v2) and 1 mm quantisation follow; no
reading (0) outside 0.5-4.5 m. Only the pixels round a person's projection test its capsules, and each capsule only
the rays that pass its bounding sphere.

Frames go to ``FOLDER/KINECTNODE<n>/depth_<k>.png`` (16-bit PNG, mm, ``k`` the depth sync table's index): the
layout ``dome-calib pointcloud`` and ``reconstruct --depth`` read.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.io_utils import atomic_folder
from dome_calib.layout import DOME_CENTRE_CM, DOME_RADIUS_CM
from dome_calib.recon.depth import MM_PER_CM, depth_rays
from dome_calib.recon.people.depth_witness import DepthWitnessOptions
from dome_calib.recon.project import depth_from_world, kinect_sensor
from dome_calib.synth.body_volume import capsules_cm
from dome_calib.synth.depth import KINECT_RANGE_MM
from dome_calib.synth.group import GroupTruth

_SLACK_PX = 12.0  # the depth lens's distortion, within the pinhole bound of a person's projection


def ray_capsules(origin: np.ndarray, dirs: np.ndarray, A: np.ndarray, B: np.ndarray, radius: np.ndarray
                 ) -> np.ndarray:
    """Nearest hit distance (N,) of rays ``origin + s * dirs`` (unit dirs (N, 3)) with capsules (K, 3), (K, 3),
    (K,); inf where none is hit (or only behind the origin)."""
    return nearest_capsule_hits(origin, dirs, A, B, radius)[0]


def nearest_capsule_hits(origin: np.ndarray, dirs: np.ndarray, A: np.ndarray, B: np.ndarray, radius: np.ndarray,
                         candidates: list[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ray_capsules` and which capsule each ray hits first: ((N,) distance, inf = none; (N,) capsule
    index, -1 = none). ``candidates``: per capsule, the rays that may meet it (indices; default all)."""
    best = np.full(len(dirs), np.inf)
    which = np.full(len(dirs), -1, dtype=np.int64)
    for k, (a, b, r) in enumerate(zip(A, B, radius)):
        centre = 0.5 * (a + b)  # the capsule's bounding sphere culls the rays first
        bound = 0.5 * np.linalg.norm(b - a) + r
        oc = centre - origin
        rays = None if candidates is None else candidates[k]
        near = dirs @ oc if rays is None else dirs[rays] @ oc
        sel = np.flatnonzero((near > -bound) & (oc @ oc - near * near < bound * bound))
        sel = sel if rays is None else rays[sel]
        if len(sel) == 0:
            continue
        s = _ray_capsule(origin, dirs[sel], a, b, r)
        nearer = s < best[sel]
        best[sel[nearer]], which[sel[nearer]] = s[nearer], k
    return best, which


def _ray_capsule(origin: np.ndarray, dirs: np.ndarray, a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """Nearest hit distance (N,) of unit rays with one capsule [a, b] of radius r (inf: none)."""
    ba = b - a
    oa = origin - a
    baba = ba @ ba
    bard = dirs @ ba
    baoa = oa @ ba
    rdoa = dirs @ oa
    oaoa = oa @ oa
    qa = baba - bard * bard
    qb = baba * rdoa - baoa * bard
    qc = baba * oaoa - baoa * baoa - r * r * baba
    h = qb * qb - qa * qc
    hit = h >= 0.0
    s = np.where(hit & (qa > 1e-12), (-qb - np.sqrt(np.maximum(h, 0.0))) / np.where(qa > 1e-12, qa, 1.0), np.inf)
    along = baoa + s * bard
    body = hit & np.isfinite(s) & (along > 0.0) & (along < baba) & (s > 0.0)
    out = np.where(body, s, np.inf)
    for end in (a, b):  # the end spheres
        oc = origin - end
        b2 = dirs @ oc
        c2 = oc @ oc - r * r
        h2 = b2 * b2 - c2
        s2 = -b2 - np.sqrt(np.maximum(h2, 0.0))
        out = np.where((h2 >= 0.0) & (s2 > 0.0), np.minimum(out, s2), out)
    return out


def _background(origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Distance (N,) to the floor (y = 0, seen from above) or else the far side of the dome's sphere."""
    c = origin - DOME_CENTRE_CM
    b = dirs @ c
    disc = b * b - (c @ c - DOME_RADIUS_CM ** 2)
    wall = np.where(disc >= 0.0, -b + np.sqrt(np.maximum(disc, 0.0)), np.inf)
    wall = np.where(wall > 0.0, wall, np.inf)
    down = dirs[:, 1] > 1e-9
    floor = np.where(down, -origin[1] / np.where(down, dirs[:, 1], 1.0), np.inf)
    floor = np.where(floor > 0.0, floor, np.inf)
    return np.minimum(wall, floor)


@dataclass(frozen=True)
class _Sensor:
    """One depth camera's rays, once: world unit directions (N, 3), origin, |d| of the z = 1 rays (N,), pose, K,
    image size, the static background's distance (N,), the sensor's depth model."""

    dirs: np.ndarray
    origin: np.ndarray
    norm: np.ndarray
    R: np.ndarray
    t: np.ndarray
    K: np.ndarray
    shape: tuple[int, int]
    background: np.ndarray
    depth_scale: float
    depth_bias_mm: float

    @staticmethod
    def of(bundle: Bundle, node: str) -> _Sensor:
        sensor = kinect_sensor(bundle, node)
        rays = depth_rays(sensor)
        h, w = rays.shape[:2]
        R, t = depth_from_world(bundle, node)
        d_cam = np.concatenate([rays.reshape(-1, 2), np.ones((h * w, 1))], axis=1)
        norm = np.linalg.norm(d_cam, axis=1)
        dirs = (d_cam / norm[:, None]) @ R  # world unit directions (R^T d)
        origin = -R.T @ t
        return _Sensor(dirs=dirs, origin=origin, norm=norm, R=R, t=t, K=sensor.K_depth, shape=(h, w),
                       background=_background(origin, dirs), depth_scale=sensor.depth_scale,
                       depth_bias_mm=sensor.depth_bias_mm)


def render_people_depth_mm(bundle: Bundle | _Sensor, node: str, X: np.ndarray, present: np.ndarray, *,
                           noise: DepthWitnessOptions | None = None, rng: np.random.Generator | None = None
                           ) -> np.ndarray:
    """(H, W) uint16 depth frame (mm) of Kinect ``node``: the present people of ``X`` (P, 19, 3) world cm in the
    dome, with the sensor's bias model, noise and 1 mm quantisation; 0 = no reading."""
    cam = bundle if isinstance(bundle, _Sensor) else _Sensor.of(bundle, node)
    noise = noise or DepthWitnessOptions()
    rng = rng or np.random.default_rng(0)
    h, w = cam.shape
    dist = cam.background.copy()
    people = np.flatnonzero(np.asarray(present, dtype=bool))
    K = cam.K
    pix = np.arange(h * w).reshape(h, w)
    for A, B, rad in zip(*capsules_cm(np.asarray(X, dtype=float)[people])) if len(people) else ():
        # the rays of the pixels round the person's projection (pinhole, with slack for the lens and the radius)
        pts = np.concatenate([A, B]) @ cam.R.T + cam.t
        if np.any(pts[:, 2] <= 1.0):
            sel = pix.ravel()
        else:
            u = K[0, 0] * pts[:, 0] / pts[:, 2] + K[0, 2]
            v = K[1, 1] * pts[:, 1] / pts[:, 2] + K[1, 2]
            pad = K[0, 0] * rad.max() / pts[:, 2].min() + _SLACK_PX
            u0, u1 = int(max(np.floor(u.min() - pad), 0)), int(min(np.ceil(u.max() + pad), w - 1))
            v0, v1 = int(max(np.floor(v.min() - pad), 0)), int(min(np.ceil(v.max() + pad), h - 1))
            if u0 > u1 or v0 > v1:
                continue
            sel = pix[v0:v1 + 1, u0:u1 + 1].ravel()
        dist[sel] = np.minimum(dist[sel], ray_capsules(cam.origin, cam.dirs[sel], A, B, rad))
    z_mm = dist / cam.norm * MM_PER_CM  # ray length -> camera-frame z
    valid = np.isfinite(z_mm) & (z_mm >= KINECT_RANGE_MM[0]) & (z_mm <= KINECT_RANGE_MM[1])
    z_mm = np.where(valid, z_mm, 0.0)
    measured = z_mm * (1.0 + cam.depth_scale) + cam.depth_bias_mm + rng.standard_normal(z_mm.shape) * noise.sigma_mm(
        z_mm)
    return np.where(valid, np.clip(np.round(measured), 1, 65535), 0).astype(np.uint16).reshape(h, w)


def write_group_depth(folder: str | Path, bundle: Bundle, truth: GroupTruth, span_ms: tuple[float, float], *,
                      nodes: list[str] | None = None, seed: int = 0,
                      noise: DepthWitnessOptions | None = None) -> Path:
    """Every depth frame of every Kinect (with a calibration and a depth sync table; or ``nodes``) whose time lies in
    ``span_ms``, as ``FOLDER/KINECTNODE<n>/depth_<k>.png`` (the folder written whole: staged, then renamed). Each
    frame's noise comes from ``default_rng([seed, crc32(node), k])``."""
    tables = bundle.sync.kinect_depth if bundle.sync is not None else {}
    known = bundle.kinect.sensors if bundle.kinect is not None else {}
    nodes = nodes if nodes is not None else sorted((n for n in tables if n in known), key=lambda n: (len(n), n))
    with atomic_folder(Path(folder)) as staging:
        for node in nodes:
            table = tables[node]
            keep = (table.univ_time_ms >= span_ms[0]) & (table.univ_time_ms <= span_ms[1])
            X, present = truth.joints_cm(table.univ_time_ms[keep])
            cam = _Sensor.of(bundle, node)
            sub = staging / node
            sub.mkdir()
            for k, idx in enumerate(table.index[keep]):
                rng = np.random.default_rng([seed, zlib.crc32(node.encode("utf-8")), int(idx)])
                depth = render_people_depth_mm(cam, node, X[k], present[k], noise=noise, rng=rng)
                cv2.imwrite(str(sub / f"depth_{int(idx):04d}.png"), depth)
    return Path(folder)
