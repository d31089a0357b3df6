"""Qualisys Track Manager calibration ``.qca.txt`` (XML), read as Pose2Sim reads it (``Pose2Sim/calibration.py``:
``calib_qca_fun``, ``read_qca``; pose2sim 0.10.49).

Per ``<camera serial=... model=... [video_resolution="540p"]>``: ``<fov_video left top right bottom>`` (the image's
pixel range on the sensor), ``<intrinsic focalLengthU focalLengthV centerPointU centerPointV radialDistortion1
radialDistortion2 tangentalDistortion1 tangentalDistortion2 ...>``: the focal lengths and the principal point in 1/64
sensor pixel (so divided by 64, the principal point then moved by the image's left/top offset), the distortion terms
as they are; ``<transform x y z r11 .. r33>``: the camera's position (mm) and orientation in the lab (z up). As
Pose2Sim: the rotation read ``r11 r12 r13 / r21 ...`` row by row is the camera-from-lab rotation of a camera whose
axes are OpenCV's turned half a turn about x (y up, looking along -z), so ``R = diag(1, -1, -1) @ M`` and
``t = -R @ position`` (``radialDistortion3`` and ``skew`` are not read by Pose2Sim: a non-zero one is said, not
used).

Where we differ from Pose2Sim (``read_qca`` divides the distortion terms by 64 and by the binning too), decided on
the evidence of the demo cameras' own checkerboard images (shipped in the pose2sim wheel, ``Demo_SinglePerson/
calibration/intrinsics``; ``tests/test_interop_qualisys_evidence.py``): distortion coefficients have no unit, so the
1/64 pixel unit does not apply to them. Read as written, they reproject the board corners better than the /64
reading on 3 of the 4 cameras (0.445 / 0.412 / 0.744 px RMS against 0.518 / 0.458 / 0.793; cam01 0.374 against
0.368), and OpenCV's own fit of k1, k2 with the file's K is -0.027 .. -0.065 and 0.045 .. 0.24, the file's terms as
written (-0.046 .. -0.048, 0.135 .. 0.14), where the /64 reading (-0.0007, 0.002) is no distortion at all.

Binning (``ImportOptions.binning``; Pose2Sim's ``binning_factor``): an image pixel is ``b`` sensor pixels along each
axis, so the size, the focal lengths and the principal point (after the offset: ``(centre - left) / b``; Pose2Sim
subtracts the offset after dividing, the same where the image starts at the sensor's corner) are divided by ``b``;
the distortion terms, in normalised coordinates, are not. Without the option a camera's ``video_resolution``
(``"540p"``: its image's short side in pixels) gives ``b`` as the sensor's short side over it (1088 / 540 -> 2); a
value that is not a whole binning is refused, and so is an option the file contradicts.

Cameras: the video cameras only (``model`` containing "video" or "none"; marker-only cameras have no images), in
natural order of their serials (``cam2`` before ``cam10``), named by serial: Pose2Sim's order. Lengths in mm.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BeforeValidator, Field, model_validator

from dome_calib.interop.common import (ForeignCamera, ImportOptions, InteropError, Read, video_cameras,
                                       xml_root)
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
    video_resolution: str | None = Field(None, description='e.g. "1080p", "540p": the video\'s short side')
    fov_video: FovVideo
    intrinsic: Intrinsic
    transform: Transform

    def is_video(self) -> bool:
        return any(kind in self.model.lower() for kind in ("video", "none"))


class QcaFile(OpenSchema):
    """``<calibration><cameras><camera>...``"""

    cameras: list[QcaCamera] = Field(min_length=1)


def _document(path: Path) -> dict[str, Any]:
    root = xml_root(path, "a Qualisys .qca.txt")
    cameras = []
    for tag in root.findall("cameras/camera"):
        entry: dict[str, Any] = dict(tag.attrib)
        for child in ("fov_video", "intrinsic", "transform"):
            element = tag.find(child)
            if element is not None:
                entry[child] = dict(element.attrib)
        cameras.append(entry)
    return {"cameras": cameras}


_RESOLUTION = re.compile(r"(\d+)p")


def binning(camera: QcaCamera, given: int | None, path: Path) -> int:
    """Sensor pixels per image pixel of ``camera`` (see the module docstring); InteropError naming the file and the
    camera where the file's ``video_resolution`` is no whole binning or contradicts ``given``."""
    told = None
    if camera.video_resolution is not None:
        match = _RESOLUTION.fullmatch(camera.video_resolution.strip())
        fov = camera.fov_video
        short = min(fov.right - fov.left + 1, fov.bottom - fov.top + 1)
        ratio = short / int(match.group(1)) if match and int(match.group(1)) > 0 else float("nan")
        if not abs(ratio - round(ratio)) <= 0.05 or round(ratio) < 1:
            raise InteropError(f"{path}: camera {camera.serial}: video_resolution {camera.video_resolution!r} is no "
                               f"whole binning of its {short:g}-pixel sensor side (give --binning)")
        told = int(round(ratio))
    if given is not None and told is not None and given != told:
        raise InteropError(f"{path}: camera {camera.serial}: video_resolution {camera.video_resolution!r} means "
                           f"binning {told}, but --binning {given}")
    return given or told or 1


def read(path: Path, options: ImportOptions) -> Read:
    """The video cameras in Pose2Sim's order (natural order of their serials), lengths in mm."""
    doc = validate(_document(path), QcaFile, source=path, error=InteropError)
    video = video_cameras(path, doc.cameras, lambda c: c.is_video(), lambda c: c.serial,
                          "model containing 'video' or 'none'")
    unused = [c.serial for c in video if c.intrinsic.radialDistortion3 != 0 or c.intrinsic.skew != 0]
    if unused:
        logger.warning("%s: radialDistortion3 or skew not zero for %s: not read (as Pose2Sim; the model holds "
                       "[k1, k2, p1, p2] here)", path, ", ".join(unused[:4]))
    cams = []
    for c in video:
        i, fov = c.intrinsic, c.fov_video
        b = binning(c, options.binning, path)
        K = np.array([[i.focalLengthU / SUBPIXELS / b, 0.0, (i.centerPointU / SUBPIXELS - fov.left) / b],
                      [0.0, i.focalLengthV / SUBPIXELS / b, (i.centerPointV / SUBPIXELS - fov.top) / b],
                      [0.0, 0.0, 1.0]])
        dist = np.array([i.radialDistortion1, i.radialDistortion2, i.tangentalDistortion1, i.tangentalDistortion2,
                         0.0])  # no unit: as written (see the module docstring)
        R = OPENCV_FROM_QTM @ c.transform.matrix()
        t = -R @ np.array([c.transform.x, c.transform.y, c.transform.z])
        w, h = fov.right - fov.left + 1, fov.bottom - fov.top + 1
        if w % b or h % b:
            raise InteropError(f"{path}: camera {c.serial}: the image ({w:g} x {h:g} sensor pixels) is not a whole "
                               f"number of {b} x {b} bins")
        size = (int(w // b), int(h // b))
        cams.append(ForeignCamera(name=c.serial, size=size, K=K, dist=dist, R=R, t=t))
    return Read(cameras=cams, unit="mm", path=path)
