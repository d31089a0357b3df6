"""easyWand's DLT calibration, ``<name>_dltCoefs.csv`` (easyWand / DLTdv, Ty Hedrick's lab; Argus writes the same
layout), read into pinhole cameras.

The file: comma-separated numbers, **11 rows, one column per camera** (no header), as DLTdv reads it
(``load(...)``) and as Python users read it (``pd.read_csv(path, header=None)``, then column k is camera k+1). The 11
coefficients L1..L11 of a camera map a world point (x, y, z) to its image point (u, v)::

    u = (L1 x + L2 y + L3 z + L4) / (L9 x + L10 y + L11 z + 1)
    v = (L5 x + L6 y + L7 z + L8) / (L9 x + L10 y + L11 z + 1)

read in argus_gui 2.1.dev3 (``argus_gui/tools.py``: ``dlt_inverse``, ``reconstruct_uv``, ``solve_dlt``; the DLT
definition of kwon3d.com/theory/dlt/dlt.html that ``uv_to_xyz`` cites). The pixels have their **origin at the bottom
left** (``dlt_inverse``: "image coordinates with the origin at the bottom left"; argus' frame finder reads the
image at row ``height - y``, ``argus_gui/frameFinderPyglet.py``), so v = height - y of OpenCV's pixel centres:
the image height is not in the file and is needed (``--image-size WxH``). DLTdv 8 can turn coefficients to an
upper-left origin (tlhedrick/dltdv @ 297d9317, ``DLTdv8a_internal/dlt_invert.m``, which also reads the file as one
column of 11 per camera); such a file is not easyWand's output and would come out upside down here.

Each camera's 3 x 4 matrix ``P = [[L1 L2 L3 L4], [L5 L6 L7 L8], [L9 L10 L11 1]]``, its rows turned to OpenCV's
pixels (v -> height - v), is decomposed (RQ) into K [R | t] with K's diagonal positive and det R = +1, the sign of P
chosen so that the calibrated volume is in front. A DLT has 11 degrees of freedom, a pinhole without skew 10: the
skew K[0, 1] is dropped (said, with what it moves at the image corner) and fx, fy kept apart. easyWand's lens
distortion is not in this file (the coefficients are for undistorted points): no distortion. Lengths are the
wand's unit, not recorded (``--unit``); the world is easyWand's (its axis points), z up taken.
Cameras: ``cam_01``, ``cam_02``, ... in column order (DLTdv's camera numbers).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field

from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read
from dome_calib.schema import OpenSchema, validate

logger = logging.getLogger(__name__)

Coefficient = Annotated[float, Field(ge=-1e12, le=1e12, allow_inf_nan=False)]
#: Rows of the file: the 11 DLT coefficients.
DLT_TERMS = 11
#: A skew moving the image's edge by more than this (px) is said when it is dropped (a DLT fitted to noisy points
#: has some; one made from a pinhole has only rounding's).
SKEW_SAID_PX = 1e-3


class DltCoefsFile(OpenSchema):
    """``*_dltCoefs.csv``: ``rows`` (11 rows of one coefficient per camera, the same count in each)."""

    rows: Annotated[list[Annotated[list[Coefficient], Field(min_length=1, max_length=1000)]],
                    Field(min_length=DLT_TERMS, max_length=DLT_TERMS)]


def _parse(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InteropError(f"{path}: cannot be read ({exc})") from None
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        row = []
        for cell in line.split(","):
            try:
                row.append(float(cell))
            except ValueError:
                raise InteropError(f"{path}: line {n}: {cell.strip()!r} is not a number (easyWand's DLT file is 11 "
                                   "rows of numbers, one column per camera)") from None
        rows.append(row)
    return {"rows": rows}


def dlt_camera(L: np.ndarray, height_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """11 DLT coefficients (pixels from the bottom left) -> K (with its skew), R, t (world to camera, the file's
    unit) in OpenCV's pixels; InteropError's message (ValueError) where they are no camera."""
    P = np.append(np.asarray(L, float), 1.0).reshape(3, 4)
    P = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, float(height_px)], [0.0, 0.0, 1.0]]) @ P  # v -> height - v
    M = P[:, :3]
    if not np.isfinite(P).all() or abs(np.linalg.det(M)) < 1e-300:
        raise ValueError("its 3 x 3 part is singular: not a camera")
    if np.linalg.det(M) < 0:
        P = -P  # the sign that makes R a rotation (det +1); K's diagonal is made positive below
        M = P[:, :3]
    # RQ by QR of the flipped transpose: M = K R, K upper triangular
    Q, U = np.linalg.qr(np.flipud(M).T)
    K = np.flipud(np.fliplr(U.T))
    R = np.flipud(Q.T)
    S = np.diag(np.sign(np.diag(K)))
    K, R = K @ S, S @ R
    if np.linalg.det(R) < 0:
        raise ValueError("it maps the world mirrored (no rotation and positive focal lengths fit it)")
    t = np.linalg.solve(K, P[:, 3])  # P = K [R | t] whatever P's scale: K carries it
    return K / K[2, 2], R, t


def read(path: Path, options: ImportOptions) -> Read:
    """The cameras of an easyWand ``*_dltCoefs.csv`` (see the module docstring); ``options.image_size`` needed."""
    if path.is_dir():
        found = sorted(path.glob("*_dltCoefs.csv"))
        if len(found) != 1:
            raise InteropError(f"{path}: a folder with {len(found)} *_dltCoefs.csv files; give the file")
        path = found[0]
    doc = validate(_parse(path), DltCoefsFile, source=path, error=InteropError)
    widths = {len(r) for r in doc.rows}
    if len(widths) != 1:
        raise InteropError(f"{path}: rows of {sorted(widths)} columns; every row holds one coefficient per camera")
    if options.image_size is None:
        raise InteropError(f"{path}: easyWand's DLT records no image size, and its pixels start at the bottom left: "
                           "give --image-size WIDTHxHEIGHT (the cameras' video size)")
    width, height = options.image_size
    L = np.array(doc.rows, float)  # (11, cameras)
    cams = []
    for k in range(L.shape[1]):
        name = f"cam_{k + 1:02d}"
        try:
            K, R, t = dlt_camera(L[:, k], height)
        except ValueError as exc:
            raise InteropError(f"{path}: column {k + 1} ({name}): {exc}") from None
        # dropping the skew moves a point's u by skew * its normalised y: at the image's top or bottom edge
        moved = abs(float(K[0, 1])) * max(abs(K[1, 2]), abs(height - 1 - K[1, 2])) / K[1, 1]
        if moved > SKEW_SAID_PX:
            skew = float(K[0, 1])
            logger.warning("%s: %s: the DLT's skew %.3g px is dropped (a pinhole without skew): %.3g px at the "
                           "image's top or bottom edge", path, name, skew, moved)
        K = K.copy()
        K[0, 1] = 0.0
        cams.append(ForeignCamera(name=name, size=(int(width), int(height)), K=K, dist=np.zeros(5), R=R, t=t))
    return Read(cameras=cams, unit=None, path=path)
