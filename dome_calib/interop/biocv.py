"""bioCV calibration: a folder of ``*.calib`` text files, one per camera, read as Pose2Sim reads them
(``Pose2Sim/calibration.py``: ``calib_biocv_fun``; pose2sim 0.10.49).

A file, line by line (Pose2Sim's reading: the lines it takes, by position)::

    1920                 width (px)
    1080                 height (px)
    fx 0 cx              K, three rows
    0 fy cy
    0 0 1
    (a line not read)
    r11 r12 r13 tx       [R | t]: world to camera, t in mm
    r21 r22 r23 ty
    r31 r32 r33 tz
    ...                  (not read)
    k1 k2 p1 p2 [k3]     the last line: distortion (OpenCV's order; a k3 is kept: Pose2Sim drops it)

Cameras: the files in name order, named ``cam_00``, ``cam_01``, ... by that order (Pose2Sim's names). Lengths in mm;
the world's up axis is not recorded (z up taken, as Pose2Sim's TRC writer takes it; ``--world-up`` to change).
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field

from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read, five_terms, folder_files
from dome_calib.interop.fields import ROTATION_REPAIR_TOL, rotation_error
from dome_calib.schema import OpenSchema, validate

Finite = Annotated[float, Field(ge=-1e9, le=1e9, allow_inf_nan=False)]


class BiocvCalib(OpenSchema):
    """One ``.calib`` file, as its lines read (see the module docstring)."""

    width: Annotated[int, Field(ge=1, le=100_000)]
    height: Annotated[int, Field(ge=1, le=100_000)]
    K: Annotated[list[Annotated[list[Finite], Field(min_length=3, max_length=3)]], Field(min_length=3, max_length=3)]
    RT: Annotated[list[Annotated[list[Finite], Field(min_length=4, max_length=4)]], Field(min_length=3, max_length=3)]
    distortion: Annotated[list[Finite], Field(min_length=4, max_length=5)]


def _numbers(line: str) -> list[float] | str:
    try:
        return [float(v) for v in line.split()]
    except ValueError:
        return line


def _parse(path: Path) -> dict:
    try:
        lines = path.read_text(encoding="utf-8").split("\n")
    except (OSError, UnicodeDecodeError) as exc:
        raise InteropError(f"{path}: cannot be read ({exc})") from None
    while lines and not lines[-1].strip():
        lines.pop()
    if len(lines) < 10:
        raise InteropError(f"{path}: {len(lines)} lines; a bioCV .calib has width, height, K (3 lines), a line, "
                           "[R | t] (3 lines), ..., distortion (the last line)")

    def integer(text: str):
        try:
            return int(text.strip())
        except ValueError:
            return text.strip()

    return {"width": integer(lines[0]), "height": integer(lines[1]), "K": [_numbers(v) for v in lines[2:5]],
            "RT": [_numbers(v) for v in lines[6:9]], "distortion": _numbers(lines[-1])}


def read(path: Path, options: ImportOptions) -> Read:
    """The cameras of the folder's ``*.calib`` files in name order, lengths in mm."""
    cams = []
    for k, f in enumerate(folder_files(path, ".calib", "a bioCV calibration")):
        c = validate(_parse(f), BiocvCalib, source=f, error=InteropError)
        RT = np.array(c.RT)
        if not rotation_error(RT[:, :3]) <= ROTATION_REPAIR_TOL:
            raise InteropError(f"{f}: [R | t]: R is not a rotation")
        dist = five_terms(c.distortion)  # k3 too where written (Pose2Sim reads the first four only)
        cams.append(ForeignCamera(name=f"cam_{k:02d}", size=(c.width, c.height), K=np.array(c.K), dist=dist,
                                  R=RT[:, :3], t=RT[:, 3]))
    return Read(cameras=cams, unit="mm", path=path)
