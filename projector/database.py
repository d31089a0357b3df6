"""COLMAP database helpers: one real COLMAP SQLite database per scene (openable in the COLMAP GUI).

Writes go through ``pycolmap.Database`` in the main process. Task workers read keypoints, descriptors and
cameras through a read-only SQLite connection (:class:`FeatureReader`); COLMAP opens its databases in WAL
mode, so these readers never block the writer.

Camera model: ``FULL_OPENCV`` ``[fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6]`` with ``k4 = k5 = k6 = 0``
is exactly OpenCV's 5-parameter model (the rational denominator is 1); the principal point is shifted by
+0.5 px to COLMAP's pixel convention. One COLMAP camera (and one single-sensor rig and frame) per image,
i.e. per physical camera of the scene.
"""
from __future__ import annotations

import contextlib
import sqlite3
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pycolmap

from dome_calib.bundle import Camera
from dome_calib.camera import COLMAP_PIXEL_OFFSET_PX, intr_to_K

COLMAP_MODEL = "FULL_OPENCV"
SIFT_DESCRIPTOR_SCALE = 512.0  # COLMAP stores L1-root SIFT descriptors as uint8(round(512 * d))


def image_name(camera: str) -> str:
    """Database / file name of a camera's image in a scene folder."""
    return f"{camera}.png"


def camera_of_image(name: str) -> str:
    return Path(name).stem


def to_colmap_camera(cam: Camera) -> pycolmap.Camera:
    """A pycolmap camera (FULL_OPENCV, COLMAP pixel convention) with ``cam``'s intrinsics and distortion."""
    fx, fy, cx, cy = cam.intr
    k1, k2, p1, p2, k3 = cam.dist
    w, h = cam.resolution
    params = [fx, fy, cx + COLMAP_PIXEL_OFFSET_PX, cy + COLMAP_PIXEL_OFFSET_PX, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    colmap_cam = pycolmap.Camera(model=COLMAP_MODEL, width=int(w), height=int(h), params=params)
    colmap_cam.has_prior_focal_length = True
    return colmap_cam


def intrinsics_from_colmap(colmap_cam: pycolmap.Camera) -> tuple[np.ndarray, np.ndarray]:
    """(K (3, 3) OpenCV pixel convention, dist (5,)) of a FULL_OPENCV or OPENCV pycolmap camera.

    Raises ValueError if the rational terms k4..k6 are not zero (not representable in the 5-parameter model).
    """
    p = np.asarray(colmap_cam.params, dtype=float)
    if colmap_cam.model_name == "FULL_OPENCV":
        if np.any(np.abs(p[9:12]) > 1e-12):
            raise ValueError(f"camera {colmap_cam.camera_id}: k4..k6 = {p[9:12]} are not zero")
        dist = p[4:9]
    elif colmap_cam.model_name == "OPENCV":
        dist = np.array([p[4], p[5], p[6], p[7], 0.0])
    else:
        raise ValueError(f"camera {colmap_cam.camera_id}: model {colmap_cam.model_name} is not OpenCV-compatible")
    K = intr_to_K(np.array([p[0], p[1], p[2] - COLMAP_PIXEL_OFFSET_PX, p[3] - COLMAP_PIXEL_OFFSET_PX]))
    return K, dist.copy()


def add_image(db: pycolmap.Database, name: str, cam: Camera) -> int:
    """Write a camera, its single-sensor rig and frame, and the image ``name``; returns the image id."""
    camera_id = db.write_camera(to_colmap_camera(cam))
    rig = pycolmap.Rig()
    rig.add_ref_sensor(db.read_camera(camera_id).sensor_id)
    rig_id = db.write_rig(rig)
    image_id = db.write_image(pycolmap.Image(name=name, camera_id=camera_id))
    frame = pycolmap.Frame()
    frame.rig_id = rig_id
    frame.add_data_id(db.read_image(image_id).data_id)
    db.write_frame(frame)
    return image_id


def descriptors_to_uint8(desc: np.ndarray) -> np.ndarray:
    """(N, 128) float SIFT descriptors (pycolmap, L1-root normalised) -> COLMAP's uint8 storage."""
    d = np.asarray(desc)
    if d.dtype == np.uint8:
        return d
    return np.clip(np.round(d * SIFT_DESCRIPTOR_SCALE), 0, 255).astype(np.uint8)


def write_features(db: pycolmap.Database, image_id: int, keypoints: np.ndarray, descriptors_u8: np.ndarray) -> None:
    """Keypoints (N, 4) [x, y, scale, orientation] COLMAP px and descriptors (N, 128) uint8."""
    db.write_keypoints(image_id, np.ascontiguousarray(keypoints, dtype=np.float32))
    db.write_descriptors(image_id, pycolmap.FeatureDescriptors(pycolmap.FeatureExtractorType.SIFT,
                                                               np.ascontiguousarray(descriptors_u8)))


#: COLMAP's pair id: ``image_id1 * PAIR_ID_BASE + image_id2`` with ``image_id1 < image_id2``.
PAIR_ID_BASE = 2147483647


def drop_features(database_path: str | Path, cameras: list[str]) -> list[tuple[str, str]]:
    """Delete the keypoints and descriptors of ``cameras``' images, and every match and two-view geometry of
    theirs, so that the next feature extraction and matching redo exactly them (the images and their cameras
    stay). One transaction; call with no ``pycolmap.Database`` open on the file. Returns the pairs (camera
    names, sorted) whose matches were deleted: matching them again restores what there was."""
    with contextlib.closing(sqlite3.connect(str(database_path), timeout=60.0)) as conn, conn:
        names = {row[0]: camera_of_image(row[1]) for row in conn.execute("SELECT image_id, name FROM images")}
        ids = sorted(i for i, n in names.items() if n in set(cameras))
        if not ids:
            return []
        marks = ",".join("?" * len(ids))
        where = f"pair_id / {PAIR_ID_BASE} IN ({marks}) OR pair_id % {PAIR_ID_BASE} IN ({marks})"
        pairs = sorted({tuple(sorted((names[pid // PAIR_ID_BASE], names[pid % PAIR_ID_BASE])))
                        for (pid,) in conn.execute(f"SELECT pair_id FROM matches WHERE {where}", ids + ids)})
        for table in ("keypoints", "descriptors"):
            conn.execute(f"DELETE FROM {table} WHERE image_id IN ({marks})", ids)
        for table in ("matches", "two_view_geometries"):
            conn.execute(f"DELETE FROM {table} WHERE {where}", ids + ids)
    return pairs


def drop_matches(database_path: str | Path) -> None:
    """Delete every match and two-view geometry of the database (features, images and cameras stay), in one
    transaction: the scene is then as if it had never been matched."""
    with pycolmap.Database.open(str(database_path)) as db, pycolmap.DatabaseTransaction(db):
        db.clear_matches()
        db.clear_two_view_geometries()


def images_with_features(db: pycolmap.Database) -> dict[str, int]:
    """Image name -> image id of every image that already has keypoints (for resuming)."""
    return {im.name: im.image_id for im in db.read_all_images() if db.exists_keypoints(im.image_id)}


class FeatureReader:
    """Read-only access to one database from a task worker (keeps the last ``cache_size`` images in memory)."""

    def __init__(self, database_path: str | Path, cache_size: int = 64) -> None:
        self.path = Path(database_path)
        self._conn = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, timeout=60.0)
        self._cache: OrderedDict[str, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._cache_size = cache_size
        self._cameras: dict[str, pycolmap.Camera] = {}

    def features(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(keypoints (N, 2) float64 COLMAP px, descriptors (N, 128) uint8) of image ``name``."""
        if name in self._cache:
            self._cache.move_to_end(name)
            return self._cache[name]
        row = self._conn.execute(
            "SELECT k.rows, k.cols, k.data, d.rows, d.cols, d.data FROM images i "
            "JOIN keypoints k ON k.image_id = i.image_id JOIN descriptors d ON d.image_id = i.image_id "
            "WHERE i.name = ?", (name,)).fetchone()
        if row is None:
            raise KeyError(f"{self.path}: no features for image {name}")
        kr, kc, kdata, dr, dc, ddata = row
        kp = np.frombuffer(kdata, dtype=np.float32).reshape(kr, kc)[:, :2].astype(np.float64) if kr else np.zeros((0, 2))
        desc = np.frombuffer(ddata, dtype=np.uint8).reshape(dr, dc) if dr else np.zeros((0, 128), np.uint8)
        self._cache[name] = (kp, desc)
        if len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return kp, desc

    def camera(self, name: str) -> pycolmap.Camera:
        """The pycolmap camera of image ``name``."""
        if name not in self._cameras:
            row = self._conn.execute(
                "SELECT c.model, c.width, c.height, c.params, c.prior_focal_length FROM images i "
                "JOIN cameras c ON c.camera_id = i.camera_id WHERE i.name = ?", (name,)).fetchone()
            if row is None:
                raise KeyError(f"{self.path}: no camera for image {name}")
            model, w, h, params, prior_focal = row
            cam = pycolmap.Camera(model=pycolmap.CameraModelId(model), width=int(w), height=int(h),
                                  params=np.frombuffer(params, dtype=np.float64).copy())
            # the prior focal length is what makes two-view verification estimate a calibrated (E) geometry
            cam.has_prior_focal_length = bool(prior_focal)
            self._cameras[name] = cam
        return self._cameras[name]

    def close(self) -> None:
        self._conn.close()


def verified_partner_ids(db: pycolmap.Database) -> dict[int, set[int]]:
    """Image id -> the image ids it has a verified pair with (at least one inlier match)."""
    partners: dict[int, set[int]] = {}
    pair_ids, counts = db.read_two_view_geometry_num_inliers()
    for pid, n in zip(pair_ids, counts):
        if n > 0:
            a, b = pycolmap.pair_id_to_image_pair(pid)
            partners.setdefault(a, set()).add(b)
            partners.setdefault(b, set()).add(a)
    return partners


@dataclass(frozen=True, kw_only=True)
class DatabaseSummary:
    """What a scene database says of its images, read once (:func:`read_summary`): the camera of each image id,
    and the images with a verified pair (:func:`verified_partner_ids`). The mappers only read the database, so a
    summary read before mapping describes the model made from it (:func:`projector.mapping.describe_model`)."""

    cameras: dict[int, str]
    verified: frozenset[int]


def read_summary(database_path: str | Path) -> DatabaseSummary:
    with pycolmap.Database.open(str(database_path)) as db:
        return DatabaseSummary(cameras={im.image_id: camera_of_image(im.name) for im in db.read_all_images()},
                               verified=frozenset(verified_partner_ids(db)))
