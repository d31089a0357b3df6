"""EasyMocap ``intri.yml`` + ``extri.yml`` (OpenCV FileStorage YAML; ``easymocap/mytools/camera_utils.py``).

``intri.yml``: ``names`` (list of camera names, the camera order), per camera ``K_<name>`` (3x3, px, OpenCV
pixel centres), ``dist_<name>`` (1x5 [k1, k2, p1, p2, k3]; ``D_<name>`` also read), ``H_<name>`` / ``W_<name>``
(image size; written by ``write_camera``, not by the calibration tools' ``write_intri``: ``read_camera`` takes them
when present). ``extri.yml``: ``names``, per camera ``R_<name>`` (3x1 Rodrigues vector), ``Rot_<name>`` (3x3),
``T_<name>`` (3x1), all world to camera (``x_cam = R X + T``), T in metres (EasyMocap's documentation: "The metric
of T must be meter"). Both files are written and read with ``cv2.FileStorage`` (full double precision; EasyMocap's
own writer prints 6 decimals). On import ``R_`` is used as ``read_camera`` does (``Rot_`` if ``R_`` is absent);
when both are present they must agree.

World: EasyMocap's is z up (its 3D scene puts the ground at z = 0 and the capture volume above it, from z = 0 to
2 m: ``config/vis3d/o3d_scene.yml``; ``calib_extri`` puts the board on the floor at z = 0): the export turns ours
to z up, the import turns z up to ours (``--world-up`` says otherwise).

Image size: where ``H_``/``W_`` are missing (EasyMocap's ``calib_intri`` writes none) the import takes the size of
the first image in ``images/<camera>/`` beside the files (EasyMocap's data layout), or ``--image-size``.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any

import cv2
import numpy as np
from pydantic import BeforeValidator, ConfigDict, Field, ValidationInfo, field_validator

from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read, Written, five_terms, label
from dome_calib.interop.fields import (CameraMatrix, Distortion, RotationMatrix, RotationVector, SidePx,
                                       Translation, flat)
from dome_calib.exact import rotvec
from dome_calib.rotation import rotation_angle_deg, rotvec_to_matrix
from dome_calib.schema import CameraName, FileSchema, OpenSchema, path_of_name, read_yaml, validate

FILES = ("intri.yml", "extri.yml")
#: ``R_`` and ``Rot_`` of one camera may differ by this much (EasyMocap writes both with 6 decimals).
ROTATION_AGREEMENT_DEG = 1e-3
#: Names that make valid FileStorage keys (``K_<name>``) and survive EasyMocap's ``name.split('.')[0]``.
_KEY_NAME = re.compile(r"[A-Za-z0-9_-]+")
_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


class CalibrationFile(OpenSchema):
    """``intri.yml`` or ``extri.yml``: ``names`` (numbers read as names, as EasyMocap's ``read``) and the per-camera
    entries, checked camera by camera (:class:`Intrinsics`, :class:`Extrinsics`)."""

    model_config = ConfigDict(extra="allow")
    names: list[CameraName | int] = Field(min_length=1)

    def strings(self) -> list[str]:
        return [str(n) for n in self.names]

    def entry(self, key: str) -> Any:
        return (self.__pydantic_extra__ or {}).get(key)


class Intrinsics(FileSchema):
    """One camera's entries of ``intri.yml``: ``K_<name>``, ``dist_<name>`` (or ``D_``), ``H_<name>``, ``W_<name>``."""

    K: CameraMatrix
    dist: Annotated[Distortion, BeforeValidator(flat)]
    H: SidePx | None = None
    W: SidePx | None = None


class Extrinsics(FileSchema):
    """One camera's entries of ``extri.yml``: ``R_<name>`` (Rodrigues), ``Rot_<name>``, ``T_<name>`` (m)."""

    R: Annotated[RotationVector, BeforeValidator(flat)] | None = None
    Rot: RotationMatrix | None = None
    T: Annotated[Translation, BeforeValidator(flat)]

    @field_validator("Rot")
    @classmethod
    def _same_rotation(cls, rot: list[list[float]] | None, info: ValidationInfo) -> list[list[float]] | None:
        rvec = info.data.get("R")
        if rot is not None and rvec is not None:
            gap = float(rotation_angle_deg(rotvec_to_matrix(np.array(rvec)), np.array(rot)))
            if not gap <= ROTATION_AGREEMENT_DEG:
                raise ValueError(f"disagrees with R by {gap:.3g} deg (not the same rotation)")
        return rot

    def matrix(self) -> np.ndarray:
        return rotvec_to_matrix(np.array(self.R)) if self.R is not None else np.array(self.Rot)


def write(cams: list[ForeignCamera], folder: Path, unit: str, options: object = None) -> Written:
    """Write ``intri.yml`` and ``extri.yml`` into ``folder`` (translations already in metres)."""
    for cam in cams:
        if not _KEY_NAME.fullmatch(cam.name):
            raise InteropError(f"camera {cam.name!r}: name: EasyMocap's YAML keys (K_<name>, ...) take letters, "
                               "digits, '_' and '-' only; rename it with --names")
    names = [c.name for c in cams]
    intri = cv2.FileStorage(str(folder / FILES[0]), cv2.FILE_STORAGE_WRITE)
    _write_names(intri, names)
    for cam in cams:
        intri.write(f"K_{cam.name}", np.asarray(cam.K, dtype=float))
        intri.write(f"dist_{cam.name}", np.asarray(cam.dist, dtype=float).reshape(1, 5))
        intri.write(f"H_{cam.name}", int(cam.size[1]))
        intri.write(f"W_{cam.name}", int(cam.size[0]))
    intri.release()
    extri = cv2.FileStorage(str(folder / FILES[1]), cv2.FILE_STORAGE_WRITE)
    _write_names(extri, names)
    for cam in cams:
        extri.write(f"R_{cam.name}", rotvec(cam.R).reshape(3, 1))
        extri.write(f"Rot_{cam.name}", np.asarray(cam.R, dtype=float))
        extri.write(f"T_{cam.name}", np.asarray(cam.t, dtype=float).reshape(3, 1))
    extri.release()
    return Written()


def _write_names(fs: cv2.FileStorage, names: list[str]) -> None:
    fs.startWriteStruct("names", cv2.FileNode_SEQ)
    for name in names:
        fs.write("", name)
    fs.endWriteStruct()


def _image_size(folder: Path, name: str) -> tuple[int, int] | None:
    """(width, height) of the first image in ``folder/images/<name>/`` (EasyMocap's data layout), if any."""
    images = path_of_name(folder / "images", name)
    if not images.is_dir():
        return None
    for path in sorted(p for p in images.iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is not None:
            return int(image.shape[1]), int(image.shape[0])
    return None


def read(folder: Path, options: ImportOptions) -> Read:
    """Cameras in the order of ``intri.yml``'s ``names``, translations in metres."""
    if not folder.is_dir():
        raise InteropError(f"{folder}: not a folder (an EasyMocap calibration is a folder with "
                           f"{' and '.join(FILES)})")
    paths = [folder / f for f in FILES]
    for path in paths:
        if not path.is_file():
            raise InteropError(f"{path}: missing (an EasyMocap calibration is a folder with {' and '.join(FILES)})")
    intri, extri = (read_yaml(p, CalibrationFile, error=InteropError) for p in paths)
    names, extri_names = intri.strings(), set(extri.strings())
    cams = []
    for name in names:
        if name not in extri_names:
            raise InteropError(f"{paths[1]}: camera {label(name)}: names: listed in intri.yml but not here")
        dist = intri.entry(f"dist_{name}")
        i = validate({k: v for k, v in (("K", intri.entry(f"K_{name}")), ("H", intri.entry(f"H_{name}")),
                                        ("W", intri.entry(f"W_{name}")),
                                        ("dist", dist if dist is not None else intri.entry(f"D_{name}")))
                      if v is not None}, Intrinsics, source=f"{paths[0]}: camera {label(name)}", error=InteropError)
        if extri.entry(f"R_{name}") is None and extri.entry(f"Rot_{name}") is None:
            raise InteropError(f"{paths[1]}: camera {label(name)}: R_{name}: missing (expected the Rodrigues vector "
                               f"R_{name} or the matrix Rot_{name})")
        e = validate({k: v for k, v in (("R", extri.entry(f"R_{name}")), ("Rot", extri.entry(f"Rot_{name}")),
                                        ("T", extri.entry(f"T_{name}"))) if v is not None},
                     Extrinsics, source=f"{paths[1]}: camera {label(name)}", error=InteropError)
        size = (i.W, i.H) if i.W is not None and i.H is not None else options.image_size or _image_size(folder, name)
        if size is None:
            raise InteropError(f"{paths[0]}: camera {label(name)}: H_{name}/W_{name}: missing (EasyMocap's calib_intri "
                               "writes no image size): give --image-size WIDTHxHEIGHT, or keep the images beside the "
                               "files (images/<camera>/)")
        cams.append(ForeignCamera(name=name, size=size, K=np.array(i.K), dist=five_terms(i.dist), R=e.matrix(),
                                  t=np.array(e.T)))
    return Read(cameras=cams, unit="m", path=folder)

