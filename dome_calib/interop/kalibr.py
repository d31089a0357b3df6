"""Kalibr camera chain ``camchain.yaml`` (``aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py``:
``CameraChainParameters``, ``CameraParameters``; ethz-asl/kalibr @ ea2791f0).

``cam0``, ``cam1``, ... (Kalibr reads ``cam{n}`` for n < the number of entries), each with ``camera_model``,
``intrinsics`` (pinhole: ``[fu, fv, pu, pv]`` px), ``distortion_model`` (``radtan``: ``[k1, k2, r1, r2]``, OpenCV's
``[k1, k2, p1, p2]``), ``distortion_coeffs``, ``resolution`` [w, h], and from cam1 on ``T_cn_cnm1``: the 4x4 rigid
transform taking points of camera n-1 into camera n (``setExtrinsicsLastCamToHere``), metres. Other keys
(``rostopic``, ``cam_overlaps``, ``T_cam_imu``, ``timeshift_cam_imu``) are Kalibr's and not read. Pixels: Kalibr's
targets are detected in OpenCV's pixel convention (the top-left pixel's centre at 0, 0), as ours.

The world is cam0's frame (x right, y down, z forward of camera 0): each camera's pose is the chain of
``T_cn_cnm1`` from cam0. Only ``pinhole`` with ``radtan`` or ``none`` distortion can be represented (``omni``,
``eucm``, ``ds``, ``equidistant``, ``fov`` are refused). The file is YAML, read as Kalibr reads it
(``yaml.safe_load``).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import ConfigDict, model_validator

from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read
from dome_calib.interop.fields import Bounded, DistTerm, RigidTransform, SidePx
from dome_calib.schema import OpenSchema, Vec, refuse_alias_bombs, show, validate

_CAM = re.compile(r"cam(0|[1-9][0-9]*)")


class KalibrCamera(OpenSchema):
    """One ``cam{n}`` entry."""

    camera_model: str
    intrinsics: list[Bounded]
    distortion_model: str
    distortion_coeffs: list[DistTerm]
    resolution: Vec(2, SidePx)
    T_cn_cnm1: RigidTransform | None = None  # noqa: N815 (Kalibr's name)

    @model_validator(mode="after")
    def _pinhole(self) -> KalibrCamera:
        if self.camera_model != "pinhole":
            raise ValueError(f"camera_model {show(self.camera_model)} cannot be represented (pinhole only)")
        if len(self.intrinsics) != 4 or not (self.intrinsics[0] > 0 and self.intrinsics[1] > 0):
            raise ValueError(f"intrinsics: expected [fu, fv, pu, pv] with fu, fv > 0, got {self.intrinsics}")
        if self.distortion_model not in ("radtan", "none"):
            raise ValueError(f"distortion_model {show(self.distortion_model)} cannot be represented (radtan or none: "
                             "OpenCV's [k1, k2, p1, p2])")
        if self.distortion_model == "radtan" and len(self.distortion_coeffs) != 4:
            raise ValueError(f"distortion_coeffs: {len(self.distortion_coeffs)} terms, radtan has 4 [k1, k2, r1, r2]")
        return self


class CamchainFile(OpenSchema):
    """``camchain.yaml``: ``cam0`` .. ``cam{N-1}``."""

    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, KalibrCamera]

    @model_validator(mode="before")
    @classmethod
    def _cameras_only(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        names = [k for k in data if not _CAM.fullmatch(str(k))]
        if names:
            raise ValueError(f"{names[0]!r}: not a camera entry (a camera chain holds cam0, cam1, ...)")
        numbers = sorted(int(str(k)[3:]) for k in data)
        if numbers != list(range(len(numbers))) or not numbers:
            raise ValueError(f"cameras {', '.join(f'cam{n}' for n in numbers) or 'none'}: expected cam0 .. "
                             f"cam{len(numbers) - 1} without gaps (Kalibr reads cam{{n}} for n < their count)")
        return data

    @model_validator(mode="after")
    def _chain(self) -> CamchainFile:
        for key, cam in (self.__pydantic_extra__ or {}).items():
            if key != "cam0" and cam.T_cn_cnm1 is None:
                raise ValueError(f"{key}.T_cn_cnm1: missing (the transform from cam{int(key[3:]) - 1} to {key})")
        return self

    def cameras(self) -> list[tuple[str, KalibrCamera]]:
        extra = self.__pydantic_extra__ or {}
        return [(f"cam{n}", extra[f"cam{n}"]) for n in range(len(extra))]


def _load(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InteropError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise InteropError(f"{path}: is a folder, expected Kalibr's camchain.yaml") from None
    except UnicodeDecodeError:
        raise InteropError(f"{path}: not a UTF-8 text file (expected Kalibr's camchain.yaml)") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InteropError(f"{path}: not YAML ({str(exc).splitlines()[0]}); expected Kalibr's camchain.yaml") \
            from None
    return refuse_alias_bombs(data, path, InteropError)


def read(path: Path, options: ImportOptions) -> Read:
    """The cameras cam0, cam1, ... in cam0's frame, metres."""
    doc = validate(_load(path), CamchainFile, source=path, error=InteropError)
    cams = []
    cam_from_world = np.eye(4)
    for name, c in doc.cameras():
        if c.T_cn_cnm1 is not None:
            step = np.array(c.T_cn_cnm1)
            U, _, Vt = np.linalg.svd(step[:3, :3])
            step[:3, :3] = U @ Vt
            cam_from_world = step @ cam_from_world
        fu, fv, pu, pv = c.intrinsics
        dist = np.zeros(5)
        if c.distortion_model == "radtan":
            dist[:4] = c.distortion_coeffs
        cams.append(ForeignCamera(name=name, size=(c.resolution[0], c.resolution[1]),
                                  K=np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]]), dist=dist,
                                  R=cam_from_world[:3, :3].copy(), t=cam_from_world[:3, 3].copy()))
    return Read(cameras=cams, unit="m", path=path)
