"""Caliscope ``camera_array.toml`` (``caliscope/cameras/camera_array.py``: ``CameraArray.to_toml`` /
``from_toml``; caliscope 0.11.8).

``[cameras.<cam_id>]`` per camera: ``cam_id``, ``size`` [w, h], ``matrix`` (K, px, OpenCV pixel centres),
``distortions`` [k1, k2, p1, p2, k3], ``rotation`` (Rodrigues vector, or a 3x3 matrix in older files) and
``translation``, world to camera (``CameraData.transformation`` is ``[R | t]``, the projection's extrinsics), in
metres (the board's size is given in cm and turned to metres: ``core/charuco.py``); ``fisheye``; and the workspace's
own fields (``rotation_count``: quarter turns applied to the frames before detection and undone on the points, so
the calibration is of the image as recorded; ``error``, ``exposure``, ``grid_count``, ``ignore``).

Cameras: those with a pose (``posed_cameras``: rotation and translation present), in ``cam_id`` order (the order
caliscope's optimisation uses), named ``cam_<cam_id>`` (as its ``to_aniposelib_toml``). The world: after
caliscope's alignment, z up with the floor at z = 0 (``core/coordinate_frame.py``).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read, five_terms
from dome_calib.interop.fields import CameraMatrix, Distortion, RotationMatrix, RotationVector, SidePx, Translation
from dome_calib.rotation import rotvec_to_matrix
from dome_calib.schema import OpenSchema, Vec, read_toml

logger = logging.getLogger(__name__)


def _pinhole(fisheye: bool) -> bool:
    if fisheye:
        raise ValueError("fisheye cameras cannot be represented (OpenCV pinhole model only)")
    return fisheye


def _flat(value: Any) -> Any:
    if isinstance(value, list) and len(value) == 3 and all(isinstance(v, list) and len(v) == 1 for v in value):
        return [v[0] for v in value]
    return value


class CaliscopeCamera(OpenSchema):
    """One ``[cameras.<cam_id>]`` table (the workspace's display fields are ignored)."""

    cam_id: Annotated[int, Field(ge=0)] | None = None
    size: Vec(2, SidePx)
    matrix: CameraMatrix | None = None
    distortions: Distortion | None = None
    rotation: RotationVector | RotationMatrix | None = Field(None, description="Rodrigues vector or 3x3, world to "
                                                                              "camera")
    translation: Translation | None = Field(None, description="world to camera, m")
    fisheye: Annotated[bool, AfterValidator(_pinhole)] = False
    ignore: bool = False

    @model_validator(mode="before")
    @classmethod
    def _shapes(cls, data: Any) -> Any:
        if isinstance(data, dict) and "translation" in data:
            data = {**data, "translation": _flat(data["translation"])}
        return data

    def posed(self) -> bool:
        return self.rotation is not None and self.translation is not None


class CameraArrayFile(OpenSchema):
    """``camera_array.toml``: ``[cameras.<cam_id>]`` tables."""

    cameras: dict[Annotated[str, Field(pattern=r"^[0-9]{1,9}$")], CaliscopeCamera] = Field(min_length=1)


def read(path: Path, options: ImportOptions) -> Read:
    """The posed cameras in ``cam_id`` order, named ``cam_<id>``, translations in metres."""
    doc = read_toml(path, CameraArrayFile, error=InteropError)
    ids = sorted(doc.cameras, key=int)
    unposed = [f"cam_{i}" for i in ids if not doc.cameras[i].posed()]
    if unposed:
        logger.warning("%s: %d camera(s) without a pose left out, as caliscope's posed_cameras (%s)", path,
                       len(unposed), ", ".join(unposed[:4]))
    cams = []
    for i in ids:
        c = doc.cameras[i]
        if not c.posed():
            continue
        if c.matrix is None or c.distortions is None:
            raise InteropError(f"{path}: cameras.{i}: matrix and distortions: missing (a posed camera without "
                               "intrinsics)")
        rotation = np.array(c.rotation, dtype=float)
        R = rotvec_to_matrix(rotation) if rotation.shape == (3,) else rotation
        cams.append(ForeignCamera(name=f"cam_{i}", size=(c.size[0], c.size[1]), K=np.array(c.matrix),
                                  dist=five_terms(c.distortions),
                                  R=R, t=np.array(c.translation)))
    if not cams:
        raise InteropError(f"{path}: no camera has a pose (rotation and translation): nothing to import")
    return Read(cameras=cams, unit="m", path=path)
