"""Pose2Sim ``Calib.toml`` (``calibration.py: toml_write``; read by ``common.py: retrieve_calib_params``).

One table per camera, in file order (Pose2Sim reads ``calib.keys()`` in order, skipping ``metadata``,
``capture_volume``, ``charuco``, ``checkerboard``), with ``name``, ``size`` [w, h] (floats), ``matrix`` (K, px,
OpenCV pixel centres), ``distortions`` [k1, k2, p1, p2] (4 terms: no k3), ``rotation`` (Rodrigues, world to
camera), ``translation`` (world to camera, metres), ``fisheye`` (false), and ``[metadata]`` ``adjusted`` /
``error``. The export names each table after its camera, in the bundle's order.

What is lost: k3. The export reports, per camera with k3 != 0, how many pixels dropping it moves the point seen
at the image corner. Import accepts 4 terms (k3 = 0) or 5 (k3 kept), refuses ``fisheye = true``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import tomli_w

from dome_calib.interop.aniposelib import camera_keys, camera_table, load_toml, read_table
from dome_calib.interop.common import ForeignCamera, corner_shift_px

UNIT = "m"


def write_pose2sim(cams: list[ForeignCamera], path: Path) -> dict[str, float]:
    """Write ``Calib.toml`` (translations must already be in metres). Returns camera -> corner shift (px) caused
    by the dropped k3, for the cameras whose k3 is not zero."""
    doc: dict[str, Any] = {}
    shifts: dict[str, float] = {}
    for cam in cams:
        doc[cam.name] = camera_table(cam, n_dist=4, size_as_float=True) | {"fisheye": False}
        if cam.dist[4] != 0.0:
            shifts[cam.name] = corner_shift_px(cam, [*cam.dist[:4], 0.0])
    doc["metadata"] = {"adjusted": False, "error": 0.0}
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    return shifts


def read_pose2sim(path: Path) -> list[ForeignCamera]:
    """Cameras in file order, translations in metres."""
    what = "a Pose2Sim Calib.toml"
    doc = load_toml(path, what)
    keys = [k for k in camera_keys(doc, path, what) if isinstance(doc[k], dict)]  # as Pose2Sim: tables only
    return [read_table(path, k, doc[k], (4, 5), what) for k in keys or camera_keys({}, path, what)]
