"""Qualisys Track Manager calibration ``.qca.txt`` (XML), read as Pose2Sim reads it (``Pose2Sim/calibration.py``:
``calib_qca_fun``, ``read_qca``; pose2sim 0.10.49).

Per ``<camera serial=... model=...>``: ``<fov_video left top right bottom>`` (the image's pixel range on the
sensor), ``<intrinsic focalLengthU focalLengthV centerPointU centerPointV radialDistortion1 radialDistortion2
tangentalDistortion1 tangentalDistortion2 ...>`` in 1/64 pixel (so divided by 64, the principal point then moved by
the image's left/top offset), ``<transform x y z r11 .. r33>``: the camera's position (mm) and orientation in the lab
(z up). As Pose2Sim: the rotation read ``r11 r12 r13 / r21 ...`` row by row is the camera-from-lab rotation of a
camera whose axes are OpenCV's turned half a turn about x (y up, looking along -z), so ``R = diag(1, -1, -1) @ M``
and ``t = -R @ position``; distortion ``[k1, k2, p1, p2]`` = the four terms / 64 (``radialDistortion3`` and
``skew`` are not read by Pose2Sim: a non-zero one is said, not used).

Cameras: the video cameras only (``model`` containing "video" or "none"; marker-only cameras have no images), in
natural order of their serials (``cam2`` before ``cam10``), named by serial: Pose2Sim's order. Lengths in mm.
"""
from __future__ import annotations

import logging
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BeforeValidator, Field, model_validator

from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read
from dome_calib.interop.fields import ROTATION_REPAIR_TOL, rotation_error
from dome_calib.schema import OpenSchema, show, validate

logger = logging.getLogger(__name__)

#: QTM writes intrinsics in 1/64 pixel.
SUBPIXELS = 64.0
#: Half a turn about x: QTM's camera axes (y up, looking along -z) to OpenCV's.
OPENCV_FROM_QTM = np.diag([1.0, -1.0, -1.0])


def _number(value: Any) -> Any:
    """An attribute's text as a number; anything else is left for the type check to refuse."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


Number = Annotated[float, BeforeValidator(_number), Field(ge=-1e9, le=1e9, allow_inf_nan=False)]


class FovVideo(OpenSchema):
    """``<fov_video>``: the image's pixel range on the sensor (inclusive)."""

    left: Number
    top: Number
    right: Number
    bottom: Number

    @model_validator(mode="after")
    def _range(self) -> FovVideo:
        for v in (self.left, self.top, self.right, self.bottom):
            if not float(v).is_integer():
                raise ValueError(f"expected whole pixel numbers, got {show(v)}")
        if not (self.right > self.left and self.bottom > self.top):
            raise ValueError(f"empty image (left {self.left:g}, right {self.right:g}, top {self.top:g}, bottom "
                             f"{self.bottom:g})")
        return self


class Intrinsic(OpenSchema):
    """``<intrinsic>``, in 1/64 pixel."""

    focalLengthU: Annotated[Number, Field(gt=0)]  # noqa: N815 (the file's names)
    focalLengthV: Annotated[Number, Field(gt=0)]  # noqa: N815
    centerPointU: Number  # noqa: N815
    centerPointV: Number  # noqa: N815
    radialDistortion1: Number  # noqa: N815
    radialDistortion2: Number  # noqa: N815
    tangentalDistortion1: Number  # noqa: N815
    tangentalDistortion2: Number  # noqa: N815
    radialDistortion3: Number = 0.0  # noqa: N815
    skew: Number = 0.0


class Transform(OpenSchema):
    """``<transform>``: the camera's position (mm) and orientation in the lab."""

    x: Number
    y: Number
    z: Number
    r11: Number
    r12: Number
    r13: Number
    r21: Number
    r22: Number
    r23: Number
    r31: Number
    r32: Number
    r33: Number

    @model_validator(mode="after")
    def _rotation(self) -> Transform:
        err = rotation_error(self.matrix())
        if not err <= ROTATION_REPAIR_TOL:
            raise ValueError(f"r11..r33: not a rotation (|R R^T - I| or |det R - 1| = {err:.2g})")
        return self

    def matrix(self) -> np.ndarray:
        return np.array([[self.r11, self.r12, self.r13], [self.r21, self.r22, self.r23],
                         [self.r31, self.r32, self.r33]])


class QcaCamera(OpenSchema):
    """``<camera serial=... model=...>`` and the three elements Pose2Sim reads."""

    serial: Annotated[str, Field(min_length=1)]
    model: str = ""
    fov_video: FovVideo
    intrinsic: Intrinsic
    transform: Transform

    def is_video(self) -> bool:
        return any(kind in self.model.lower() for kind in ("video", "none"))


class QcaFile(OpenSchema):
    """``<calibration><cameras><camera>...``"""

    cameras: list[QcaCamera] = Field(min_length=1)


def _natural(name: str) -> list[Any]:
    """``cam2`` before ``cam10``: digits compared as numbers, the rest without case."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def _document(path: Path) -> dict[str, Any]:
    try:
        root = ET.fromstring(path.read_bytes())
    except FileNotFoundError:
        raise InteropError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise InteropError(f"{path}: is a folder, expected a Qualisys .qca.txt file") from None
    except ET.ParseError as exc:
        raise InteropError(f"{path}: not an XML file ({exc}); expected a Qualisys .qca.txt calibration") from None
    cameras = []
    for tag in root.findall("cameras/camera"):
        entry: dict[str, Any] = dict(tag.attrib)
        for child in ("fov_video", "intrinsic", "transform"):
            element = tag.find(child)
            if element is not None:
                entry[child] = dict(element.attrib)
        cameras.append(entry)
    return {"cameras": cameras}


def read(path: Path, options: ImportOptions) -> Read:
    """The video cameras in Pose2Sim's order (natural order of their serials), lengths in mm."""
    doc = validate(_document(path), QcaFile, source=path, error=InteropError)
    video = sorted((c for c in doc.cameras if c.is_video()), key=lambda c: _natural(c.serial))
    if not video:
        raise InteropError(f"{path}: no video camera (model containing 'video' or 'none'): nothing to import")
    left_out = [c.serial for c in doc.cameras if not c.is_video()]
    if left_out:
        logger.warning("%s: %d marker-only camera(s) left out, as Pose2Sim does (%s)", path, len(left_out),
                       ", ".join(left_out[:4]))
    unused = [c.serial for c in video if c.intrinsic.radialDistortion3 != 0 or c.intrinsic.skew != 0]
    if unused:
        logger.warning("%s: radialDistortion3 or skew not zero for %s: not read (as Pose2Sim; the model holds "
                       "[k1, k2, p1, p2] here)", path, ", ".join(unused[:4]))
    cams = []
    for c in video:
        i, fov = c.intrinsic, c.fov_video
        K = np.array([[i.focalLengthU / SUBPIXELS, 0.0, i.centerPointU / SUBPIXELS - fov.left],
                      [0.0, i.focalLengthV / SUBPIXELS, i.centerPointV / SUBPIXELS - fov.top], [0.0, 0.0, 1.0]])
        dist = np.array([i.radialDistortion1, i.radialDistortion2, i.tangentalDistortion1, i.tangentalDistortion2,
                         0.0]) / np.array([SUBPIXELS] * 4 + [1.0])
        R = OPENCV_FROM_QTM @ c.transform.matrix()
        t = -R @ np.array([c.transform.x, c.transform.y, c.transform.z])
        size = (int(fov.right - fov.left + 1), int(fov.bottom - fov.top + 1))
        cams.append(ForeignCamera(name=c.serial, size=size, K=K, dist=dist, R=R, t=t))
    return Read(cameras=cams, unit="mm", path=path)
