"""aniposelib / anipose ``calibration.toml`` (``CameraGroup.dump`` / ``CameraGroup.load``).

One table per camera with ``name``, ``size`` [w, h], ``matrix`` (K, px, OpenCV pixel centres), ``distortions``
[k1, k2, p1, p2, k3] (``cv2.projectPoints`` order), ``rotation`` (Rodrigues vector, world to camera),
``translation`` (world to camera), plus a ``[metadata]`` table kept as is. The length unit is that of the
calibration board's squares (anipose's ``board_square_side_length``); the file does not record it.

Order: ``CameraGroup.load`` sorts the table names as strings (``cam_10`` before ``cam_2``), so the export names
them ``cam_000``, ``cam_001``, ... (zero-padded to the camera count) and the sort gives the bundle's order. The
unit written is recorded in ``[metadata]`` as ``unit`` with ``written_by`` (aniposelib keeps the metadata table
and ignores it). The camera table's schema (:class:`CameraTable`) is Pose2Sim's too.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tomli_w
from pydantic import AfterValidator, ConfigDict, Field, model_validator

from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read, Written, five_terms
from dome_calib.interop.fields import CameraMatrix, Distortion, RotationVector, SidePxNumber, Translation
from dome_calib.exact import rotvec
from dome_calib.rotation import rotvec_to_matrix
from dome_calib.schema import CameraName, OpenSchema, Vec, read_toml


def section_names(count: int) -> list[str]:
    """``cam_000`` .. : zero-padded so that sorting them as strings keeps their order."""
    width = max(3, len(str(count - 1)))
    return [f"cam_{i:0{width}d}" for i in range(count)]


def _pinhole(fisheye: bool) -> bool:
    if fisheye:
        raise ValueError("fisheye cameras cannot be represented (OpenCV pinhole model only)")
    return fisheye


class CameraTable(OpenSchema):
    """One camera of an aniposelib or Pose2Sim calibration (other keys are the peer's and ignored)."""

    name: CameraName
    size: Vec(2, SidePxNumber) = Field(description="[width, height] px (Pose2Sim writes them as floats)")
    matrix: CameraMatrix
    distortions: Distortion
    rotation: RotationVector = Field(description="Rodrigues vector, world to camera")
    translation: Translation = Field(description="world to camera, in the file's unit")
    fisheye: Annotated[bool, AfterValidator(_pinhole)] = False

    def camera(self) -> ForeignCamera:
        return ForeignCamera(name=self.name, size=(int(self.size[0]), int(self.size[1])), K=np.array(self.matrix),
                             dist=five_terms(self.distortions), R=rotvec_to_matrix(np.array(self.rotation)), t=np.array(self.translation))


class Metadata(OpenSchema):
    """The ``[metadata]`` table: this toolkit records the unit it wrote and that it wrote the file."""

    unit: Literal["mm", "cm", "m"] | None = None
    written_by: str | None = None


class AniposeFile(OpenSchema):
    """``calibration.toml``: every table but ``[metadata]`` is a camera."""

    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, CameraTable]
    metadata: Metadata = Metadata()

    @model_validator(mode="after")
    def _has_cameras(self) -> AniposeFile:
        if not self.__pydantic_extra__:
            raise ValueError("no camera tables (is this an aniposelib calibration.toml?)")
        return self


def camera_table(cam: ForeignCamera, *, size_as_float: bool = False) -> dict[str, Any]:
    """One camera's TOML table (floats written by tomli_w with repr: exact)."""
    size = [float(v) for v in cam.size] if size_as_float else [int(v) for v in cam.size]
    return {
        "name": cam.name,
        "size": size,
        "matrix": np.asarray(cam.K, dtype=float).tolist(),
        "distortions": [float(v) for v in cam.dist],
        "rotation": rotvec(cam.R).tolist(),
        "translation": np.asarray(cam.t, dtype=float).tolist(),
    }


def write(cams: list[ForeignCamera], path: Path, unit: str, options: object = None) -> Written:
    """Write ``calibration.toml`` for ``CameraGroup.load`` (sections sorted into our order)."""
    doc: dict[str, Any] = {key: camera_table(cam) for key, cam in zip(section_names(len(cams)), cams)}
    doc["metadata"] = {"unit": unit, "written_by": "dome-calib export --to aniposelib"}
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    return Written()


def read(path: Path, options: ImportOptions) -> Read:
    """Cameras in ``CameraGroup.load``'s order (table names sorted as strings) and the unit the metadata names
    (only files written by this toolkit record one)."""
    doc = read_toml(path, AniposeFile, error=InteropError)
    tables = doc.__pydantic_extra__
    return Read(cameras=[tables[k].camera() for k in sorted(tables)], unit=doc.metadata.unit, path=path)
