"""Reconstruction with known cameras: what the quick recalibration does instead of mapping.

When a previous calibration is good for most cameras, a scene needs no mapping: the tent is triangulated
from the verified matches of the cameras held at their prior poses (COLMAP's point triangulator,
:func:`pycolmap.triangulate_points`), and each camera to re-estimate is registered against those points
(2D-3D correspondences through its verified matches, then pycolmap's LO-RANSAC absolute pose with non-linear
refinement). :func:`observations_from_known` turns the result into the :class:`Observations` of the fine bundle
adjustment, in the prior's frame (cm).
"""
from __future__ import annotations

import logging
import shutil
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pycolmap

from dome_calib.bundle import Camera
from dome_calib.camera import colmap_to_opencv_px
from dome_calib.colmap_options import colmap_options
from projector.database import camera_of_image, to_colmap_camera, verified_partner_ids
from projector.observations import Observations

logger = logging.getLogger(__name__)

PNP_MAX_ERROR_PX = 12.0  # generous: a replaced camera is registered with its predecessor's lens
MIN_PNP_INLIERS = 30


@dataclass(kw_only=True)
class Registration:
    """A camera registered against known points: its pose (prior intrinsics), and its inlier correspondences."""

    camera: Camera
    point3D_ids: np.ndarray  # (N,) ids in the reconstruction
    uv_px: np.ndarray  # (N, 2) OpenCV pixels
    num_candidates: int
    keypoint_idx: np.ndarray  # (N,) the observations' keypoint indices in the camera's image of the database


def add_posed_image(rec: pycolmap.Reconstruction, db: pycolmap.Database, db_image: pycolmap.Image,
                    camera: Camera) -> None:
    """Put a database image into ``rec`` at ``camera``'s pose and intrinsics, with its keypoints (no observations)."""
    colmap_cam = to_colmap_camera(camera)
    colmap_cam.camera_id = db_image.camera_id
    rec.add_camera_with_trivial_rig(colmap_cam)
    keypoints = np.asarray(db.read_keypoints(db_image.image_id)[:, :2], dtype=np.float64)
    image = pycolmap.Image(name=db_image.name, keypoints=keypoints, camera_id=db_image.camera_id,
                           image_id=db_image.image_id)
    rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(camera.R), camera.t_cm))


def triangulate_known(database_path: str | Path, image_dir: str | Path, output_dir: str | Path,
                      cameras: Mapping[str, Camera], names: Iterable[str],
                      options: pycolmap.IncrementalPipelineOptions | None = None) -> pycolmap.Reconstruction:
    """Points of a scene triangulated from the verified matches of ``names``, held at ``cameras`` (pose and
    intrinsics). Images of other cameras stay out of the reconstruction. ``options``: the triangulator's and
    filter's thresholds (default COLMAP's)."""
    names = set(names)
    rec = pycolmap.Reconstruction()
    with pycolmap.Database.open(str(database_path)) as db:
        for im in db.read_all_images():
            if camera_of_image(im.name) in names:
                add_posed_image(rec, db, im, cameras[camera_of_image(im.name)])
    output_dir = Path(output_dir)
    if output_dir.exists():
        shutil.rmtree(output_dir)
    output_dir.mkdir(parents=True)
    options = options or colmap_options(pycolmap.IncrementalPipelineOptions)
    return pycolmap.triangulate_points(rec, str(database_path), str(image_dir), str(output_dir), options=options)


def verified_partners(database_path: str | Path) -> dict[str, set[str]]:
    """Camera -> the cameras it has a verified pair with in a scene database."""
    with pycolmap.Database.open(str(database_path)) as db:
        names = {im.image_id: camera_of_image(im.name) for im in db.read_all_images()}
        return {names[a]: {names[b] for b in bs} for a, bs in verified_partner_ids(db).items()}


def _correspondences(db: pycolmap.Database, image_id: int, rec: pycolmap.Reconstruction,
                     partners: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(keypoint index, point3D id) of ``image_id`` through its verified matches with registered ``partners``;
    a keypoint voted to several points keeps the most voted (then the lowest id), one keypoint per point."""
    kp_idx, pt_ids = [], []
    for other in partners:
        tvg = db.read_two_view_geometry(image_id, other)
        m = np.asarray(tvg.inlier_matches)
        if not len(m):
            continue
        image = rec.image(other)
        ids = np.array([image.points2D[int(j)].point3D_id if image.points2D[int(j)].has_point3D() else -1
                        for j in m[:, 1]], dtype=np.int64)
        ok = ids >= 0
        kp_idx.append(m[ok, 0].astype(np.int64))
        pt_ids.append(ids[ok])
    if not kp_idx:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    votes = np.stack([np.concatenate(kp_idx), np.concatenate(pt_ids)], axis=1)
    pairs, counts = np.unique(votes, axis=0, return_counts=True)
    order = np.lexsort((pairs[:, 1], -counts))  # most voted first
    pairs = pairs[order]
    _, first_kp = np.unique(pairs[:, 0], return_index=True)
    pairs = pairs[np.sort(first_kp)]
    _, first_pt = np.unique(pairs[:, 1], return_index=True)
    pairs = pairs[np.sort(first_pt)]
    return pairs[:, 0], pairs[:, 1]


def register_cameras(database_path: str | Path, rec: pycolmap.Reconstruction, cameras: Mapping[str, Camera],
                     names: Iterable[str]) -> tuple[dict[str, Registration], dict[str, str]]:
    """Register each camera of ``names`` against the points of ``rec`` (``cameras`` gives the intrinsics and
    type). Returns the registrations and, for the cameras that could not be registered, the reason."""
    done: dict[str, Registration] = {}
    failed: dict[str, str] = {}
    registered = {im.image_id for im in rec.images.values() if im.has_pose}
    estimation = colmap_options(pycolmap.AbsolutePoseEstimationOptions)
    estimation.ransac.max_error = PNP_MAX_ERROR_PX
    refinement = colmap_options(pycolmap.AbsolutePoseRefinementOptions)
    with pycolmap.Database.open(str(database_path)) as db:
        ids = {camera_of_image(im.name): im.image_id for im in db.read_all_images()}
        partners = verified_partner_ids(db)
        for name in sorted(names):
            if name not in ids:
                failed[name] = "no features in this scene"
                continue
            image_id = ids[name]
            kp, pts = _correspondences(db, image_id, rec, sorted(partners.get(image_id, set()) & registered))
            if len(kp) < MIN_PNP_INLIERS:
                failed[name] = f"only {len(kp)} matches to points of unchanged cameras (need {MIN_PNP_INLIERS})"
                continue
            uv_colmap = np.asarray(db.read_keypoints(image_id)[:, :2], dtype=np.float64)[kp]
            X = np.stack([rec.point3D(int(p)).xyz for p in pts])
            cam = cameras[name]
            answer = pycolmap.estimate_and_refine_absolute_pose(uv_colmap, X, to_colmap_camera(cam), estimation,
                                                                refinement)
            if answer is None or int(answer["num_inliers"]) < MIN_PNP_INLIERS:
                n_in = 0 if answer is None else int(answer["num_inliers"])
                failed[name] = f"absolute pose failed ({n_in} inliers of {len(kp)} correspondences)"
                continue
            inl = np.asarray(answer["inlier_mask"], dtype=bool)
            pose = answer["cam_from_world"]
            R = np.asarray(pose.rotation.matrix())
            done[name] = Registration(camera=replace(cam, R=R, t_cm=np.asarray(pose.translation, float)),
                                      point3D_ids=pts[inl], uv_px=colmap_to_opencv_px(uv_colmap[inl]),
                                      num_candidates=len(kp), keypoint_idx=kp[inl])
    return done, failed


def observations_from_known(rec: pycolmap.Reconstruction, cameras: Mapping[str, Camera],
                       registrations: Mapping[str, Registration], scene: str) -> Observations:
    """The observations of the points seen by the registered cameras: their observations in the
    held cameras of ``rec`` and in the registered ones. Cameras: held ones at ``cameras``, registered ones at
    their new pose. Everything starts free (fix what must stay)."""
    wanted = {int(p) for r in registrations.values() for p in r.point3D_ids}
    point_ids = sorted(wanted)
    point_index = {p: i for i, p in enumerate(point_ids)}
    held = {im.image_id: camera_of_image(im.name) for im in rec.images.values() if im.has_pose}
    observer, pi, xy_colmap = [], [], []  # held cameras that see none of these points stay out of the problem
    for p in point_ids:
        for el in rec.point3D(p).track.elements:
            observer.append(held[el.image_id])
            pi.append(point_index[p])
            xy_colmap.append(rec.image(el.image_id).points2D[el.point2D_idx].xy)
    uv = [colmap_to_opencv_px(np.array(xy_colmap, dtype=float).reshape(-1, 2))]
    for n, r in registrations.items():
        observer += [n] * len(r.point3D_ids)
        pi += [point_index[int(p)] for p in r.point3D_ids]
        uv.append(r.uv_px)
    names = sorted(set(observer))
    cam_index = {n: i for i, n in enumerate(names)}
    X = np.array([rec.point3D(p).xyz for p in point_ids], dtype=float).reshape(-1, 3)
    start = {n: registrations[n].camera if n in registrations else cameras[n] for n in names}
    return Observations(camera_names=names, cameras=start, scene_points_cm={scene: X},
                        camera_index=np.array([cam_index[n] for n in observer], np.int64),
                        point_index=np.array(pi, np.int64), uv_px=np.concatenate(uv))
