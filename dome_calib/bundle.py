"""The calibration-and-sync bundle as typed objects keyed by camera name (no file access here).

On disk a bundle is one folder of Panoptic-format files: :mod:`dome_calib.panoptic_io` reads and formats each
file, :mod:`dome_calib.bundle_io` loads and writes the folder (``load_bundle`` / ``write_bundle``, also exported
as ``dome_calib.load_bundle`` / ``dome_calib.write_bundle``).

Conventions: world = Panoptic frame (origin at the floor centre, y down, cm); ``x_cam = R @ X_world + t_cm``.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from dome_calib.camera import K_to_intr


class CameraType(StrEnum):
    VGA = "vga"
    HD = "hd"
    KINECT_COLOR = "kinect-color"


#: A Panoptic camera name: VGA ``01_01``..``20_24`` (panel_camera), HD ``00_00``..``00_30``, Kinect colour
#: ``50_01``..``50_10``.
CAMERA_NAME = re.compile(r"(?:(?:0[1-9]|1\d|20)_(?:0[1-9]|1\d|2[0-4]))|(?:00_(?:[0-2]\d|30))|(?:50_(?:0[1-9]|10))")
CAMERA_NAMES_HELP = "VGA 01_01..20_24 (panel_camera), HD 00_00..00_30, Kinect colour 50_01..50_10"


#: A Kinect sensor's node name, ``KINECTNODE1``..``KINECTNODE10``; its colour camera is ``50_<nn>``.
KINECT_NODE_NAME = re.compile(r"KINECTNODE([1-9]|10)")


def kinect_node_camera(node: str) -> str | None:
    """``KINECTNODE3`` -> ``50_03`` (its colour camera); None when ``node`` is not a Kinect node name."""
    match = KINECT_NODE_NAME.fullmatch(node)
    return f"50_{int(match.group(1)):02d}" if match else None


def is_camera_name(name: str) -> bool:
    """Whether ``name`` is a Panoptic camera name (:data:`CAMERA_NAME`)."""
    return CAMERA_NAME.fullmatch(name) is not None


def camera_type_from_name(name: str) -> CameraType:
    """Camera type from a Panoptic name: ``00_*`` HD, ``50_*`` Kinect colour, anything else VGA."""
    prefix = name.split("_", 1)[0]
    return CameraType.HD if prefix == "00" else CameraType.KINECT_COLOR if prefix == "50" else CameraType.VGA


#: Nominal resolution (width, height) px per camera type.
NOMINAL_RESOLUTION = {CameraType.VGA: (640, 480), CameraType.HD: (1920, 1080), CameraType.KINECT_COLOR: (1920, 1080)}


@dataclass(kw_only=True)
class Camera:
    """One calibrated camera. ``R`` (3, 3) and ``t_cm`` (3,) map world to camera: x_cam = R @ X + t_cm."""

    name: str
    type: CameraType
    resolution: tuple[int, int]  # (width_px, height_px)
    K: np.ndarray  # (3, 3) px, zero skew
    dist: np.ndarray  # (5,) [k1, k2, p1, p2, k3]
    R: np.ndarray  # (3, 3) cam_from_world rotation
    t_cm: np.ndarray  # (3,) cam_from_world translation, cm
    panel: int
    node: int

    @property
    def intr(self) -> np.ndarray:
        """(4,) [fx, fy, cx, cy] px."""
        return K_to_intr(self.K)

    @property
    def center_cm(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, cm."""
        return -self.R.T @ self.t_cm

    @property
    def cam_from_world(self) -> np.ndarray:
        """(4, 4) homogeneous transform, translation in cm."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t_cm
        return T


@dataclass(kw_only=True)
class KinectSensor:
    """Depth-colour calibration of one Kinect v2 (Panoptic ``kcalibration`` layout, metres).

    Convention (this project's, written into every file as ``"convention"``): ``M_depth`` and ``M_color`` map
    camera coordinates INTO the sensor frame, i.e. ``M_depth = sensor_from_depth`` and
    ``M_color = sensor_from_color`` (the reading of the official MATLAB demo, ``T_kinectColor2KinectLocal =
    M_color``). Hence ``color_from_depth = inv(M_color) @ M_depth``. ``M_world2sensor`` maps the Kinoptic
    world (metres) into the sensor frame.
    """

    name: str  # "KINECTNODE1" .. "KINECTNODE10"
    K_depth: np.ndarray
    dist_depth: np.ndarray  # (5,) [k1, k2, p1, p2, k3]
    depth_size: tuple[int, int]  # (width_px, height_px)
    K_color: np.ndarray
    dist_color: np.ndarray  # (5,)
    color_size: tuple[int, int]
    M_depth: np.ndarray  # (4, 4) sensor_from_depth, metres
    M_color: np.ndarray  # (4, 4) sensor_from_color, metres
    M_world2sensor: np.ndarray  # (4, 4) sensor_from_kinoptic_world, metres
    color_time_offset_ms: float = 0.0
    depth_time_offset_ms: float = 0.0
    depth_bias_mm: float = 0.0  # measured = true * (1 + depth_scale) + depth_bias_mm; correct by inverting
    depth_scale: float = 0.0
    extra: dict = field(default_factory=dict)  # other keys of the file, kept verbatim (domeCenter, ...)

    @property
    def color_from_depth(self) -> np.ndarray:
        """(4, 4) depth-camera coordinates -> colour-camera coordinates, metres."""
        return np.linalg.inv(self.M_color) @ self.M_depth


@dataclass(kw_only=True)
class KinectCalibration:
    """All Kinect sensors of a session plus the Kinoptic-to-Panoptic world transform ``M_world2vga`` (m -> cm)."""

    sensors: dict[str, KinectSensor]
    M_world2vga: np.ndarray  # (4, 4) panoptic_world_cm_from_kinoptic_world_m
    calib_data_source: str = ""
    panoptic_calib_data_source: str = ""


#: A universal time this close to a frame's time IS that frame's time (ms; half a microsecond: far below the sync's
#: own accuracy, far above the float rounding of ms times on a day-long timeline, ~1e-8 ms).
FRAME_TIME_TOLERANCE_MS = 5e-4


@dataclass(kw_only=True)
class SyncTable:
    """Frames of one stream on universal time. ``index`` (F,) int frame indices; ``univ_time_ms`` (F,) strictly
    increasing. Look frames up through ``index``, never by list position."""

    index: np.ndarray
    univ_time_ms: np.ndarray

    def times_of(self, frame_index: np.ndarray | int) -> np.ndarray:
        """Universal time (ms) of frame indices (vectorised). KeyError names the first index the stream lacks."""
        idx = np.asarray(frame_index)
        flat = idx.reshape(-1)
        pos = np.minimum(np.searchsorted(self.index, flat), len(self.index) - 1)
        found = (pos >= 0) & (self.index[pos] == flat) if len(self.index) else np.zeros(flat.shape, bool)
        if not np.all(found):
            raise KeyError(f"frame {int(flat[~found][0])} not in sync table")
        return self.univ_time_ms[pos].reshape(idx.shape)

    def time_of(self, frame_index: int) -> float:
        """Universal time (ms) of one frame index; KeyError if the stream has no such frame."""
        return float(self.times_of(frame_index))

    def nearest(self, univ_time_ms: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """For universal times (ms): the nearest frame's index and ``frame_time - univ_time`` in ms (vectorised)."""
        t = np.asarray(univ_time_ms, dtype=float)
        hi = np.clip(np.searchsorted(self.univ_time_ms, t), 1, len(self.index) - 1)
        lo = hi - 1
        pick = np.where(np.abs(self.univ_time_ms[lo] - t) <= np.abs(self.univ_time_ms[hi] - t), lo, hi)
        return self.index[pick], self.univ_time_ms[pick] - t

    def bracket(self, univ_time_ms: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The two frames around each time and their linear-interpolation weights.

        Returns ``(index0, index1, w0, w1)`` with ``value(t) ~= w0 * value[index0] + w1 * value[index1]``;
        weights are NaN for times outside the stream's span (no extrapolation). Consecutive entries of the
        table are bracketed, so a dropped frame widens the gap instead of being bridged by a wrong index.
        A time within ``FRAME_TIME_TOLERANCE_MS`` of a frame's time is that frame alone (its weight exactly 1, the
        other's exactly 0; at the ends of the table too): a grid that meets frame times only up to float rounding
        must not need the neighbouring frame (a missed detection there would drop the joint).
        """
        t = np.asarray(univ_time_ms, dtype=float)
        tol = FRAME_TIME_TOLERANCE_MS
        hi = np.clip(np.searchsorted(self.univ_time_ms, t, side="right"), 1, len(self.index) - 1)
        lo = hi - 1
        t0, t1 = self.univ_time_ms[lo], self.univ_time_ms[hi]
        span = np.where(t1 > t0, t1 - t0, 1.0)  # a one-frame table brackets its frame by itself
        w1 = np.where(t - t0 <= tol, 0.0, np.where(t1 - t <= tol, 1.0, (t - t0) / span))
        outside = (t < self.univ_time_ms[0] - tol) | (t > self.univ_time_ms[-1] + tol)
        w1 = np.where(outside, np.nan, w1)
        return self.index[lo], self.index[hi], 1.0 - w1, w1


@dataclass(kw_only=True)
class SyncTables:
    """``synctables``: 'vga' and 'hd' streams; ``ksynctables``: Kinect colour and depth streams keyed by node."""

    streams: dict[str, SyncTable] = field(default_factory=dict)  # "vga", "hd"
    kinect_color: dict[str, SyncTable] = field(default_factory=dict)  # "KINECTNODE1" -> table
    kinect_depth: dict[str, SyncTable] = field(default_factory=dict)


@dataclass(kw_only=True)
class Bundle:
    """A calibration-and-sync bundle. ``cameras`` is keyed by Panoptic name ("01_01", "00_00", "50_01")."""

    seq: str
    cameras: dict[str, Camera]
    calib_data_source: str = ""
    kinect: KinectCalibration | None = None
    sync: SyncTables | None = None

    def of_type(self, camera_type: CameraType | str) -> dict[str, Camera]:
        """Cameras of one type, keyed by name, in name order."""
        return {n: c for n, c in sorted(self.cameras.items()) if c.type == CameraType(camera_type)}

    def stacked(self, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Arrays for the vectorised camera model: R (C,3,3), t_cm (C,3), intr (C,4), dist (C,5), resolution (C,2)."""
        names = sorted(self.cameras) if names is None else names
        cams = [self.cameras[n] for n in names]
        return {
            "R": np.stack([c.R for c in cams]),
            "t_cm": np.stack([c.t_cm for c in cams]),
            "intr": np.stack([c.intr for c in cams]),
            "dist": np.stack([c.dist for c in cams]),
            "resolution": np.array([c.resolution for c in cams]),
        }
