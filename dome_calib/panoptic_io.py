"""Read and format the four Panoptic files of a bundle.

Each file is read through its schema (:mod:`dome_calib.bundle_schema`): a wrong type, a missing field, a shape, a
NaN, an implausible value or a matrix that is not what it must be is one :class:`BundleFormatError` line naming
the file, the camera or sensor, and the field path (``calibration_s.json: camera 01_03: cameras[2].K: ...``).

Stated leniencies (each logged once per file as a warning):

- a rotation orthonormal only to ``ROTATION_REPAIR_TOL`` (written with ~6 decimals by another tool) is replaced
  by the nearest rotation (SVD); beyond that it is refused; up to ``ROTATION_EXACT_TOL`` it is kept bit for bit;
- a ``kcalibration`` without ``"convention"`` (the Panoptic toolbox writes none) is read with this toolkit's.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from dome_calib.bundle import Camera, CameraType, KinectCalibration, KinectSensor, SyncTable
from dome_calib.bundle_schema import (KINECT_NODE, LIMITS, M_COLOR_CONVENTION, ROTATION_EXACT_TOL,
                                      ROTATION_REPAIR_TOL, CalibrationFile, KCalibrationFile, KSyncTablesFile,
                                      SyncTableEntry, SyncTablesFile)
from dome_calib.errors import BundleFormatError
from dome_calib.jsonfmt import dumps
from dome_calib.schema import read_json

logger = logging.getLogger(__name__)

__all__ = ["LIMITS", "KINECT_NODE", "M_COLOR_CONVENTION", "ROTATION_EXACT_TOL", "ROTATION_REPAIR_TOL",
           "read_calibration", "read_kcalibration", "read_synctables", "read_ksynctables", "format_calibration",
           "format_kcalibration", "format_synctables", "format_ksynctables"]

_TYPE_ORDER = [CameraType.VGA, CameraType.HD, CameraType.KINECT_COLOR]


class _Repairs:
    """The rotations of one file re-orthonormalised on reading (said once per file)."""

    def __init__(self, path: Path) -> None:
        self.path, self.names, self.worst = path, [], 0.0

    def rotation(self, R: list, owner: str) -> np.ndarray:
        """R as written when orthonormal to ROTATION_EXACT_TOL, else the nearest rotation (the schema refused
        those beyond ROTATION_REPAIR_TOL)."""
        R = np.asarray(R, dtype=float)
        err = float(np.abs(R @ R.T - np.eye(3)).max())
        if err <= ROTATION_EXACT_TOL and abs(float(np.linalg.det(R)) - 1.0) <= ROTATION_EXACT_TOL:
            return R
        U, _, Vt = np.linalg.svd(R)
        self.names.append(owner)
        self.worst = max(self.worst, err)
        return U @ Vt  # det(U Vt) = +1 here: det(R) is within 3e-5 of 1

    def transform(self, M: list, owner: str) -> np.ndarray:
        M = np.asarray(M, dtype=float)
        M[:3, :3] = self.rotation(M[:3, :3].tolist(), owner)
        return M

    def warn(self) -> None:
        if not self.names:
            return
        shown = ", ".join(self.names[:4]) + (f", ... ({len(self.names)} in all)" if len(self.names) > 4 else "")
        logger.warning("%s: %d rotation(s) orthonormal only to %.2g (%s), as when written with few decimals: replaced "
                       "by the nearest rotation", self.path, len(self.names), self.worst, shown)


def read_calibration(path: Path) -> tuple[dict[str, Camera], str]:
    """``calibration_<seq>.json`` -> (cameras keyed by name, calibDataSource)."""
    data = read_json(path, CalibrationFile, error=BundleFormatError)
    repairs = _Repairs(path)
    cameras = {c.name: Camera(name=c.name, type=CameraType(c.type), resolution=(c.resolution[0], c.resolution[1]),
                              K=np.asarray(c.K, dtype=float), dist=np.asarray(c.distCoef, dtype=float),
                              R=repairs.rotation(c.R, f"camera {c.name} R"), t_cm=np.asarray(c.t, dtype=float),
                              panel=c.panel, node=c.node)
               for c in data.cameras}
    repairs.warn()
    return cameras, data.calibDataSource


def format_calibration(cameras: dict[str, Camera], calib_data_source: str) -> str:
    """Cameras -> text of ``calibration_<seq>.json`` in the Panoptic layout and order (VGA, HD, Kinect; by name)."""
    entries = [
        {
            "name": c.name, "type": str(c.type), "resolution": list(c.resolution), "panel": c.panel, "node": c.node,
            "K": c.K, "distCoef": c.dist, "R": c.R, "t": c.t_cm.reshape(3, 1),
        }
        for c in sorted(cameras.values(), key=lambda c: (_TYPE_ORDER.index(c.type), c.name))
    ]
    return dumps({"calibDataSource": calib_data_source, "cameras": entries}) + "\n"


def read_kcalibration(path: Path) -> KinectCalibration:
    """``kcalibration_<seq>.json`` -> :class:`KinectCalibration`. Sensors are named by their ``name`` field, else
    KINECTNODE1.. in file order. A file without ``"convention"`` is read with ours (one warning)."""
    data = read_json(path, KCalibrationFile, error=BundleFormatError)
    repairs = _Repairs(path)
    sensors: dict[str, KinectSensor] = {}
    for i, s in enumerate(data.sensors):
        name = s.name or f"KINECTNODE{i + 1}"
        dist_depth = np.asarray(s.distCoeffs_depth, dtype=float)
        sensors[name] = KinectSensor(
            name=name, K_depth=np.asarray(s.K_depth, dtype=float), dist_depth=dist_depth[:5],
            depth_size=(s.depth_width, s.depth_height), K_color=np.asarray(s.K_color, dtype=float),
            dist_color=np.asarray(s.distCoeffs_color, dtype=float), color_size=(s.color_width, s.color_height),
            M_depth=repairs.transform(s.M_depth, f"sensor {name} M_depth"),
            M_color=repairs.transform(s.M_color, f"sensor {name} M_color"),
            M_world2sensor=repairs.transform(s.M_world2sensor, f"sensor {name} M_world2sensor"),
            color_time_offset_ms=s.color_time_offset, depth_time_offset_ms=s.depth_time_offset,
            depth_bias_mm=s.depth_bias_mm, depth_scale=s.depth_scale,
            extra=dict(s.model_extra or {})
            | ({"distCoeffs_depth_tail": dist_depth[5:].tolist()} if dist_depth.size > 5 else {}),
        )
    repairs.warn()
    if data.convention is None:
        logger.warning("%s: no 'convention' field (as in the Panoptic toolbox's files): read with this toolkit's, "
                       "M_depth = sensor_from_depth and M_color = sensor_from_color", path)
    return KinectCalibration(sensors=sensors, M_world2vga=np.asarray(data.M_world2vga, dtype=float),
                             calib_data_source=data.calibDataSource,
                             panoptic_calib_data_source=data.panopticCalibDataSource)


def format_kcalibration(kinect: KinectCalibration) -> str:
    """:class:`KinectCalibration` -> text of ``kcalibration_<seq>.json`` (Panoptic layout plus our convention)."""
    sensors = []
    for name, s in kinect.sensors.items():
        if not KINECT_NODE.fullmatch(name):  # what read_kcalibration would refuse is never written
            raise BundleFormatError(f"Kinect sensor {name!r}: not named KINECTNODE<n>; it would not read back")
        extra = dict(s.extra)
        tail = extra.pop("distCoeffs_depth_tail", [])
        sensors.append({
            "name": name,
            "K_depth": s.K_depth, "M_depth": s.M_depth, "distCoeffs_depth": list(s.dist_depth) + list(tail),
            "depth_width": s.depth_size[0], "depth_height": s.depth_size[1],
            "K_color": s.K_color, "M_color": s.M_color, "distCoeffs_color": s.dist_color.reshape(5, 1),
            "color_width": s.color_size[0], "color_height": s.color_size[1],
            "color_time_offset": s.color_time_offset_ms, "depth_time_offset": s.depth_time_offset_ms,
            "depth_bias_mm": s.depth_bias_mm, "depth_scale": s.depth_scale,
            "M_world2sensor": s.M_world2sensor, **extra,
        })
    return dumps({
        "calibDataSource": kinect.calib_data_source,
        "panopticCalibDataSource": kinect.panoptic_calib_data_source,
        "convention": M_COLOR_CONVENTION,
        "sensors": sensors,
        "M_world2vga": kinect.M_world2vga,
    }) + "\n"


def _table(entry: SyncTableEntry) -> SyncTable:
    return SyncTable(index=np.asarray(entry.index, dtype=np.int64), univ_time_ms=np.asarray(entry.univ_time, float))


def read_synctables(path: Path) -> dict[str, SyncTable]:
    """``synctables_<seq>.json`` -> {"vga": table, "hd": table} (univ_time in ms)."""
    data = read_json(path, SyncTablesFile, error=BundleFormatError)
    return {stream: _table(entry) for stream, entry in data.root.items()}


def read_ksynctables(path: Path) -> tuple[dict[str, SyncTable], dict[str, SyncTable]]:
    """``ksynctables_<seq>.json`` -> (colour tables, depth tables), each keyed by "KINECTNODE<n>"."""
    data = read_json(path, KSyncTablesFile, error=BundleFormatError)
    return ({n: _table(e) for n, e in data.kinect.color.items()}, {n: _table(e) for n, e in data.kinect.depth.items()})


def _table_json(table: SyncTable) -> dict:
    return {"index": table.index.astype(int).tolist(), "univ_time": table.univ_time_ms}


def format_synctables(streams: dict[str, SyncTable]) -> str:
    return dumps({name: _table_json(t) for name, t in streams.items()}) + "\n"


def format_ksynctables(color: dict[str, SyncTable], depth: dict[str, SyncTable]) -> str:
    for node in [*color, *depth]:  # what read_ksynctables would refuse is never written
        if not KINECT_NODE.fullmatch(node):
            raise BundleFormatError(f"Kinect sync table {node!r}: not named KINECTNODE<n>; it would not read back")
    return dumps({"kinect": {
        "color": {n: _table_json(t) for n, t in color.items()},
        "depth": {n: _table_json(t) for n, t in depth.items()},
    }}) + "\n"


# ---- the hand checks the interop readers (dome_calib/interop) still use until they read through schemas --------
# (the bundle's own files no longer do: delete these with their last use)

def _show(value: Any, n: int = 60) -> str:
    """A value from a file, shortened, on one line (for error messages)."""
    text = json.dumps(value)
    return text if len(text) <= n else text[: n - 3] + "..."


def _label(name: str) -> str:
    """A name from a file as shown in messages: as is if short and printable, else quoted and shortened."""
    return name if name.isprintable() and len(name) <= 40 else _show(name, 40)


def _float_array(value: Any) -> np.ndarray | None:
    """Nested lists of JSON numbers (int or float; never bool, string, null) -> float array; None otherwise."""
    if isinstance(value, (bool, str, dict)) or value is None:
        return None
    try:
        obj = np.array(value, dtype=object)
    except ValueError:  # ragged nesting
        return None
    if not all(type(v) is float or type(v) is int for v in obj.flat):
        return None
    try:
        return obj.astype(float)
    except OverflowError:  # an integer beyond the float range
        return None


class _Where:
    """Names the place of a value for error messages: file, camera (or sensor, stream) and field. ``repaired``
    collects the owners whose rotations were re-orthonormalised (shared per file: one warning per file)."""

    def __init__(self, path: Path, owner: str = "", repaired: list[tuple[str, float]] | None = None) -> None:
        self.path, self.owner = path, owner
        self.repaired = repaired if repaired is not None else []

    def at(self, owner: str) -> _Where:
        return _Where(self.path, owner, self.repaired)

    def fail(self, field: str, problem: str) -> BundleFormatError:
        owner = f"{self.owner}: " if self.owner else ""
        return BundleFormatError(f"{self.path}: {owner}field '{field}': {problem}")

    def get(self, obj: dict, field: str) -> Any:
        if not isinstance(obj, dict) or field not in obj:
            raise self.fail(field, "missing")
        return obj[field]

    def array(self, obj: dict, field: str, shapes: tuple[tuple[int, ...], ...], limit: float) -> np.ndarray:
        return self.numbers(self.get(obj, field), field, shapes, limit)

    def numbers(self, value: Any, field: str, shapes: tuple[tuple[int, ...], ...] | None, limit: float) -> np.ndarray:
        """A finite float array of one of ``shapes`` (the first is the canonical one; None: any), |values| <= limit."""
        arr = _float_array(value)
        if arr is None:
            want = "a number" if shapes == ((),) else f"numbers of shape {shapes[0]}" if shapes else "numbers"
            raise self.fail(field, f"expected {want}, got {_show(value)}")
        if shapes is not None and arr.shape not in shapes:
            raise self.fail(field, f"shape {arr.shape} but expected {shapes[0]}")
        if not np.all(np.isfinite(arr)):
            raise self.fail(field, "contains NaN or infinity")
        if arr.size and np.abs(arr).max() > limit:
            raise self.fail(field, f"value {np.abs(arr).max():.3g} is implausible (beyond {limit:.3g})")
        return arr.reshape(shapes[0]) if shapes else arr

    def scalar(self, obj: dict, field: str, default: float, limit: float) -> float:
        """An optional finite number (default if absent)."""
        if field not in obj:
            return default
        return float(self.numbers(obj[field], field, ((),), limit))

    def integer(self, obj: dict, field: str, default: int) -> int:
        """An optional non-negative integer (default if absent)."""
        value = obj.get(field, default)
        if type(value) is float and value.is_integer():
            value = int(value)
        if type(value) is not int or not 0 <= value < LIMITS["frame_index"]:
            raise self.fail(field, f"expected a non-negative integer, got {_show(value)}")
        return value

    def string(self, obj: dict, field: str) -> str:
        value = obj.get(field, "")
        if not isinstance(value, str):
            raise self.fail(field, f"expected a string, got {_show(value)}")
        return value

    def size(self, value: Any, field: str) -> tuple[int, int]:
        ok = (
            isinstance(value, (list, tuple)) and len(value) == 2
            and all(type(v) in (int, float) and 0 < v <= LIMITS["resolution_px"] and float(v).is_integer()
                    for v in value)
        )
        if not ok:
            raise self.fail(field, f"expected two positive integers [width, height], got {_show(value)}")
        return int(value[0]), int(value[1])

    def rotation(self, R: np.ndarray, field: str) -> np.ndarray:
        """R as written if orthonormal to ROTATION_EXACT_TOL; the nearest rotation (noted) up to
        ROTATION_REPAIR_TOL; else refused."""
        err = float(np.abs(R @ R.T - np.eye(3)).max())
        det = float(np.linalg.det(R))
        if err <= ROTATION_EXACT_TOL and abs(det - 1.0) <= ROTATION_EXACT_TOL:
            return R
        if err > ROTATION_REPAIR_TOL or abs(det - 1.0) > 3 * ROTATION_REPAIR_TOL:
            raise self.fail(field, f"not a rotation (|R R^T - I| = {err:.2g}, det = {det:.6g}; "
                            f"accepted up to {ROTATION_REPAIR_TOL:g})")
        U, _, Vt = np.linalg.svd(R)
        self.repaired.append((f"{self.owner} {field}".strip(), err))
        return U @ Vt  # det(U Vt) = +1 here: det(R) is within 3e-5 of 1

    def warn_repaired(self) -> None:
        """One warning per file naming the re-orthonormalised rotations."""
        if not self.repaired:
            return
        names = [o for o, _ in self.repaired]
        shown = ", ".join(names[:4]) + (f", ... ({len(names)} in all)" if len(names) > 4 else "")
        logger.warning("%s: %d rotation(s) orthonormal only to %.2g (%s), as when written with few decimals: replaced "
                       "by the nearest rotation", self.path, len(names), max(e for _, e in self.repaired), shown)

    def camera_matrix(self, K: np.ndarray, field: str) -> np.ndarray:
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise self.fail(field, f"focal length must be positive (fx={K[0, 0]:g}, fy={K[1, 1]:g})")
        if K[0, 1] != 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0, 0, 1]):
            raise self.fail(field, "expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
        return K

    def transform(self, obj: dict, field: str, *, rigid: bool) -> np.ndarray:
        """A 4x4 [R t; 0 0 0 1]; ``rigid``: R a rotation (re-orthonormalised as :meth:`rotation`), else a
        similarity s R with s > 0 (M_world2vga: metres to centimetres)."""
        M = self.array(obj, field, ((4, 4),), LIMITS["transform"])
        if not np.array_equal(M[3], [0, 0, 0, 1]):
            raise self.fail(field, "last row must be [0, 0, 0, 1]")
        if rigid:
            M[:3, :3] = self.rotation(M[:3, :3], field)
            return M
        det = float(np.linalg.det(M[:3, :3]))
        scale = np.cbrt(det) if det > 0 else 0.0
        if not scale > 0 or np.abs(M[:3, :3] @ M[:3, :3].T / scale**2 - np.eye(3)).max() > ROTATION_REPAIR_TOL:
            raise self.fail(field, f"the 3x3 block is not a scaled rotation (det = {det:.6g})")
        return M


def _load_json(path: Path) -> Any:
    """The file's JSON object (one-line errors for invalid JSON or another top level)."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except json.JSONDecodeError as exc:
        raise BundleFormatError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except UnicodeDecodeError:
        raise BundleFormatError(f"{path}: not a UTF-8 text file") from None
    except RecursionError:
        raise BundleFormatError(f"{path}: JSON nested too deeply") from None
    if not isinstance(data, dict):
        raise BundleFormatError(f"{path}: expected a JSON object at the top level, got {type(data).__name__}")
    return data
