"""aniposelib / anipose ``calibration.toml`` (``CameraGroup.dump`` / ``CameraGroup.load``).

One table per camera with ``name``, ``size`` [w, h], ``matrix`` (K, px, OpenCV pixel centres), ``distortions``
[k1, k2, p1, p2, k3] (``cv2.projectPoints`` order), ``rotation`` (Rodrigues vector, world to camera),
``translation`` (world to camera), plus a ``[metadata]`` table kept as is. The length unit is that of the
calibration board's squares (anipose's ``board_square_side_length``); the file does not record it.

Order: ``CameraGroup.load`` sorts the table names as strings (``cam_10`` before ``cam_2``), so the export names
them ``cam_000``, ``cam_001``, ... (zero-padded to the camera count) and the sort gives the bundle's order. The
unit written is recorded in ``[metadata]`` as ``unit`` (aniposelib keeps the metadata table and ignores it).
"""
from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from dome_calib import panoptic_io as pio
from dome_calib.interop.common import ForeignCamera, InteropError
from dome_calib.rotation import matrix_to_rotvec, rotvec_to_matrix

DEFAULT_UNIT = "mm"
#: Top-level tables that are not cameras (aniposelib's metadata; Pose2Sim's board and volume settings).
NOT_CAMERAS = ("metadata", "capture_volume", "charuco", "checkerboard")


def section_names(count: int) -> list[str]:
    """``cam_000`` .. : zero-padded so that sorting them as strings keeps their order."""
    width = max(3, len(str(count - 1)))
    return [f"cam_{i:0{width}d}" for i in range(count)]


def camera_table(cam: ForeignCamera, *, n_dist: int = 5, size_as_float: bool = False) -> dict[str, Any]:
    """One camera's TOML table (floats written by tomli_w with repr: exact)."""
    size = [float(v) for v in cam.size] if size_as_float else [int(v) for v in cam.size]
    return {
        "name": cam.name,
        "size": size,
        "matrix": np.asarray(cam.K, dtype=float).tolist(),
        "distortions": [float(v) for v in cam.dist[:n_dist]],
        "rotation": matrix_to_rotvec(cam.R).tolist(),
        "translation": np.asarray(cam.t, dtype=float).tolist(),
    }


def write_aniposelib(cams: list[ForeignCamera], path: Path, unit: str) -> None:
    """Write ``calibration.toml`` for ``CameraGroup.load`` (sections sorted into our order)."""
    doc: dict[str, Any] = {key: camera_table(cam) for key, cam in zip(section_names(len(cams)), cams)}
    doc["metadata"] = {"unit": unit, "written_by": "dome-calib export --to aniposelib"}
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")


def load_toml(path: Path, what: str) -> dict[str, Any]:
    """The file's TOML document (one-line error if it is not TOML)."""
    if not path.is_file():
        raise InteropError(f"{path}: not a file (expected {what})")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InteropError(f"{path}: not a TOML file ({str(exc).splitlines()[0]}); expected {what}") from None


def read_table(path: Path, key: str, table: Any, n_dists: tuple[int, ...], what: str) -> ForeignCamera:
    """One camera table -> foreign camera; fields checked with the bundle reader's messages."""
    w = pio._Where(path).at(f"camera {pio._label(key)}")
    if not isinstance(table, dict):
        raise w.fail(key, f"expected a table of camera fields, got {pio._show(table)} (is this {what}?)")
    if table.get("fisheye", False) is True:
        raise w.fail("fisheye", "fisheye cameras cannot be represented (OpenCV pinhole model only)")
    name = w.get(table, "name")
    if not isinstance(name, str) or not name:
        raise w.fail("name", f"expected a non-empty string, got {pio._show(name)}")
    w = w.at(f"camera {pio._label(name)}")
    dist = w.numbers(w.get(table, "distortions"), "distortions", None, pio.LIMITS["dist"]).ravel()
    if dist.size not in n_dists:
        raise w.fail("distortions", f"{dist.size} terms, expected {' or '.join(map(str, n_dists))} for {what}")
    rvec = w.array(table, "rotation", ((3,), (3, 1), (1, 3)), 1e3)
    return ForeignCamera(
        name=name,
        size=w.size(w.get(table, "size"), "size"),
        K=w.array(table, "matrix", ((3, 3),), pio.LIMITS["K_px"]),
        dist=np.concatenate([dist, np.zeros(5 - dist.size)]),
        R=rotvec_to_matrix(rvec),
        t=w.array(table, "translation", ((3,), (3, 1), (1, 3)), pio.LIMITS["t_cm"]),
    )


def camera_keys(doc: dict[str, Any], path: Path, what: str) -> list[str]:
    keys = [k for k in doc if k not in NOT_CAMERAS]
    if not keys:
        raise InteropError(f"{path}: no camera tables (is this {what}?)")
    return keys


def read_aniposelib(path: Path) -> tuple[list[ForeignCamera], str | None]:
    """Cameras in ``CameraGroup.load``'s order (table names sorted as strings) and the unit the metadata names
    (only files written by this toolkit record one)."""
    what = "an aniposelib calibration.toml"
    doc = load_toml(path, what)
    cams = [read_table(path, k, doc[k], (4, 5), what) for k in sorted(camera_keys(doc, path, what))]
    unit = doc.get("metadata", {}).get("unit") if isinstance(doc.get("metadata"), dict) else None
    return cams, unit if isinstance(unit, str) else None
