"""Read, validate and format the four Panoptic files of a bundle.

Every reading error is a :class:`BundleFormatError` of one line: ``<file>: camera <name>: field '<field>': <what>``.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from dome_calib.bundle import Camera, CameraType, KinectCalibration, KinectSensor, SyncTable
from dome_calib.errors import BundleFormatError
from dome_calib.jsonfmt import dumps

ORTHONORMAL_TOL = 1e-6  # the real files store R with 10 significant digits: |R R^T - I| ~ 1e-10
M_COLOR_CONVENTION = (
    "M_depth = sensor_from_depth and M_color = sensor_from_color (camera coordinates into the sensor frame, "
    "metres); color_from_depth = inv(M_color) @ M_depth; M_world2sensor = sensor_from_kinoptic_world (metres); "
    "M_world2vga = panoptic_world_cm_from_kinoptic_world_m"
)


_TYPE_ORDER = [CameraType.VGA, CameraType.HD, CameraType.KINECT_COLOR]


class _Where:
    """Names the place of a value for error messages: file, camera (or sensor, stream) and field."""

    def __init__(self, path: Path, owner: str = "") -> None:
        self.path, self.owner = path, owner

    def fail(self, field: str, problem: str) -> BundleFormatError:
        owner = f"{self.owner}: " if self.owner else ""
        return BundleFormatError(f"{self.path}: {owner}field '{field}': {problem}")

    def get(self, obj: dict, field: str) -> Any:
        if not isinstance(obj, dict) or field not in obj:
            raise self.fail(field, "missing")
        return obj[field]

    def array(self, obj: dict, field: str, shapes: tuple[tuple[int, ...], ...]) -> np.ndarray:
        """A finite float array of one of the allowed shapes (first shape is the canonical one)."""
        value = self.get(obj, field)
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise self.fail(field, f"expected numbers of shape {shapes[0]}, got {json.dumps(value)[:60]}") from None
        if arr.shape not in shapes:
            raise self.fail(field, f"shape {arr.shape} but expected {shapes[0]}")
        if not np.all(np.isfinite(arr)):
            raise self.fail(field, "contains NaN or infinity")
        return arr.reshape(shapes[0])

    def size(self, value: Any, field: str) -> tuple[int, int]:
        ok = (
            isinstance(value, (list, tuple)) and len(value) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and float(v).is_integer() and v > 0 for v in value)
        )
        if not ok:
            raise self.fail(field, f"expected two positive integers [width, height], got {json.dumps(value)[:60]}")
        return int(value[0]), int(value[1])

    def rotation(self, R: np.ndarray, field: str) -> np.ndarray:
        err = np.abs(R @ R.T - np.eye(3)).max()
        if err > ORTHONORMAL_TOL or abs(np.linalg.det(R) - 1.0) > ORTHONORMAL_TOL:
            raise self.fail(field, f"not a rotation (|R R^T - I| = {err:.2g}, det = {np.linalg.det(R):.6g})")
        return R

    def camera_matrix(self, K: np.ndarray, field: str) -> np.ndarray:
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise self.fail(field, f"focal length must be positive (fx={K[0, 0]:g}, fy={K[1, 1]:g})")
        if K[0, 1] != 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0, 0, 1]):
            raise self.fail(field, "expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
        return K

    def transform(self, obj: dict, field: str) -> np.ndarray:
        M = self.array(obj, field, ((4, 4),))
        if not np.array_equal(M[3], [0, 0, 0, 1]):
            raise self.fail(field, "last row must be [0, 0, 0, 1]")
        return M


def _load_json(path: Path) -> Any:
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except json.JSONDecodeError as exc:
        raise BundleFormatError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None


def read_calibration(path: Path) -> tuple[dict[str, Camera], str]:
    """``calibration_<seq>.json`` -> (cameras keyed by name, calibDataSource)."""
    data = _load_json(path)
    top = _Where(path)
    entries = top.get(data, "cameras")
    if not isinstance(entries, list):
        raise top.fail("cameras", "expected a list of cameras")
    cameras: dict[str, Camera] = {}
    for i, entry in enumerate(entries):
        name = entry.get("name") if isinstance(entry, dict) else None
        where = _Where(path, f"camera {name}" if isinstance(name, str) else f"camera #{i}")
        if not isinstance(name, str) or not name:
            raise where.fail("name", "missing or not a string")
        if name in cameras:
            raise where.fail("name", "duplicate camera name")
        try:
            cam_type = CameraType(where.get(entry, "type"))
        except ValueError:
            raise where.fail("type", f"unknown camera type {entry['type']!r} (expected vga, hd or kinect-color)") from None
        cameras[name] = Camera(
            name=name,
            type=cam_type,
            resolution=where.size(where.get(entry, "resolution"), "resolution"),
            K=where.camera_matrix(where.array(entry, "K", ((3, 3),)), "K"),
            dist=where.array(entry, "distCoef", ((5,), (5, 1), (1, 5))),
            R=where.rotation(where.array(entry, "R", ((3, 3),)), "R"),
            t_cm=where.array(entry, "t", ((3,), (3, 1), (1, 3))),
            panel=int(entry.get("panel", 0)),
            node=int(entry.get("node", 0)),
        )
    return cameras, str(data.get("calibDataSource", ""))


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
    """``kcalibration_<seq>.json`` -> :class:`KinectCalibration`. Sensors are named KINECTNODE1.. in file order."""
    data = _load_json(path)
    top = _Where(path)
    entries = top.get(data, "sensors")
    if not isinstance(entries, list):
        raise top.fail("sensors", "expected a list of sensors")
    convention = data.get("convention")
    if convention is not None and convention != M_COLOR_CONVENTION:
        raise top.fail("convention", f"unknown convention {convention!r}; this toolkit reads {M_COLOR_CONVENTION!r}")
    known = {"K_depth", "distCoeffs_depth", "depth_width", "depth_height", "K_color", "distCoeffs_color", "color_width",
             "color_height", "M_depth", "M_color", "M_world2sensor", "color_time_offset", "depth_time_offset",
             "depth_bias_mm", "depth_scale", "name"}
    sensors: dict[str, KinectSensor] = {}
    for i, entry in enumerate(entries):
        name = entry.get("name", f"KINECTNODE{i + 1}") if isinstance(entry, dict) else f"KINECTNODE{i + 1}"
        w = _Where(path, f"sensor {name}")
        dist_depth = np.asarray(w.get(entry, "distCoeffs_depth"), dtype=float).ravel()
        if dist_depth.size < 5 or not np.all(np.isfinite(dist_depth)):
            raise w.fail("distCoeffs_depth", f"expected at least 5 finite numbers, got {dist_depth.size}")
        sensors[name] = KinectSensor(
            name=name,
            K_depth=w.camera_matrix(w.array(entry, "K_depth", ((3, 3),)), "K_depth"),
            dist_depth=dist_depth[:5],
            depth_size=w.size([w.get(entry, "depth_width"), w.get(entry, "depth_height")], "depth_width/depth_height"),
            K_color=w.camera_matrix(w.array(entry, "K_color", ((3, 3),)), "K_color"),
            dist_color=w.array(entry, "distCoeffs_color", ((5,), (5, 1), (1, 5))),
            color_size=w.size([w.get(entry, "color_width"), w.get(entry, "color_height")], "color_width/color_height"),
            M_depth=w.transform(entry, "M_depth"),
            M_color=w.transform(entry, "M_color"),
            M_world2sensor=w.transform(entry, "M_world2sensor"),
            color_time_offset_ms=float(entry.get("color_time_offset", 0.0)),
            depth_time_offset_ms=float(entry.get("depth_time_offset", 0.0)),
            depth_bias_mm=float(entry.get("depth_bias_mm", 0.0)),
            depth_scale=float(entry.get("depth_scale", 0.0)),
            extra={k: v for k, v in entry.items() if k not in known}
            | ({"distCoeffs_depth_tail": dist_depth[5:].tolist()} if dist_depth.size > 5 else {}),
        )
        for field in ("M_depth", "M_color"):
            w.rotation(getattr(sensors[name], field)[:3, :3], field)
    return KinectCalibration(
        sensors=sensors,
        M_world2vga=top.transform(data, "M_world2vga"),
        calib_data_source=str(data.get("calibDataSource", "")),
        panoptic_calib_data_source=str(data.get("panopticCalibDataSource", "")),
    )


def format_kcalibration(kinect: KinectCalibration) -> str:
    """:class:`KinectCalibration` -> text of ``kcalibration_<seq>.json`` (Panoptic layout plus our convention)."""
    sensors = []
    for name, s in kinect.sensors.items():
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


def _read_table(w: _Where, obj: Any, stream: str) -> SyncTable:
    if not isinstance(obj, dict):
        raise w.fail(stream, "expected an object with 'index' and 'univ_time'")
    index = np.asarray(w.get(obj, "index"), dtype=float).ravel()
    times = np.asarray(w.get(obj, "univ_time"), dtype=float).ravel()
    if index.shape != times.shape:
        raise w.fail(f"{stream}.univ_time", f"{times.size} times for {index.size} indices (lengths differ)")
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(index))):
        raise w.fail(f"{stream}.univ_time", "contains NaN or infinity")
    if np.any(index != np.round(index)) or np.any(np.diff(index) <= 0):
        raise w.fail(f"{stream}.index", "frame indices must be increasing integers")
    if np.any(np.diff(times) <= 0):
        bad = int(np.argmax(np.diff(times) <= 0))
        raise w.fail(f"{stream}.univ_time", f"time does not increase at frame index {int(index[bad + 1])}")
    return SyncTable(index=index.astype(np.int64), univ_time_ms=times)


def read_synctables(path: Path) -> dict[str, SyncTable]:
    """``synctables_<seq>.json`` -> {"vga": table, "hd": table} (univ_time in ms)."""
    data = _load_json(path)
    w = _Where(path)
    if not isinstance(data, dict) or not data:
        raise w.fail("vga/hd", "expected an object with sync streams")
    return {stream: _read_table(w, obj, stream) for stream, obj in data.items()}


def read_ksynctables(path: Path) -> tuple[dict[str, SyncTable], dict[str, SyncTable]]:
    """``ksynctables_<seq>.json`` -> (colour tables, depth tables), each keyed by "KINECTNODE<n>"."""
    data = _load_json(path)
    w = _Where(path)
    kinect = w.get(data, "kinect")
    out = []
    for kind in ("color", "depth"):
        streams = w.get(kinect, kind)
        if not isinstance(streams, dict):
            raise w.fail(f"kinect.{kind}", "expected an object keyed by KINECTNODE<n>")
        out.append({node: _read_table(w, obj, f"kinect.{kind}.{node}") for node, obj in streams.items()})
    return out[0], out[1]


def _table_json(table: SyncTable) -> dict:
    return {"index": table.index.astype(int).tolist(), "univ_time": table.univ_time_ms}


def format_synctables(streams: dict[str, SyncTable]) -> str:
    return dumps({name: _table_json(t) for name, t in streams.items()}) + "\n"


def format_ksynctables(color: dict[str, SyncTable], depth: dict[str, SyncTable]) -> str:
    return dumps({"kinect": {
        "color": {n: _table_json(t) for n, t in color.items()},
        "depth": {n: _table_json(t) for n, t in depth.items()},
    }}) + "\n"
