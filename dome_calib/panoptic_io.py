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

import logging
from pathlib import Path

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
