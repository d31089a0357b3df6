"""Pose2Sim ``Calib.toml`` (``calibration.py: toml_write``; read by ``common.py: retrieve_calib_params`` and
``computeP``).

One table per camera, in file order (Pose2Sim reads ``calib.keys()`` in order, skipping ``metadata``,
``capture_volume``, ``charuco``, ``checkerboard`` and anything that is not a table, and pairs calibration table i
with the i-th pose folder), with ``name``, ``size`` [w, h] (floats), ``matrix`` (K, px, OpenCV pixel centres),
``distortions``, ``rotation`` (Rodrigues, world to camera), ``translation`` (world to camera, metres), ``fisheye``
(false), and ``[metadata]`` ``adjusted`` / ``error``. The export names each table after its camera, in the
bundle's order.

Distortion: Pose2Sim's reader passes ``distortions`` to OpenCV as it is (``cv2.undistortPoints``,
``cv2.getOptimalNewCameraMatrix``, ``cv2.projectPoints``), which take 4 or 5 terms; only Pose2Sim's own writer
prints 4. The export writes all 5 (k3 kept: dropping it moved the real HD cameras' corners by 20-34 px); import
accepts 4 (k3 = 0) or 5.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import tomli_w
from pydantic import ConfigDict, model_validator

from dome_calib.interop.aniposelib import CameraTable, camera_table
from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read, Written, label
from dome_calib.schema import OpenSchema, read_toml, show

#: Top-level tables Pose2Sim reads as settings, not cameras (``common.py: retrieve_calib_params``).
SETTINGS = ("metadata", "capture_volume", "charuco", "checkerboard")
WRITTEN_BY = "dome-calib export --to pose2sim"


class Pose2SimMetadata(OpenSchema):
    """``[metadata]``: Pose2Sim's ``adjusted`` / ``error``; a ``unit`` other than metres or a file this toolkit
    wrote for another tool (``written_by``) is not a Pose2Sim calibration."""

    unit: str | None = None
    written_by: str | None = None

    @model_validator(mode="after")
    def _pose2sims(self) -> Pose2SimMetadata:
        if self.written_by is not None and self.written_by != WRITTEN_BY:
            raise ValueError(f"this file was written by {show(self.written_by)}, not for Pose2Sim (lengths in "
                             f"{self.unit or 'its unit'}, not metres): import it with --from "
                             f"{self.written_by.rsplit(' ', 1)[-1]}")
        if self.unit is not None and self.unit != "m":
            raise ValueError(f"the file states unit {show(self.unit)}; Pose2Sim calibrations are in metres (is this "
                             "another tool's file? aniposelib's: --from aniposelib)")
        return self


class Pose2SimFile(OpenSchema):
    """``Calib.toml``: every table but the settings ones is a camera, in file order."""

    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, CameraTable]
    metadata: Pose2SimMetadata = Pose2SimMetadata()
    capture_volume: dict[str, Any] | None = None
    charuco: dict[str, Any] | None = None
    checkerboard: dict[str, Any] | None = None

    @model_validator(mode="before")
    @classmethod
    def _tables_only(cls, data: Any) -> Any:
        """As Pose2Sim: top-level keys that are not tables are not cameras (skipped); a camera table without
        ``name`` is named by its key (Pose2Sim's ``retrieve_calib_params`` never reads ``name``)."""
        if isinstance(data, dict):
            return {k: (v if k in SETTINGS or "name" in v else {"name": k} | v) for k, v in data.items()
                    if k in SETTINGS or isinstance(v, dict)}
        return data

    @model_validator(mode="after")
    def _has_cameras(self) -> Pose2SimFile:
        if not self.__pydantic_extra__:
            raise ValueError("no camera tables (is this a Pose2Sim Calib.toml?)")
        return self


def write(cams: list[ForeignCamera], path: Path, unit: str, options: object = None) -> Written:
    """Write ``Calib.toml`` (translations already in metres), 5 distortion terms."""
    doc: dict[str, Any] = {}
    for cam in cams:
        if cam.name in SETTINGS:
            raise InteropError(f"camera {label(cam.name)}: name: Pose2Sim reads a table of that name as settings, "
                               "not a camera; rename it with --names")
        doc[cam.name] = camera_table(cam, size_as_float=True) | {"fisheye": False}
    doc["metadata"] = {"adjusted": False, "error": 0.0, "written_by": WRITTEN_BY}
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    return Written()


def read(path: Path, options: ImportOptions) -> Read:
    """Cameras in file order, translations in metres."""
    doc = read_toml(path, Pose2SimFile, error=InteropError)
    return Read(cameras=[t.camera() for t in doc.__pydantic_extra__.values()], unit="m", path=path)
