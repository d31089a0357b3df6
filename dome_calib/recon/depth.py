"""Kinect depth to world: the depth frames of all Kinects nearest to a universal time as one tagged point cloud.

Per sensor: depth pixel (u, v) with measured depth d (uint16 mm, 0 = no reading) ->
true depth ``z = (d - depth_bias_mm) / (1 + depth_scale)`` (inverting ``KinectSensor``'s model
``measured = true * (1 + depth_scale) + depth_bias_mm``) -> depth-camera point ``z * [x, y, 1]`` with
``(x, y) = pixels_to_normalized(uv, K_depth, dist_depth)`` (Kinect depth is the z coordinate, not the ray
length) -> colour camera (``KinectSensor.color_from_depth``, metres) -> world (the dome bundle's ``50_xx``
camera, cm). Every point is tagged with its sensor and with ``frame_time - requested_time`` (ms).

Depth folder layout (as written by the Kinect generator): ``FOLDER/KINECTNODE<n>/depth_<k>.png``, 16-bit PNG in
millimetres, ``k`` = the frame's index in the bundle's ``ksynctables`` depth table (any zero padding).
"""
from __future__ import annotations

import functools
import logging
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dome_calib.bundle import Bundle, KinectSensor
from dome_calib.camera import pixels_to_normalized
from dome_calib.ownership import replace_file
from dome_calib.recon.errors import ReconError
from dome_calib.recon.project import depth_from_world, kinect_sensor

logger = logging.getLogger(__name__)

MM_PER_CM = 10.0
_DEPTH_FILE_RE = re.compile(r"^depth_(\d+)\.png$")
PLY_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("sensor", "u1"), ("time_offset_ms", "<f4")])


@dataclass(frozen=True)
class PointCloud:
    """World points (N, 3) cm (Panoptic frame); sensor (N,) index into ``sensors``; time_offset_ms (N,)
    = depth frame time - requested universal time."""

    xyz_cm: np.ndarray
    sensor: np.ndarray
    time_offset_ms: np.ndarray
    sensors: list[str]


@functools.lru_cache(maxsize=16)
def _rays_cached(key: tuple) -> np.ndarray:
    fx, fy, cx, cy, *dist, w, h = key
    v, u = np.mgrid[0:h, 0:w]
    uv = np.stack([u, v], axis=-1).reshape(-1, 2).astype(float)
    return pixels_to_normalized(uv, np.array([fx, fy, cx, cy]), np.array(dist)).reshape(h, w, 2)


def depth_rays(sensor: KinectSensor) -> np.ndarray:
    """(H, W, 2) undistorted normalised coordinates of every depth pixel (cached per calibration)."""
    K = sensor.K_depth
    return _rays_cached((K[0, 0], K[1, 1], K[0, 2], K[1, 2], *map(float, sensor.dist_depth), *sensor.depth_size))


def correct_depth_mm(sensor: KinectSensor, measured_mm: np.ndarray) -> np.ndarray:
    """Measured depth (mm) -> true depth (mm), inverting ``measured = true * (1 + depth_scale) + depth_bias_mm``."""
    return (np.asarray(measured_mm, dtype=float) - sensor.depth_bias_mm) / (1.0 + sensor.depth_scale)


def depth_to_world(bundle: Bundle, node: str, depth_mm: np.ndarray, *, correct_bias: bool = True) -> np.ndarray:
    """One depth frame (H, W) uint16 mm of Kinect ``node`` -> (N, 3) world points (cm) of its valid pixels.

    Example:
        >>> pts = depth_to_world(bundle, "KINECTNODE1", cv2.imread("depth_0001.png", cv2.IMREAD_UNCHANGED))
    """
    sensor = kinect_sensor(bundle, node)
    w, h = sensor.depth_size
    depth = np.asarray(depth_mm)
    if depth.shape != (h, w):
        raise ReconError(f"{node}: depth frame has shape {depth.shape} but the calibration says {h} x {w} "
                         f"(rows x cols)")
    valid = depth > 0
    z_mm = correct_depth_mm(sensor, depth[valid]) if correct_bias else depth[valid].astype(float)
    rays = depth_rays(sensor)[valid]
    z_cm = z_mm / MM_PER_CM
    X_depth_cm = np.column_stack([rays * z_cm[:, None], z_cm])
    R, t = depth_from_world(bundle, node)
    return (X_depth_cm - t) @ R  # R^T (x - t) for row vectors


@dataclass(frozen=True)
class DepthFolder:
    """A folder of Kinect depth frames, ``ROOT/KINECTNODE<n>/depth_<k>.png`` (16-bit PNG, millimetres, 0 = no
    reading; ``k`` the frame's index in the depth sync table, any zero padding), indexed once. ``folder(node, k)``
    reads one frame (None if there is none); a file that is not a 16-bit single-channel PNG is a ReconError naming
    it. Picklable: a long run's chunks read their own frames."""

    root: Path
    index: dict[str, dict[int, Path]]

    @property
    def nodes(self) -> list[str]:
        return sorted(self.index, key=lambda n: (len(n), n))

    def __call__(self, node: str, k: int) -> np.ndarray | None:
        path = self.index.get(node, {}).get(int(k))
        if path is None:
            return None
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint16 or image.ndim != 2:
            raise ReconError(f"{path}: not a 16-bit single-channel depth PNG (millimetres)")
        return image


def depth_folder_reader(folder: str | Path) -> DepthFolder:
    """The :class:`DepthFolder` of ``FOLDER/KINECTNODE<n>/depth_<k>.png``: ``read(node, k)`` -> uint16 array or
    None; ReconError if the folder is missing or holds no depth frame."""
    root = Path(folder)
    if not root.is_dir():
        raise ReconError(f"{root}: depth folder not found (expected {root}/KINECTNODE<n>/depth_<k>.png)")
    index: dict[str, dict[int, Path]] = {}
    for sub in sorted(p for p in root.iterdir() if p.is_dir()):
        files = {int(m.group(1)): f for f in sub.iterdir() if (m := _DEPTH_FILE_RE.match(f.name))}
        if files:
            index[sub.name] = files
    if not index:
        raise ReconError(f"{root}: no depth frames (expected {root}/KINECTNODE<n>/depth_<k>.png)")
    return DepthFolder(root=root, index=index)


def pointcloud_at(bundle: Bundle, univ_time_ms: float, read_frame: Callable[[str, int], np.ndarray | None], *,
                  nodes: list[str] | None = None, max_offset_ms: float | None = None,
                  correct_bias: bool = True, progress: Callable[[int, int], None] | None = None) -> PointCloud:
    """Merge the depth frames of all Kinects nearest to a universal time into one world point cloud.

    Args:
        read_frame: ``(node, frame_index) -> (H, W) uint16 mm or None`` (see :func:`depth_folder_reader`).
        nodes: sensors to use; default every sensor with a depth sync table and a calibration.
        max_offset_ms: skip sensors whose nearest frame is further than this from the time.
        progress: called with (sensors done, sensors) after each sensor.
    Raises:
        ReconError if the bundle lacks depth sync tables or Kinect calibration, or no sensor has a frame.
    """
    if bundle.sync is None or not bundle.sync.kinect_depth:
        raise ReconError(f"bundle {bundle.seq}: no Kinect depth sync tables (ksynctables_{bundle.seq}.json, "
                         f"kinect.depth)")
    tables = bundle.sync.kinect_depth
    if nodes is None:
        known = bundle.kinect.sensors if bundle.kinect is not None else {}
        nodes = sorted((n for n in tables if n in known), key=lambda n: (len(n), n))
    points, sensor_ids, offsets, names, skipped = [], [], [], [], []
    for done, node in enumerate(nodes, start=1):
        if progress is not None and done > 1:
            progress(done - 1, len(nodes))
        if node not in tables:
            raise ReconError(f"bundle {bundle.seq}: no depth sync table for {node}")
        table = tables[node]
        k, dt = table.nearest(univ_time_ms)
        k, dt = int(k), float(dt)
        if univ_time_ms < table.univ_time_ms[0] or univ_time_ms > table.univ_time_ms[-1]:
            skipped.append(f"{node}: time outside its depth stream ({table.univ_time_ms[0]:.1f}.."
                           f"{table.univ_time_ms[-1]:.1f} ms)")
            continue
        if max_offset_ms is not None and abs(dt) > max_offset_ms:
            skipped.append(f"{node}: nearest depth frame {k} is {dt:+.1f} ms away")
            continue
        frame = read_frame(node, k)
        if frame is None:
            skipped.append(f"{node}: depth frame {k} missing")
            continue
        xyz = depth_to_world(bundle, node, frame, correct_bias=correct_bias)
        points.append(xyz)
        sensor_ids.append(np.full(len(xyz), len(names), dtype=np.uint8))
        offsets.append(np.full(len(xyz), dt, dtype=np.float32))
        names.append(node)
        logger.debug("%s: frame %d (%+.1f ms), %d points", node, k, dt, len(xyz))
    if progress is not None:
        progress(len(nodes), len(nodes))
    if not names:
        first = skipped[0] if skipped else "no sensors"
        raise ReconError(f"no Kinect depth frame near {univ_time_ms} ms in {len(nodes)} sensors (first: {first})")
    for reason in skipped:
        logger.warning("%s; skipped", reason)
    return PointCloud(xyz_cm=np.concatenate(points), sensor=np.concatenate(sensor_ids),
                      time_offset_ms=np.concatenate(offsets), sensors=names)


def write_ply(path: str | Path, cloud: PointCloud) -> Path:
    """Write a binary little-endian PLY (x, y, z float cm; sensor uchar; time_offset_ms float), atomically, where
    :mod:`dome_calib.ownership` allows (nothing there, or a file dome-calib wrote, unchanged)."""
    data = np.empty(len(cloud.xyz_cm), dtype=PLY_DTYPE)
    data["x"], data["y"], data["z"] = cloud.xyz_cm[:, 0], cloud.xyz_cm[:, 1], cloud.xyz_cm[:, 2]
    data["sensor"], data["time_offset_ms"] = cloud.sensor, cloud.time_offset_ms
    comments = ["dome-calib Kinect point cloud, Panoptic world frame (cm, y down)"]
    comments += [f"sensor {i} {name}" for i, name in enumerate(cloud.sensors)]
    header = "ply\nformat binary_little_endian 1.0\n" + "".join(f"comment {c}\n" for c in comments)
    header += f"element vertex {len(data)}\n"
    header += "".join(f"property {t} {n}\n" for n, t in (("x", "float"), ("y", "float"), ("z", "float"),
                                                          ("sensor", "uchar"), ("time_offset_ms", "float")))
    header += "end_header\n"
    path = Path(path)
    with replace_file(path) as tmp, open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(data.tobytes())
    return path


def read_ply(path: str | Path) -> PointCloud:
    """Read a PLY written by :func:`write_ply` (this layout only)."""
    raw = Path(path).read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply\n") or end < 0:
        raise ReconError(f"{path}: not a PLY file")
    lines = raw[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise ReconError(f"{path}: only binary little-endian PLY is read")
    n = next(int(line.split()[2]) for line in lines if line.startswith("element vertex"))
    sensors = [line.split()[3] for line in lines if line.startswith("comment sensor ")]
    data = np.frombuffer(raw, dtype=PLY_DTYPE, count=n, offset=end + len(b"end_header\n"))
    xyz = np.column_stack([data["x"], data["y"], data["z"]]).astype(float)
    return PointCloud(xyz_cm=xyz, sensor=data["sensor"].copy(), time_offset_ms=data["time_offset_ms"].copy(),
                      sensors=sensors)
