"""nerfstudio ``transforms.json`` (``nerfstudio/data/dataparsers/nerfstudio_dataparser.py``; the fields that
``process_data/colmap_utils.py: colmap_to_json`` writes).

Per frame: ``file_path``, ``transform_matrix`` (4x4 camera to world, OpenGL camera axes: x right, y up, z back,
i.e. OpenCV's with y and z negated), and the intrinsics ``w``, ``h``, ``fl_x``, ``fl_y``, ``cx``, ``cy``, ``k1``,
``k2``, ``k3``, ``p1``, ``p2`` (one camera per frame); ``camera_model`` ``OPENCV``. nerfstudio's rays start at
pixel index + 0.5 (``Cameras.get_image_coords(pixel_offset=0.5)``), COLMAP's pixel convention: principal points
are ours + 0.5.

World: nerfstudio wants z up. The export maps the Panoptic world (y down, cm) by ``X_file = s * A @ X`` with
``A`` the rotation taking -y (up) to +z (x kept) and ``s`` = 1 / (cm per ``--unit``, default metres), and
records both as nerfstudio's own ``applied_transform`` (3x4, ``[A | 0]``) and ``applied_scale`` keys, which its
dataparser composes into ``dataparser_transform`` / ``dataparser_scale`` so that its exports return to our world.
The original world's unit is written as ``original_unit`` (an extra key nerfstudio ignores); each frame carries
its camera's ``camera_name``. Import undoes ``applied_transform`` / ``applied_scale`` when present.
"""
from __future__ import annotations

import json
from pathlib import Path, PurePosixPath

import numpy as np

from dome_calib import panoptic_io as pio
from dome_calib.camera import COLMAP_PIXEL_OFFSET_PX
from dome_calib.interop.common import ForeignCamera

DEFAULT_UNIT = "m"
#: Panoptic world -> z-up world: x kept, y_new = z, z_new = -y (up = -y becomes +z). det +1.
Z_UP_FROM_PANOPTIC = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0])  # camera axes: y and z negated


def write_nerfstudio(cams: list[ForeignCamera], path: Path, *, unit: str, cm_per_unit: float) -> None:
    """Write ``transforms.json``. ``cams`` translations are in cm (the bundle's); ``unit`` is the file's."""
    scale = 1.0 / cm_per_unit
    frames = []
    for cam in cams:
        world_from_cam = np.eye(4)
        world_from_cam[:3, :3] = Z_UP_FROM_PANOPTIC @ cam.R.T @ OPENGL_FROM_OPENCV
        world_from_cam[:3, 3] = scale * (Z_UP_FROM_PANOPTIC @ (-cam.R.T @ cam.t))
        k1, k2, p1, p2, k3 = (float(v) for v in cam.dist)
        frames.append({
            "file_path": f"images/{cam.name}.png", "camera_name": cam.name,
            "transform_matrix": world_from_cam.tolist(),
            "w": int(cam.size[0]), "h": int(cam.size[1]), "fl_x": float(cam.K[0, 0]), "fl_y": float(cam.K[1, 1]),
            "cx": float(cam.K[0, 2]) + COLMAP_PIXEL_OFFSET_PX, "cy": float(cam.K[1, 2]) + COLMAP_PIXEL_OFFSET_PX,
            "k1": k1, "k2": k2, "k3": k3, "p1": p1, "p2": p2,
        })
    applied = np.hstack([Z_UP_FROM_PANOPTIC, np.zeros((3, 1))])
    doc = {"camera_model": "OPENCV", "applied_transform": applied.tolist(), "applied_scale": scale,
           "original_unit": "cm", "unit": unit, "frames": frames}
    path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


def _number(w: pio._Where, frame: dict, top: dict, key: str, default: float | None = None) -> float:
    if key in frame:
        return float(w.numbers(frame[key], key, ((),), pio.LIMITS["K_px"]))
    if key in top:
        return float(w.numbers(top[key], key, ((),), pio.LIMITS["K_px"]))
    if default is None:
        raise w.fail(key, "missing (in the frame and at the top level)")
    return default


def _applied(doc: dict, path: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """(A (3, 3), a (3,), s): the file's world is ``s * (A X + a)`` of the original world."""
    w = pio._Where(path)
    A, a = np.eye(3), np.zeros(3)
    if "applied_transform" in doc:
        M = w.numbers(doc["applied_transform"], "applied_transform", ((3, 4), (4, 4)), 1e6)
        A, a = w.rotation(M[:3, :3].copy(), "applied_transform"), M[:3, 3]
    s = float(w.numbers(doc.get("applied_scale", 1.0), "applied_scale", ((),), 1e9))
    if not s > 0:
        raise w.fail("applied_scale", f"must be positive, got {s}")
    return A, a, s


def read_nerfstudio(path: Path) -> tuple[list[ForeignCamera], str | None]:
    """Cameras in frame order (translations in the original world's unit) and that unit if the file names it
    (``original_unit``, written by this toolkit)."""
    if path.is_dir():
        path = path / "transforms.json"
    doc = pio._load_json(path)
    top = pio._Where(path)
    frames = top.get(doc, "frames")
    if not isinstance(frames, list) or not frames:
        raise top.fail("frames", "expected a non-empty list of frames (is this a nerfstudio transforms.json?)")
    model = doc.get("camera_model", "OPENCV")
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise top.fail("camera_model", f"{pio._show(model)} cannot be represented (OpenCV pinhole model only)")
    A, a, s = _applied(doc, path)
    cams = []
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise top.at(f"frame #{i}").fail("frames", f"expected an object, got {pio._show(frame)}")
        fp = frame.get("file_path")
        name = frame.get("camera_name") or (PurePosixPath(fp).stem if isinstance(fp, str) and fp else None)
        if not isinstance(name, str) or not name:
            raise top.at(f"frame #{i}").fail("file_path", "missing (needed to name the camera)")
        w = top.at(f"camera {pio._label(name)}")
        if _number(w, frame, doc, "k4", 0.0) != 0.0:
            raise w.fail("k4", "non-zero k4 cannot be represented (OpenCV [k1, k2, p1, p2, k3] only)")
        fx, fy, cx, cy = (_number(w, frame, doc, k) for k in ("fl_x", "fl_y", "cx", "cy"))
        dist = np.array([_number(w, frame, doc, k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")])
        M = w.array(frame, "transform_matrix", ((4, 4), (3, 4)), 1e9)
        R_file = w.rotation(M[:3, :3].copy(), "transform_matrix") @ OPENGL_FROM_OPENCV  # world_from_cam, OpenCV
        world_from_cam = A.T @ R_file
        centre = A.T @ (M[:3, 3] / s - a)
        R = world_from_cam.T
        K = np.array([[fx, 0.0, cx - COLMAP_PIXEL_OFFSET_PX], [0.0, fy, cy - COLMAP_PIXEL_OFFSET_PX], [0, 0, 1.0]])
        size = (_number(w, frame, doc, "w"), _number(w, frame, doc, "h"))  # checked as integers by common.checked
        cams.append(ForeignCamera(name=name, size=size, K=K, dist=dist, R=R, t=-R @ centre))
    unit = doc.get("original_unit")
    if unit is not None and not isinstance(unit, str):
        raise top.fail("original_unit", f"expected a unit name, got {pio._show(unit)}")
    return cams, unit
