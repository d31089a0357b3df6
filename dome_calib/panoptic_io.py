"""Read, validate and format the four Panoptic files of a bundle.

Every reading error is a :class:`BundleFormatError` of one line: ``<file>: camera <name>: field '<field>': <what>``.
Every field is checked before use: JSON numbers only (no strings, booleans or null where numbers belong), the
expected shape, finite and within a plausible range (``LIMITS``), rotations orthonormal with det 1.

Stated leniencies (each logged once per file as a warning):

- a rotation orthonormal only to ``ROTATION_REPAIR_TOL`` (written with ~6 decimals by another tool) is replaced
  by the nearest rotation (SVD); beyond that it is refused; up to ``ROTATION_EXACT_TOL`` it is kept bit for bit;
- a ``kcalibration`` without ``"convention"`` (the Panoptic toolbox writes none) is read with this toolkit's.
"""
from __future__ import annotations

import json
import logging
import re
from pathlib import Path
from typing import Any

import numpy as np

from dome_calib.bundle import Camera, CameraType, KinectCalibration, KinectSensor, SyncTable
from dome_calib.errors import BundleFormatError
from dome_calib.jsonfmt import dumps

logger = logging.getLogger(__name__)

#: |R R^T - I| up to this is kept as written (the real files store 10 significant digits: ~1e-10).
ROTATION_EXACT_TOL = 1e-8
#: |R R^T - I| up to this is re-orthonormalised with a warning (6 decimals give ~1e-6); beyond: refused.
ROTATION_REPAIR_TOL = 1e-5
#: Largest plausible magnitude per field (beyond it a value is a unit mix-up or garbage, not a calibration).
LIMITS = {
    "t_cm": 1e6,  # 10 km
    "K_px": 1e6,  # focal length and principal point
    "dist": 1e6,  # distortion coefficients
    "transform": 1e6,  # entries of the Kinect 4x4 transforms (m, or cm for M_world2vga)
    "time_offset_ms": 86_400_000.0,  # one day
    "depth_bias_mm": 1e4,
    "depth_scale": 0.5,  # relative: measured = true * (1 + depth_scale) + bias
    "resolution_px": 100_000,
    "frame_index": 2**53,  # exact in a float
}
KINECT_NODE = re.compile(r"KINECTNODE[1-9][0-9]*")
M_COLOR_CONVENTION = (
    "M_depth = sensor_from_depth and M_color = sensor_from_color (camera coordinates into the sensor frame, "
    "metres); color_from_depth = inv(M_color) @ M_depth; M_world2sensor = sensor_from_kinoptic_world (metres); "
    "M_world2vga = panoptic_world_cm_from_kinoptic_world_m"
)


_TYPE_ORDER = [CameraType.VGA, CameraType.HD, CameraType.KINECT_COLOR]


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


def read_calibration(path: Path) -> tuple[dict[str, Camera], str]:
    """``calibration_<seq>.json`` -> (cameras keyed by name, calibDataSource)."""
    data = _load_json(path)
    top = _Where(path)
    entries = top.get(data, "cameras")
    if not isinstance(entries, list) or not entries:
        raise top.fail("cameras", "expected a non-empty list of cameras")
    cameras: dict[str, Camera] = {}
    for i, entry in enumerate(entries):
        name = entry.get("name") if isinstance(entry, dict) else None
        where = top.at(f"camera {_label(name)}" if isinstance(name, str) and name else f"camera #{i}")
        if not isinstance(entry, dict):
            raise where.fail("cameras", f"expected an object, got {_show(entry)}")
        if not isinstance(name, str) or not name:
            problem = f"expected a non-empty string, got {_show(name)}" if "name" in entry else "missing"
            raise where.fail("name", problem)
        if name in cameras:
            raise where.fail("name", "duplicate camera name")
        cam_type = where.get(entry, "type")
        if not isinstance(cam_type, str) or cam_type not in {str(t) for t in CameraType}:
            shown = _label(repr(cam_type)) if isinstance(cam_type, str) else _show(cam_type)
            raise where.fail("type", f"unknown camera type {shown} (expected vga, hd or kinect-color)")
        cameras[name] = Camera(
            name=name,
            type=CameraType(cam_type),
            resolution=where.size(where.get(entry, "resolution"), "resolution"),
            K=where.camera_matrix(where.array(entry, "K", ((3, 3),), LIMITS["K_px"]), "K"),
            dist=where.array(entry, "distCoef", ((5,), (5, 1), (1, 5)), LIMITS["dist"]),
            R=where.rotation(where.array(entry, "R", ((3, 3),), 2.0), "R"),
            t_cm=where.array(entry, "t", ((3,), (3, 1), (1, 3)), LIMITS["t_cm"]),
            panel=where.integer(entry, "panel", 0),
            node=where.integer(entry, "node", 0),
        )
    top.warn_repaired()
    return cameras, top.string(data, "calibDataSource")


def panoptic_order(cameras: dict[str, Camera]) -> dict[str, Camera]:
    """The cameras in the Panoptic files' order: VGA, HD, Kinect colour, each by name."""
    return {c.name: c for c in sorted(cameras.values(), key=lambda c: (_TYPE_ORDER.index(c.type), c.name))}


def format_calibration(cameras: dict[str, Camera], calib_data_source: str) -> str:
    """Cameras -> text of ``calibration_<seq>.json`` in the Panoptic layout, in the order given (a calibration
    writes :func:`panoptic_order`; an imported bundle keeps its source's order, which some tools pair with their
    data by position)."""
    entries = [
        {
            "name": c.name, "type": str(c.type), "resolution": list(c.resolution), "panel": c.panel, "node": c.node,
            "K": c.K, "distCoef": c.dist, "R": c.R, "t": c.t_cm.reshape(3, 1),
        }
        for c in cameras.values()
    ]
    return dumps({"calibDataSource": calib_data_source, "cameras": entries}) + "\n"


_SENSOR_KEYS = {"K_depth", "distCoeffs_depth", "depth_width", "depth_height", "K_color", "distCoeffs_color",
                "color_width", "color_height", "M_depth", "M_color", "M_world2sensor", "color_time_offset",
                "depth_time_offset", "depth_bias_mm", "depth_scale", "name"}


def _read_sensor(w: _Where, entry: dict, name: str) -> KinectSensor:
    dist_depth = w.numbers(w.get(entry, "distCoeffs_depth"), "distCoeffs_depth", None, LIMITS["dist"]).ravel()
    if dist_depth.size < 5:
        raise w.fail("distCoeffs_depth", f"expected at least 5 numbers, got {dist_depth.size}")
    return KinectSensor(
        name=name,
        K_depth=w.camera_matrix(w.array(entry, "K_depth", ((3, 3),), LIMITS["K_px"]), "K_depth"),
        dist_depth=dist_depth[:5],
        depth_size=w.size([w.get(entry, "depth_width"), w.get(entry, "depth_height")], "depth_width/depth_height"),
        K_color=w.camera_matrix(w.array(entry, "K_color", ((3, 3),), LIMITS["K_px"]), "K_color"),
        dist_color=w.array(entry, "distCoeffs_color", ((5,), (5, 1), (1, 5)), LIMITS["dist"]),
        color_size=w.size([w.get(entry, "color_width"), w.get(entry, "color_height")], "color_width/color_height"),
        M_depth=w.transform(entry, "M_depth", rigid=True),
        M_color=w.transform(entry, "M_color", rigid=True),
        M_world2sensor=w.transform(entry, "M_world2sensor", rigid=True),
        color_time_offset_ms=w.scalar(entry, "color_time_offset", 0.0, LIMITS["time_offset_ms"]),
        depth_time_offset_ms=w.scalar(entry, "depth_time_offset", 0.0, LIMITS["time_offset_ms"]),
        depth_bias_mm=w.scalar(entry, "depth_bias_mm", 0.0, LIMITS["depth_bias_mm"]),
        depth_scale=w.scalar(entry, "depth_scale", 0.0, LIMITS["depth_scale"]),
        extra={k: v for k, v in entry.items() if k not in _SENSOR_KEYS}
        | ({"distCoeffs_depth_tail": dist_depth[5:].tolist()} if dist_depth.size > 5 else {}),
    )


def read_kcalibration(path: Path) -> KinectCalibration:
    """``kcalibration_<seq>.json`` -> :class:`KinectCalibration`. Sensors are named by their ``name`` field, else
    KINECTNODE1.. in file order. A file without ``"convention"`` is read with ours (one warning)."""
    data = _load_json(path)
    top = _Where(path)
    entries = top.get(data, "sensors")
    if not isinstance(entries, list) or not entries:
        raise top.fail("sensors", "expected a non-empty list of sensors")
    if "convention" in data and data["convention"] != M_COLOR_CONVENTION:
        raise top.fail("convention", f"unknown convention {_show(data['convention'])}; this toolkit reads "
                       f"{M_COLOR_CONVENTION!r}")
    sensors: dict[str, KinectSensor] = {}
    for i, entry in enumerate(entries):
        name = entry.get("name", f"KINECTNODE{i + 1}") if isinstance(entry, dict) else f"KINECTNODE{i + 1}"
        w = top.at(f"sensor {_label(name)}" if isinstance(name, str) else f"sensor #{i}")
        if not isinstance(entry, dict):
            raise w.fail("sensors", f"expected an object, got {_show(entry)}")
        if not isinstance(name, str) or not KINECT_NODE.fullmatch(name):
            raise w.fail("name", f"expected KINECTNODE<n>, got {_show(name)}")
        if name in sensors:
            raise w.fail("name", "duplicate sensor name")
        sensors[name] = _read_sensor(w, entry, name)
    kinect = KinectCalibration(
        sensors=sensors,
        M_world2vga=top.transform(data, "M_world2vga", rigid=False),
        calib_data_source=top.string(data, "calibDataSource"),
        panoptic_calib_data_source=top.string(data, "panopticCalibDataSource"),
    )
    top.warn_repaired()
    if "convention" not in data:
        logger.warning("%s: no 'convention' field (as in the Panoptic toolbox's files): read with this toolkit's, "
                       "M_depth = sensor_from_depth and M_color = sensor_from_color", path)
    return kinect


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


def _read_table(w: _Where, obj: Any, stream: str) -> SyncTable:
    if not isinstance(obj, dict):
        raise w.fail(stream, f"expected an object with 'index' and 'univ_time', got {_show(obj)}")
    index = w.numbers(w.get(obj, "index"), f"{stream}.index", None, LIMITS["frame_index"])
    times = w.numbers(w.get(obj, "univ_time"), f"{stream}.univ_time", None, np.inf)
    if index.ndim != 1 or index.size == 0:
        raise w.fail(f"{stream}.index", f"expected a non-empty list of frame indices, got shape {index.shape}")
    if times.shape != index.shape:
        raise w.fail(f"{stream}.univ_time", f"{times.size} times for {index.size} indices (shape {times.shape}; "
                     "expected one time per index)")
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
    if not data:
        raise w.fail("vga/hd", "expected an object with sync streams")
    return {stream: _read_table(w, obj, _label(stream)) for stream, obj in data.items()}


def read_ksynctables(path: Path) -> tuple[dict[str, SyncTable], dict[str, SyncTable]]:
    """``ksynctables_<seq>.json`` -> (colour tables, depth tables), each keyed by "KINECTNODE<n>"."""
    data = _load_json(path)
    w = _Where(path)
    kinect = w.get(data, "kinect")
    if not isinstance(kinect, dict):
        raise w.fail("kinect", f"expected an object with 'color' and 'depth', got {_show(kinect)}")
    out = []
    for kind in ("color", "depth"):
        streams = w.get(kinect, kind) if kind in kinect else w.get({}, f"kinect.{kind}")
        if not isinstance(streams, dict):
            raise w.fail(f"kinect.{kind}", "expected an object keyed by KINECTNODE<n>")
        for node in streams:
            if not KINECT_NODE.fullmatch(node):
                raise w.fail(f"kinect.{kind}", f"stream {_show(node)} is not named KINECTNODE<n>")
        out.append({node: _read_table(w, obj, f"kinect.{kind}.{node}") for node, obj in streams.items()})
    return out[0], out[1]


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
