"""The schemas of the four Panoptic files of a bundle, as they are read back (:mod:`dome_calib.panoptic_io`).

One class per file: :class:`CalibrationFile` (``calibration_<seq>.json``), :class:`KCalibrationFile`
(``kcalibration_<seq>.json``), :class:`SyncTablesFile` (``synctables_<seq>.json``) and :class:`KSyncTablesFile`
(``ksynctables_<seq>.json``). Numbers are JSON numbers (never strings, booleans or null), finite and within a
plausible range (``LIMITS``: beyond it a value is a unit mix-up or garbage, not a calibration); matrices have
their shape; rotations are orthonormal with det +1 (to ``ROTATION_REPAIR_TOL``).

Written by CMU's tools too, so where their real files carry more (``domeCenter`` per Kinect sensor), the schema
keeps it (:class:`KinectSensorEntry`), and where a column vector may be written three ways (``[k1, ...]``,
``[[k1], ...]``, ``[[k1, ...]]``) each is read. The sync tables and their ``kinect`` object ignore fields they do
not know (no real sync file was found to say what else CMU's carry).
"""
from __future__ import annotations

import re
from fractions import Fraction
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BeforeValidator, ConfigDict, RootModel, model_validator

from dome_calib.schema import (INT64_MAX, CameraName, Field, FieldError, FileSchema, JsonData, OpenSchema, Vec, show,
                               words)

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


def Bounded(limit: float) -> Any:  # noqa: N802 (a type constructor)
    """A finite number of magnitude at most ``limit``."""
    return Annotated[float, Field(ge=-limit, le=limit, allow_inf_nan=False)]


def _column(n: int):
    def flatten(value: Any) -> Any:
        """``[[a], [b], ...]`` (n x 1) or ``[[a, b, ...]]`` (1 x n) -> ``[a, b, ...]``; anything else as it is."""
        if isinstance(value, list) and len(value) == n and all(isinstance(v, list) and len(v) == 1 for v in value):
            return [v[0] for v in value]
        if isinstance(value, list) and len(value) == 1 and isinstance(value[0], list) and len(value[0]) == n:
            return value[0]
        if isinstance(value, list) and any(isinstance(v, list) for v in value):
            raise ValueError(f"expected {n} numbers (flat, {n} x 1 or 1 x {n}), got {show(value)}")
        return value
    return flatten


def Column(n: int, limit: float) -> Any:  # noqa: N802 (a type constructor)
    """``n`` numbers written flat, as an n x 1 column or a 1 x n row."""
    return Annotated[Vec(n, Bounded(limit)), BeforeValidator(_column(n)),
                     Field(**words(f"a list of {n} finite numbers (or {n} x 1, 1 x {n}) of magnitude <= {limit:g}"))]


def _camera_matrix(K: list[list[float]]) -> list[list[float]]:
    if K[0][1] != 0 or K[1][0] != 0 or K[2] != [0, 0, 1]:
        raise ValueError("expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    if K[0][0] <= 0 or K[1][1] <= 0:
        raise ValueError(f"focal length must be positive (fx={K[0][0]:g}, fy={K[1][1]:g})")
    return K


def _rotation(R: list[list[float]]) -> list[list[float]]:
    """Orthonormal with det +1 to ROTATION_REPAIR_TOL (the reader keeps it, or replaces it by the nearest rotation
    when it is off by more than ROTATION_EXACT_TOL)."""
    M = np.asarray(R, dtype=float)
    err, det = float(np.abs(M @ M.T - np.eye(3)).max()), float(np.linalg.det(M))
    if err > ROTATION_REPAIR_TOL or abs(det - 1.0) > 3 * ROTATION_REPAIR_TOL:
        raise ValueError(f"not a rotation (|R R^T - I| = {err:.2g}, det = {det:.6g}; accepted up to "
                         f"{ROTATION_REPAIR_TOL:g})")
    return R


def _last_row(M: list[list[float]]) -> list[list[float]]:
    if M[3] != [0, 0, 0, 1]:
        raise ValueError(f"last row must be [0, 0, 0, 1], got {show(M[3])}")
    return M


def _rigid(M: list[list[float]]) -> list[list[float]]:
    _rotation([row[:3] for row in _last_row(M)[:3]])
    return M


def _similarity(M: list[list[float]]) -> list[list[float]]:
    A = np.asarray(_last_row(M), dtype=float)[:3, :3]
    det = float(np.linalg.det(A))
    scale = np.cbrt(det) if det > 0 else 0.0
    if not scale > 0 or np.abs(A @ A.T / scale**2 - np.eye(3)).max() > ROTATION_REPAIR_TOL:
        raise ValueError(f"the 3x3 block is not a scaled rotation (det = {det:.6g})")
    return M


CameraMatrix = Annotated[Vec(3, Vec(3, Bounded(LIMITS["K_px"]))), AfterValidator(_camera_matrix),
                         Field(**words("a 3 x 3 camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (px, fx, fy > 0)"))]
Rotation = Annotated[Vec(3, Vec(3, Bounded(2.0))), AfterValidator(_rotation),
                     Field(**words(f"a 3 x 3 rotation (orthonormal to {ROTATION_REPAIR_TOL:g}, det +1)"))]
RigidTransform = Annotated[Vec(4, Vec(4, Bounded(LIMITS["transform"]))), AfterValidator(_rigid),
                           Field(**words("a 4 x 4 rigid transform [R t; 0 0 0 1] (m)"))]
SimilarityTransform = Annotated[Vec(4, Vec(4, Bounded(LIMITS["transform"]))), AfterValidator(_similarity),
                                Field(**words("a 4 x 4 similarity [s R t; 0 0 0 1]"))]
SizePx = Annotated[int, Field(ge=1, le=LIMITS["resolution_px"])]
FrameIndex = Annotated[int, Field(ge=0, le=LIMITS["frame_index"])]


def _kinect_node(name: str) -> str:
    if not KINECT_NODE.fullmatch(name):
        raise ValueError(f"expected KINECTNODE<n>, got {show(name)}")
    return name


KinectNodeName = Annotated[str, AfterValidator(_kinect_node), Field(**words("KINECTNODE<n>"))]


def _no_duplicate_names(items: list, field: str, what: str) -> None:
    seen: set[str] = set()
    for i, item in enumerate(items):
        if item.name in seen:
            raise FieldError((field, i, "name"), f"duplicate {what} name {show(item.name)}")
        seen.add(item.name)


# ---- calibration_<seq>.json --------------------------------------------------------------------------------------

class CalibrationCamera(FileSchema):
    """One camera: OpenCV pinhole, ``x_cam = R @ X_world + t`` (t in cm, the Panoptic world)."""

    name: CameraName = Field(description="Panoptic name: VGA 01_01..20_24, HD 00_00..00_30, Kinect 50_01..")
    type: Literal["vga", "hd", "kinect-color"]
    resolution: Vec(2, SizePx) = Field(description="[width, height] px")
    K: CameraMatrix
    distCoef: Column(5, LIMITS["dist"]) = Field(description="[k1, k2, p1, p2, k3]")
    R: Rotation = Field(description="cam_from_world rotation")
    t: Column(3, LIMITS["t_cm"]) = Field(description="cam_from_world translation, cm")
    panel: Annotated[int, Field(ge=0, le=INT64_MAX)] = 0
    node: Annotated[int, Field(ge=0, le=INT64_MAX)] = 0


class CalibrationFile(FileSchema):
    """``calibration_<seq>.json``: every camera of the dome (Panoptic layout)."""

    calibDataSource: str = Field("", description="what the calibration was made from")
    cameras: list[CalibrationCamera] = Field(min_length=1)

    @model_validator(mode="after")
    def _names_once(self) -> CalibrationFile:
        _no_duplicate_names(self.cameras, "cameras", "camera")
        return self


# ---- kcalibration_<seq>.json -------------------------------------------------------------------------------------

def _distortion_tail(value: Any) -> Any:
    """distCoeffs_depth as a flat list: an n x 1 column or a 1 x n row is flattened (n >= 5)."""
    if isinstance(value, list) and value and all(isinstance(v, list) and len(v) == 1 for v in value):
        return [v[0] for v in value]
    if isinstance(value, list) and len(value) == 1 and isinstance(value[0], list):
        return value[0]
    return value


class KinectSensorEntry(FileSchema):
    """One Kinect v2 (metres; see ``convention``). Fields of CMU's files this toolkit does not use
    (``domeCenter``) and its own additions (``colorCamera``, ``framesUsed``, ``rmsIrPx``, ``rmsColorPx``) are kept
    as written."""

    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, JsonData]  # kept as written, but JSON data without NaN

    name: KinectNodeName | None = Field(None, description="default: KINECTNODE1.. in file order")
    K_depth: CameraMatrix
    distCoeffs_depth: Annotated[list[Bounded(LIMITS["dist"])], BeforeValidator(_distortion_tail),
                                Field(min_length=5)] = Field(description="[k1, k2, p1, p2, k3, ...]: 5 used")
    depth_width: SizePx
    depth_height: SizePx
    K_color: CameraMatrix
    distCoeffs_color: Column(5, LIMITS["dist"])
    color_width: SizePx
    color_height: SizePx
    M_depth: RigidTransform = Field(description="sensor_from_depth")
    M_color: RigidTransform = Field(description="sensor_from_color")
    M_world2sensor: RigidTransform = Field(description="sensor_from_kinoptic_world")
    color_time_offset: Bounded(LIMITS["time_offset_ms"]) = Field(0.0, description="ms")
    depth_time_offset: Bounded(LIMITS["time_offset_ms"]) = Field(0.0, description="ms")
    depth_bias_mm: Bounded(LIMITS["depth_bias_mm"]) = 0.0
    depth_scale: Bounded(LIMITS["depth_scale"]) = Field(0.0, description="measured = true * (1 + scale) + bias")


def _convention(text: str) -> str:
    if text != M_COLOR_CONVENTION:
        raise ValueError(f"unknown convention {show(text, 60)}; this toolkit reads {M_COLOR_CONVENTION!r}")
    return text


class KCalibrationFile(FileSchema):
    """``kcalibration_<seq>.json``: every Kinect's depth-colour calibration, placed in the dome's world."""

    calibDataSource: str = ""
    panopticCalibDataSource: str = ""
    convention: Annotated[str, AfterValidator(_convention)] | None = Field(
        None, description="how M_depth / M_color read (CMU's files have none: read with this toolkit's)")
    sensors: list[KinectSensorEntry] = Field(min_length=1)
    M_world2vga: SimilarityTransform = Field(description="panoptic_world_cm_from_kinoptic_world_m")

    @model_validator(mode="after")
    def _names_once(self) -> KCalibrationFile:
        seen: set[str] = set()
        for i, sensor in enumerate(self.sensors):
            name = sensor.name or f"KINECTNODE{i + 1}"
            if name in seen:
                raise FieldError(("sensors", i, "name"), f"duplicate sensor name {name}")
            seen.add(name)
        return self


# ---- synctables_<seq>.json, ksynctables_<seq>.json ---------------------------------------------------------------

class SyncTableEntry(OpenSchema):
    """One stream's frames: ``univ_time[k]`` (ms, universal time) of frame ``index[k]``; both increasing."""

    index: list[FrameIndex] = Field(min_length=1, description="frame indices, increasing")
    univ_time: list[Annotated[float, Field(allow_inf_nan=False)]] = Field(description="ms, increasing")

    @model_validator(mode="after")
    def _one_time_per_increasing_index(self) -> SyncTableEntry:
        index, times = self.index, self.univ_time
        if len(times) != len(index):
            raise FieldError(("univ_time",), f"{len(times)} times for {len(index)} indices (expected one time per "
                                             "index)")
        for k in range(1, len(index)):
            if index[k] <= index[k - 1]:
                raise FieldError(("index", k), "frame indices must be increasing")
            if times[k] <= times[k - 1]:
                raise FieldError(("univ_time", k), f"time does not increase at frame index {index[k]}")
        return self


#: The frame rates of the dome's streams (the Kinects' colour and depth: 30 fps).
STREAM_FPS = {"vga": Fraction(25), "hd": Fraction(30000, 1001), "kinect": Fraction(30)}
#: A stream's frames may be this many times closer or farther apart than its rate says (an HD camera at 59.94 fps,
#: a dropped frame): a table in seconds (1000x closer) or in microseconds (1000x farther) is not.
SPACING_FACTOR = 10
#: The closest frames of a stream of another name (2,000 fps): a table in seconds is closer for any rate above 2 fps.
MIN_SPACING_MS = 0.5


def spacing_problem(stream: str, entry: SyncTableEntry) -> str | None:
    """Why the times of ``stream`` cannot be milliseconds (None: they can): the median time per frame index step
    against the stream's rate (:data:`STREAM_FPS`), or under :data:`MIN_SPACING_MS` for a stream of another name."""
    if len(entry.index) < 2:
        return None
    step = np.median(np.diff(entry.univ_time) / np.diff(entry.index))
    fps = STREAM_FPS.get(stream)
    if fps is None:
        return (f"frames {step:.3g} ms apart (faster than {1000 / MIN_SPACING_MS:g} fps): univ_time is in "
                "milliseconds (are these seconds?)") if step < MIN_SPACING_MS else None
    period = 1000.0 / float(fps)
    if not period / SPACING_FACTOR <= step <= period * SPACING_FACTOR:
        unit = "seconds" if step < period else "microseconds"
        return (f"frames {step:.3g} ms apart, but the {stream} stream runs at {float(fps):.4g} fps ({period:.3g} ms): "
                f"univ_time is in milliseconds (are these {unit}?)")
    return None


class SyncTablesFile(RootModel[dict[str, SyncTableEntry]]):
    """``synctables_<seq>.json``: ``{"vga": table, "hd": table}`` (any stream name); each stream's frames as far
    apart as its rate says (:func:`spacing_problem`: a table in seconds is refused)."""

    model_config = ConfigDict(strict=True, allow_inf_nan=False, frozen=True)

    @model_validator(mode="after")
    def _not_empty(self) -> SyncTablesFile:
        if not self.root:
            raise ValueError("expected an object with sync streams (vga, hd)")
        for stream, entry in self.root.items():
            problem = spacing_problem(stream, entry)
            if problem is not None:
                raise FieldError((stream, "univ_time"), problem)
        return self


class KinectSyncStreams(OpenSchema):
    color: dict[KinectNodeName, SyncTableEntry]
    depth: dict[KinectNodeName, SyncTableEntry]

    @model_validator(mode="after")
    def _milliseconds(self) -> KinectSyncStreams:
        for kind in ("color", "depth"):
            for node, entry in getattr(self, kind).items():
                problem = spacing_problem("kinect", entry)
                if problem is not None:
                    raise FieldError((kind, node, "univ_time"), problem)
        return self


class KSyncTablesFile(OpenSchema):
    """``ksynctables_<seq>.json``: each Kinect's colour and depth frames on universal time."""

    kinect: KinectSyncStreams
