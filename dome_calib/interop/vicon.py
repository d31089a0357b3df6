"""Vicon calibration ``.xcp`` (XML, Vicon Nexus / Shogun), read as Pose2Sim reads it (``Pose2Sim/calibration.py``:
``calib_vicon_fun``, ``read_vicon``; pose2sim 0.10.49).

Per ``<Camera DEVICEID=... TYPE=... SENSOR_SIZE="w h" PIXEL_ASPECT_RATIO=...>``, its first
``<KeyFrames><KeyFrame FOCAL_LENGTH PRINCIPAL_POINT="u v" ORIENTATION="qx qy qz w" POSITION="x y z"
[VICON_RADIAL2=...] [VICON_RADIAL="k1 k2"]>``:

- ``K = [[f, 0, u], [0, f / aspect, v], [0, 0, 1]]`` (pixels), the image ``SENSOR_SIZE``;
- the quaternion (scalar last) is the camera-from-lab rotation ``R``, ``POSITION`` the camera's centre in the lab
  (mm, z up): ``t = -R @ position``;
- distortion as Pose2Sim passes it to OpenCV: ``VICON_RADIAL2``'s 4th and 5th numbers, else ``VICON_RADIAL``'s two,
  as ``k1, k2`` (``p1 = p2 = 0``). Vicon's own radial model is not OpenCV's; with no Vicon file and images to judge
  by, Pose2Sim's reading is kept and said here (docs/interop.md).

Cameras: those whose ``TYPE`` contains "video" (as Pose2Sim: marker-only cameras have no images; the others are
said), in natural order of their ``DEVICEID``, named by it.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BeforeValidator, Field

from dome_calib.interop.common import (ForeignCamera, ImportOptions, InteropError, Read, video_cameras,
                                       xml_root)
from dome_calib.interop.fields import ROTATION_REPAIR_TOL
from dome_calib.schema import OpenSchema, validate


def _numbers(value: Any) -> Any:
    """``"1.5 2 3"`` -> [1.5, 2.0, 3.0]; anything else is left for the type check to refuse."""
    if isinstance(value, str):
        try:
            return [float(v) for v in value.split()]
        except ValueError:
            return value
    return value


def _number(value: Any) -> Any:
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


Finite = Annotated[float, Field(ge=-1e9, le=1e9, allow_inf_nan=False)]
Number = Annotated[float, BeforeValidator(_number), Field(ge=-1e9, le=1e9, allow_inf_nan=False)]


def Numbers(n: int, at_least: bool = False):  # noqa: N802 (a type)
    return Annotated[list[Finite], BeforeValidator(_numbers), Field(min_length=n, max_length=None if at_least else n)]


class KeyFrame(OpenSchema):
    """``<KeyFrame>``: the camera's intrinsics and pose (the first one is read, as Pose2Sim does)."""

    FOCAL_LENGTH: Annotated[Number, Field(gt=0)]
    PRINCIPAL_POINT: Numbers(2)
    ORIENTATION: Numbers(4) = Field(description="quaternion qx qy qz w, camera from lab")
    POSITION: Numbers(3) = Field(description="the camera's centre in the lab, mm")
    VICON_RADIAL2: Numbers(5, at_least=True) | None = None
    VICON_RADIAL: Numbers(2) | None = None

    def radial(self) -> list[float]:
        if self.VICON_RADIAL2 is not None:
            return self.VICON_RADIAL2[3:5]
        return self.VICON_RADIAL or [0.0, 0.0]


class XcpCamera(OpenSchema):
    """``<Camera>`` and its first key frame."""

    DEVICEID: Annotated[str, Field(min_length=1)]
    TYPE: str = ""
    SENSOR_SIZE: Numbers(2)
    PIXEL_ASPECT_RATIO: Annotated[Number, Field(gt=0)] = 1.0
    keyframe: KeyFrame

    def is_video(self) -> bool:
        return "video" in self.TYPE.lower()


class XcpFile(OpenSchema):
    """``<Calibration><Camera>...``"""

    cameras: list[XcpCamera] = Field(min_length=1)


def _document(path: Path) -> dict[str, Any]:
    root = xml_root(path, "a Vicon .xcp")
    cameras = []
    for tag in root.findall("Camera"):
        entry: dict[str, Any] = dict(tag.attrib)
        frame = tag.find("KeyFrames/KeyFrame")
        if frame is not None:
            entry["keyframe"] = dict(frame.attrib)
        cameras.append(entry)
    return {"cameras": cameras}


def quaternion_matrix(q: list[float]) -> np.ndarray:
    """(qx, qy, qz, w) -> the rotation matrix (Pose2Sim's ``quat2mat(q, scalar_idx=3)`` transposed back)."""
    x, y, z, w = q
    n = np.sqrt(x * x + y * y + z * z + w * w)
    if not abs(n - 1.0) <= ROTATION_REPAIR_TOL:
        raise ValueError(f"ORIENTATION: not a unit quaternion (norm {n:.6g})")
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def read(path: Path, options: ImportOptions) -> Read:
    """The video cameras in Pose2Sim's order (natural order of their ids), lengths in mm."""
    doc = validate(_document(path), XcpFile, source=path, error=InteropError)
    video = video_cameras(path, doc.cameras, lambda c: c.is_video(), lambda c: c.DEVICEID,
                          "TYPE containing 'video'")
    cams = []
    for c in video:
        k = c.keyframe
        try:
            R = quaternion_matrix(k.ORIENTATION)
        except ValueError as exc:
            raise InteropError(f"{path}: camera {c.DEVICEID}: {exc}") from None
        f, (u, v) = k.FOCAL_LENGTH, k.PRINCIPAL_POINT
        K = np.array([[f, 0.0, u], [0.0, f / c.PIXEL_ASPECT_RATIO, v], [0.0, 0.0, 1.0]])
        dist = np.array(list(k.radial()) + [0.0, 0.0, 0.0])
        t = -R @ np.asarray(k.POSITION, dtype=float)
        size = (int(round(c.SENSOR_SIZE[0])), int(round(c.SENSOR_SIZE[1])))
        cams.append(ForeignCamera(name=c.DEVICEID, size=size, K=K, dist=dist, R=R, t=t))
    return Read(cameras=cams, unit="mm", path=path)
