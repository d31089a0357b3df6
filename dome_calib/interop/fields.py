"""Typed fields shared by the schemas of other tools' calibration files (pydantic, through
:mod:`dome_calib.schema`): a camera matrix, distortion terms, a Rodrigues vector, a rotation matrix, an image size.

Each is strict (numbers are numbers, never strings or booleans), finite and bounded (a value beyond the bound is a
unit mix-up or garbage, not a calibration); each says what is wrong in words that end up in the one-line message
``<file>: <field path>: <what>``.
"""
from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import AfterValidator, BeforeValidator, Field

from dome_calib.exact import det3, matmul3, transpose3
from dome_calib.schema import Finite, Vec, show

#: Largest plausible magnitude of a pixel value (focal length, principal point) and of a distortion term.
LIMIT_PX = 1e6
LIMIT_DIST = 1e6
#: Largest plausible translation in any file unit (10 km in metres; in mm, 10 m: checked again in cm on import).
LIMIT_T = 1e7
#: Largest image side, px.
LIMIT_SIZE_PX = 100_000
#: |R R^T - I| up to this is kept as written; up to REPAIR it is replaced by the nearest rotation (a file written
#: with ~6 decimals); beyond it is refused.
ROTATION_EXACT_TOL = 1e-8
ROTATION_REPAIR_TOL = 1e-5

Bounded = Annotated[float, Field(ge=-LIMIT_PX, le=LIMIT_PX, allow_inf_nan=False)]
DistTerm = Annotated[float, Field(ge=-LIMIT_DIST, le=LIMIT_DIST, allow_inf_nan=False)]
Length = Annotated[float, Field(ge=-LIMIT_T, le=LIMIT_T, allow_inf_nan=False)]
Angle = Annotated[float, Field(ge=-1e3, le=1e3, allow_inf_nan=False)]
SidePx = Annotated[int, Field(ge=1, le=LIMIT_SIZE_PX)]


def _integral(value: float) -> float:
    if not float(value).is_integer():
        raise ValueError(f"expected a whole number of pixels, got {show(value)}")
    return value


#: An image side written as a number with no fraction (Pose2Sim writes ``1088.0``).
SidePxNumber = Annotated[float, Field(ge=1, le=LIMIT_SIZE_PX, allow_inf_nan=False), AfterValidator(_integral)]


def _camera_matrix(K: list[list[float]]) -> list[list[float]]:
    if not (K[0][0] > 0 and K[1][1] > 0):
        raise ValueError(f"focal lengths must be positive (fx={K[0][0]:g}, fy={K[1][1]:g})")
    if K[0][1] != 0 or K[1][0] != 0 or K[2] != [0, 0, 1]:
        raise ValueError(f"expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {K}")
    return K


def flat(value: Any) -> Any:
    """An OpenCV matrix read as nested lists (1xN or Nx1) -> a flat list; anything else unchanged (a
    ``BeforeValidator`` of a vector field)."""
    if isinstance(value, list) and value and all(isinstance(row, list) for row in value):
        if len(value) == 1 or all(len(row) == 1 for row in value):
            return [v for row in value for v in row]
    return value


#: ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` px, fx, fy > 0.
CameraMatrix = Annotated[Vec(3, Vec(3, Bounded)), AfterValidator(_camera_matrix)]


def _distortion(terms: list[float]) -> list[float]:
    if len(terms) not in (4, 5):
        raise ValueError(f"{len(terms)} terms, expected 4 [k1, k2, p1, p2] or 5 [k1, k2, p1, p2, k3]")
    return terms


#: OpenCV's ``[k1, k2, p1, p2]`` or ``[k1, k2, p1, p2, k3]``.
Distortion = Annotated[list[DistTerm], AfterValidator(_distortion)]
#: A Rodrigues vector (axis times angle, rad).
RotationVector = Vec(3, Angle)
Translation = Vec(3, Length)


def rotation_error(R: Any) -> float:
    """max |R R^T - I| and |det R - 1| of a 3x3 matrix."""
    R = np.asarray(R, dtype=float)  # in basic operations (dome_calib.exact): the same on every CPU
    return max(float(np.abs(matmul3(R, transpose3(R)) - np.eye(3)).max()), abs(float(det3(R)) - 1.0))


def check_rotation(R: list[list[float]]) -> list[list[float]]:
    """``R`` if it is a rotation to ROTATION_REPAIR_TOL; ValueError saying how far it is otherwise."""
    err = rotation_error(R)
    if not err <= ROTATION_REPAIR_TOL:
        raise ValueError(f"not a rotation (|R R^T - I| or |det R - 1| = {err:.2g}; accepted up to "
                         f"{ROTATION_REPAIR_TOL:g})")
    return R


#: A 3x3 rotation (orthonormal, det +1, to ROTATION_REPAIR_TOL).
RotationMatrix = Annotated[Vec(3, Vec(3, Finite)), AfterValidator(check_rotation)]


def _rigid(M: list[list[float]]) -> list[list[float]]:
    if M[3] != [0, 0, 0, 1]:
        raise ValueError(f"last row must be [0, 0, 0, 1], got {M[3]}")
    check_rotation([row[:3] for row in M[:3]])
    return M


#: A 4x4 rigid transform ``[[R, t], [0, 0, 0, 1]]``.
RigidTransform = Annotated[Vec(4, Vec(4, Length)), AfterValidator(_rigid)]


def _number_text(value: Any) -> Any:
    """An XML attribute's text as a number (``"1.5e3"``); anything else is left for the type check to refuse."""
    if isinstance(value, str):
        try:
            return float(value) if any(c in value for c in ".eE") else int(value)
        except ValueError:
            return value
    return value


#: A number written as text (XML attributes): parsed, then checked as any number (finite, bounded).
NumberText = Annotated[Bounded, BeforeValidator(_number_text)]
LengthText = Annotated[Length, BeforeValidator(_number_text)]
