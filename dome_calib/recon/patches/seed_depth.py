"""Seed patches from the Kinect depth maps (where the bundle has Kinects and depth frames are given): the CVPR 2014
method's own seeding.

At a seed time, one world point cloud from the depth frames of every Kinect nearest that time
(:func:`dome_calib.recon.depth.pointcloud_at`: each depth camera placed in the world through its colour camera in
the bundle); the points inside the capture volume and more than ``depth_floor_cm`` above the floor. One point per
``seed_spacing_cm`` cell (the one nearest the cell's centre, quantised to 1e-3 cm; ties by sensor, then pixel
order) is a seed; its normal is the least principal axis (SVD) of the cloud's points within the patch's size
(``size_cm / 2`` of it, at least ``normal_min_points``), its first plane axis the largest.

A Kinect's depth frame is not taken at the seed time (30 fps against the reference stream's own rate: up to half a
period off, 1.7 cm at 1 m/s), so each point is placed at the seed time in the images, as image seeds are: projected
into the reference camera that looks at it most nearly as its depth camera did (smallest angle at the point; the
normal facing the camera by more than ``min_cos_view``, the point in the image: the camera most likely to
see what the depth camera saw), followed from there by optical flow into the ``seed_views`` nearest cameras and
triangulated robustly (:func:`dome_calib.recon.patches.seed.flow_to_neighbours`, as image seeds are), if the image
can be tracked there (:func:`trackable`: the depth also sees the floor and the walls). The
triangulated seeds are thinned again as image seeds are (most inlier views, then the camera) and the normal's
sign is chosen by the cameras that see it (the triangulation's inliers). Every choice is per point on quantised
keys: the cloud depends on the depth frames and the images, never on how the work is cut.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.recon.depth import pointcloud_at
from dome_calib.recon.patches.frames import FrameSource, sample
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.seed import (Seeds, _normals, flow_to_neighbours, in_volume, patch_triplets,
                                           thin_to_cells)
from dome_calib.recon.project import ViewSet, depth_from_world, project_points, project_view
from dome_calib.recon.triangulate import TriangulationOptions, triangulate
from dome_calib import ties

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class DepthFrames:
    """The depth frames the patch stage seeds from: ``read_frame(node, k)`` -> (H, W) uint16 mm or None (a
    :class:`dome_calib.recon.depth.DepthFolder`: picklable, so executor tasks read their own frames); ``nodes`` the
    Kinects to use (None: every Kinect with a calibration and a depth sync table)."""

    read_frame: Callable[[str, int], np.ndarray | None]
    nodes: tuple[str, ...] | None = None


def _in_volume(X: np.ndarray, o: PatchOptions) -> np.ndarray:
    return in_volume(X, o, o.depth_floor_cm)


#: A seed is kept where its reference camera's image can be tracked: the structure tensor's smaller eigenvalue
#: (``cv2.cornerMinEigenVal``, 5 px blocks) at its pixel at least this share of the image's largest, the quality
#: level of the image seeds' corners (:func:`dome_calib.recon.patches.seed.seed_camera`). A flat background is not.
TRACKABLE_QUALITY = 0.02


def trackable(gray: np.ndarray, uv_px: np.ndarray) -> np.ndarray:
    """(M,) whether the image can be tracked at pixels (M, 2) (:data:`TRACKABLE_QUALITY`)."""
    eig = cv2.cornerMinEigenVal(gray, 5)
    return sample(eig, uv_px) >= TRACKABLE_QUALITY * float(eig.max())


def depth_points(bundle: Bundle, depth: DepthFrames, t_ms: float, o: PatchOptions, nodes: list[str] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The Kinects' depth nearest ``t_ms`` as thinned points with normals (steps 1-3 of the module): (M, 3) points,
    (M, 3) normals (towards their depth camera), (M, 3) first plane axes, (M, 3) their depth camera's centre.
    ``nodes``: these Kinects (None: ``depth.nodes``)."""
    use = nodes if nodes is not None else None if depth.nodes is None else list(depth.nodes)
    cloud = pointcloud_at(bundle, t_ms, depth.read_frame, nodes=use)
    keep = _in_volume(cloud.xyz_cm, o)
    P, sensor = cloud.xyz_cm[keep], cloud.sensor[keep].astype(np.int64)
    if len(P) == 0:
        return (np.zeros((0, 3)),) * 4
    sensor_centre = np.array([-R.T @ t for R, t in (depth_from_world(bundle, n) for n in cloud.sensors)])
    cell_centre = (np.floor(P / o.seed_spacing_cm) + 0.5) * o.seed_spacing_cm
    off = ties.quantize(np.linalg.norm(P - cell_centre, axis=1), ties.POINT_OFFSET_QUANTUM_CM)
    pick = thin_to_cells(P, [np.arange(len(P)), sensor, off], o.seed_spacing_cm)
    X = P[pick]
    one_hot = sensor[pick][:, None] == np.arange(len(cloud.sensors))[None]
    normal, axis, ok = _normals(X, P, one_hot, sensor_centre, o.size_cm / 2.0, o.normal_min_points)
    return X[ok], normal[ok], axis[ok], sensor_centre[sensor[pick][ok]]


def seed_from_own_kinect(bundle: Bundle, depth: DepthFrames, node: str, t_ms: float, source: FrameSource,
                         views: ViewSet, camera: int, frame: int, o: PatchOptions) -> Seeds:
    """Seeds from one Kinect's depth in its own colour camera (``views`` position ``camera``, its ``frame`` the one
    nearest ``t_ms``): a Kinect's colour camera is a stream of one camera (its own clock), which cannot triangulate a
    seed, but its depth gives the point. The depth nearest ``t_ms`` (its frame's time: the points are placed from
    there, :func:`dome_calib.recon.patches.run.place_seeds`; steps 1-3 of the module), kept where the colour
    camera sees the point (in its image, the normal facing it by more than ``min_cos_view``) and its image can be
    tracked there (:func:`trackable`); ``seen`` that camera alone (the MAP then judges every camera at the first
    tracking step, :func:`dome_calib.recon.patches.run.place_seeds`)."""
    V = len(views.names)
    X, normal, axis, _ = depth_points(bundle, depth, t_ms, o, nodes=[node])
    if len(X) == 0:
        return Seeds(X_cm=np.zeros((0, 3, 3)), normal=np.zeros((0, 3)), seen=np.zeros((0, V), bool))
    uv, visible = project_view(views, camera, X)
    to_cam = views.center_cm[camera][None] - X
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    ok = visible & ties.above(np.sum(to_cam * normal, 1), o.min_cos_view, ties.VIEW_COSINE_QUANTUM)
    idx = np.flatnonzero(ok)
    idx = idx[trackable(source.gray(views.names[camera], frame), uv[idx])] if len(idx) else idx
    seen = np.zeros((len(idx), V), bool)
    seen[:, camera] = True
    return Seeds(X_cm=patch_triplets(X[idx], normal[idx], axis[idx], o.axis_cm), normal=normal[idx], seen=seen)


def seed_from_depth(bundle: Bundle, depth: DepthFrames, seed_time_ms: float, source: FrameSource, views: ViewSet,
                    frames: dict[str, int], o: PatchOptions) -> Seeds:
    """A seed cloud from the Kinects' depth at ``seed_time_ms``, placed in the reference cameras ``views`` (as
    imaged; their ``frames`` are at the seed time). ``seen`` is over ``views``.

    Example:
        >>> seeds = seed_from_depth(bundle, DepthFrames(depth_folder_reader("depth")), t_ms, scene, ref_views,
        ...                         {n: 120 for n in ref_views.names}, PatchOptions())
    """
    V = len(views.names)
    empty = Seeds(X_cm=np.zeros((0, 3, 3)), normal=np.zeros((0, 3)), seen=np.zeros((0, V), bool))
    X, normal, axis, own = depth_points(bundle, depth, seed_time_ms, o)
    if len(X) == 0:
        return empty
    # the reference camera: the one looking at the point most nearly as its depth camera did
    proj = project_points(views, X)
    inside = proj.visible.T  # (N, V)
    to_cam = views.center_cm[None] - X[:, None]
    to_cam /= np.linalg.norm(to_cam, axis=-1, keepdims=True)
    to_own = own - X
    to_own /= np.linalg.norm(to_own, axis=-1, keepdims=True)
    faces = ties.above(np.sum(to_cam * normal[:, None], -1), o.min_cos_view, ties.VIEW_COSINE_QUANTUM)
    ref, has = ties.argmax_where(np.sum(to_cam * to_own[:, None], -1), inside & faces, ties.VIEW_COSINE_QUANTUM)
    tri_o = TriangulationOptions(inlier_threshold_px=o.triangulation_px, min_views=o.seed_min_views)
    centre_px = proj.uv_px  # (V, N, 2)
    got_X, got_seen, got_n, got_r, got_k = [], [], [], [], []
    for r in range(V):
        idx = np.flatnonzero(has & (ref == r))
        if len(idx) == 0:
            continue
        idx = idx[trackable(source.gray(views.names[r], frames[views.names[r]]), centre_px[r, idx])]
        if len(idx) == 0:
            continue
        uv, conf = flow_to_neighbours(source, views, frames, r, centre_px[r, idx], X[idx], o)
        tri = triangulate(views, uv, conf, tri_o)
        good = np.all(np.isfinite(tri.X_cm), axis=1) & tri.inliers[:, r]
        got_X.append(tri.X_cm[good]), got_seen.append(tri.inliers[good]), got_n.append(tri.n_inliers[good])
        got_r.append(np.full(good.sum(), r)), got_k.append(idx[good])
    if not got_X:
        return empty
    Xt, seen, n_inl = np.concatenate(got_X), np.concatenate(got_seen), np.concatenate(got_n)
    r_a, k_a = np.concatenate(got_r), np.concatenate(got_k)
    pick = thin_to_cells(Xt, [k_a, r_a, -n_inl], o.seed_spacing_cm)
    Xt, seen, k_a = Xt[pick], seen[pick], k_a[pick]
    n, a = normal[k_a], axis[k_a]
    towards = np.einsum("nv,vk->nk", seen.astype(float), views.center_cm) - seen.sum(1, keepdims=True) * Xt
    n = np.where(np.sum(n * towards, 1, keepdims=True) > 0, n, -n)
    logger.info("depth seed cloud at %.1f ms: %d cells with a normal, %d seeds", seed_time_ms, len(X), len(Xt))
    return Seeds(X_cm=patch_triplets(Xt, n, a, o.axis_cm), normal=n, seen=seen)
