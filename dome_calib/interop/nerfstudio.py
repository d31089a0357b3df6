"""nerfstudio ``transforms.json`` (read by ``nerfstudio/data/dataparsers/nerfstudio_dataparser.py``; the fields
that ``process_data/colmap_utils.py: colmap_to_json`` writes).

Per frame: ``file_path``, ``transform_matrix`` (4x4 camera to world, OpenGL camera axes: x right, y up, z back,
i.e. OpenCV's with y and z negated), and the intrinsics ``w``, ``h``, ``fl_x``, ``fl_y``, ``cx``, ``cy``, ``k1``,
``k2``, ``k3``, ``p1``, ``p2`` (one camera per frame; a key missing in a frame is taken from the top level, as the
dataparser does); ``camera_model`` ``OPENCV``. nerfstudio's rays start at pixel index + 0.5
(``Cameras.get_image_coords(pixel_offset=0.5)``), COLMAP's pixel convention: principal points are ours + 0.5.

World: nerfstudio wants z up. The export writes ``X_file = A @ X`` (``A`` takes our up, -y, to +z; x kept) in the
``--unit`` (metres by default) and records ``A`` as nerfstudio's own ``applied_transform`` (3x4, ``[A | 0]``), which
its dataparser composes into ``dataparser_transform`` so that ``transform_poses_to_original_space`` returns to our
world, in that unit. No ``applied_scale`` is written: the dataparser multiplies it into ``dataparser_scale`` after
it has centred the poses, so mapping back divides the centring offset by it too (with 0.01 the real Panoptic
cameras came back 178 cm from where they are); nerfstudio's own converters never write it. The unit is recorded as
``unit`` (an extra key nerfstudio ignores), each frame's camera as ``camera_name``.

Import undoes ``applied_transform`` and ``applied_scale`` when present (files of other tools and older ones of
ours, which record their world's unit as ``original_unit``).
"""
from __future__ import annotations

import json
from pathlib import Path, PurePosixPath
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from dome_calib.camera import COLMAP_PIXEL_OFFSET_PX
from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read, Written, label
from dome_calib.exact import centre, matmul3, transpose3
from dome_calib.interop.fields import Bounded, DistTerm, Length, SidePxNumber, check_rotation
from dome_calib.interop.registry import UNITS
from dome_calib.schema import CameraName, OpenSchema, Vec, read_json

#: Panoptic world -> z-up world: x kept, y_new = z, z_new = -y (up = -y becomes +z). det +1.
Z_UP_FROM_PANOPTIC = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0])  # camera axes: y and z negated
_INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
_DISTORTION = ("k1", "k2", "p1", "p2", "k3")  # our order


class Intrinsics(OpenSchema):
    """Intrinsic keys, per frame or once at the top level (the dataparser reads a frame's, else the file's)."""

    fl_x: Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)] | None = None
    fl_y: Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)] | None = None
    cx: Bounded | None = None
    cy: Bounded | None = None
    w: SidePxNumber | None = None
    h: SidePxNumber | None = None
    k1: DistTerm | None = None
    k2: DistTerm | None = None
    k3: DistTerm | None = None
    k4: DistTerm | None = None
    p1: DistTerm | None = None
    p2: DistTerm | None = None


def _pose(M: list[list[float]]) -> list[list[float]]:
    """A 3x4 or 4x4 ``[R | t]`` whose R is a rotation."""
    if len(M) == 4 and M[3] != [0, 0, 0, 1]:
        raise ValueError(f"last row must be [0, 0, 0, 1], got {M[3]}")
    check_rotation([row[:3] for row in M[:3]])
    return M


class Frame(Intrinsics):
    """One frame: one camera."""

    file_path: Annotated[str, Field(min_length=1)] | None = None
    camera_name: CameraName | None = None
    transform_matrix: Annotated[list[Vec(4, Length)], Field(min_length=3, max_length=4)]

    @model_validator(mode="after")
    def _checked(self) -> Frame:
        if self.camera_name is None and self.file_path is None:
            raise ValueError("file_path: missing (needed to name the camera)")
        try:
            _pose(self.transform_matrix)
        except ValueError as exc:
            raise ValueError(f"camera {label(self.name())}: transform_matrix: {exc}") from None
        return self

    def name(self) -> str:
        return self.camera_name or PurePosixPath(self.file_path or "").stem


class TransformsFile(Intrinsics):
    """``transforms.json``."""

    camera_model: Literal["OPENCV", "PINHOLE", "SIMPLE_PINHOLE"] = Field(
        "OPENCV", description="OpenCV pinhole models only (fisheye and equirectangular cannot be represented)")
    frames: list[Frame] = Field(min_length=1)
    applied_transform: Annotated[list[Vec(4, Length)], Field(min_length=3, max_length=4)] | None = None
    applied_scale: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] | None = None
    unit: Literal[UNITS] | None = Field(None, description="the unit of the world once applied_* are undone (ours)")
    original_unit: Literal[UNITS] | None = Field(None, description="older files of ours: as unit")

    @model_validator(mode="after")
    def _checked(self) -> TransformsFile:
        if self.applied_transform is not None:
            try:
                _pose(self.applied_transform)
            except ValueError as exc:
                raise ValueError(f"applied_transform: {exc}") from None
        for i, frame in enumerate(self.frames):
            for key in _INTRINSICS:
                if getattr(frame, key) is None and getattr(self, key) is None:
                    raise ValueError(f"frames[{i}].{key}: missing (in the frame and at the top level)")
            if (frame.k4 if frame.k4 is not None else self.k4 or 0.0) != 0.0:
                raise ValueError(f"frames[{i}].k4: non-zero k4 cannot be represented (OpenCV [k1, k2, p1, p2, k3] "
                                 "only)")
        return self

    def value(self, frame: Frame, key: str, default: float | None = None) -> float:
        mine = getattr(frame, key)
        return float(mine if mine is not None else getattr(self, key) if getattr(self, key) is not None else default)


def write(cams: list[ForeignCamera], path: Path, unit: str, options: object = None) -> Written:
    """Write ``transforms.json``: ``cams`` are already in the z-up world (x kept, -y of ours up) and in ``unit``."""
    frames = []
    for cam in cams:
        world_from_cam = np.eye(4)
        world_from_cam[:3, :3] = matmul3(transpose3(cam.R), OPENGL_FROM_OPENCV)
        world_from_cam[:3, 3] = centre(cam.R, cam.t)
        k1, k2, p1, p2, k3 = (float(v) for v in cam.dist)
        frames.append({
            "file_path": f"images/{cam.name}.png", "camera_name": cam.name,
            "transform_matrix": world_from_cam.tolist(),
            "w": int(cam.size[0]), "h": int(cam.size[1]), "fl_x": float(cam.K[0, 0]), "fl_y": float(cam.K[1, 1]),
            "cx": float(cam.K[0, 2]) + COLMAP_PIXEL_OFFSET_PX, "cy": float(cam.K[1, 2]) + COLMAP_PIXEL_OFFSET_PX,
            "k1": k1, "k2": k2, "k3": k3, "p1": p1, "p2": p2,
        })
    applied = np.hstack([Z_UP_FROM_PANOPTIC, np.zeros((3, 1))])
    doc = {"camera_model": "OPENCV", "applied_transform": applied.tolist(), "unit": unit, "frames": frames}
    path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return Written()


def read(path: Path, options: ImportOptions) -> Read:
    """Cameras in frame order, in the world before ``applied_transform`` / ``applied_scale`` (the original world),
    in its unit if the file names it (``unit``, or ``original_unit`` in older files of ours)."""
    doc = read_json(path, TransformsFile, error=InteropError)
    A, a, s = np.eye(3), np.zeros(3), doc.applied_scale or 1.0
    if doc.applied_transform is not None:
        M = np.array(doc.applied_transform)
        A, a = M[:3, :3], M[:3, 3]
        U, _, Vt = np.linalg.svd(A)
        A = U @ Vt
    cams = []
    for frame in doc.frames:
        M = np.array(frame.transform_matrix)
        R_file = M[:3, :3] @ OPENGL_FROM_OPENCV  # world_from_cam, OpenCV camera axes
        R = (A.T @ R_file).T
        centre = A.T @ (M[:3, 3] / s - a)
        fx, fy, cx, cy = (doc.value(frame, k) for k in ("fl_x", "fl_y", "cx", "cy"))
        K = np.array([[fx, 0.0, cx - COLMAP_PIXEL_OFFSET_PX], [0.0, fy, cy - COLMAP_PIXEL_OFFSET_PX], [0, 0, 1.0]])
        dist = np.array([doc.value(frame, k, 0.0) for k in _DISTORTION])
        size = (int(doc.value(frame, "w")), int(doc.value(frame, "h")))
        cams.append(ForeignCamera(name=frame.name(), size=size, K=K, dist=dist, R=R, t=-R @ centre))
    return Read(cameras=cams, unit=doc.unit or doc.original_unit, path=path)
