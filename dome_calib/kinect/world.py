"""Kinect frames in the dome's world: the kcalibration matrices and depth pixels -> Panoptic world points.

Frames (this project's convention, also in every kcalibration file's ``"convention"`` field):

- ``M_depth = sensor_from_depth`` and ``M_color = sensor_from_color`` (metres), so
  ``color_from_depth = inv(M_color) @ M_depth``. As in the real Kinoptic files, ``M_depth = diag(-1, -1, 1, 1)``:
  the sensor frame is the depth camera turned half a turn about its optical axis.
- The Kinoptic world is the Panoptic world expressed in metres (same origin and axes, y down), so
  ``M_world2vga = diag(100, 100, 100, 1)`` (Panoptic cm from Kinoptic m) and
  ``M_world2sensor = M_color @ color_from_world_m``, where ``color_from_world`` is the dome bundle's pose of the
  Kinect's colour camera ``50_<nn>`` (translation converted cm -> m).
"""
from __future__ import annotations

import numpy as np

from dome_calib.bundle import KinectSensor
from dome_calib.camera import K_to_intr, pixels_to_normalized

M_DEPTH = np.diag([-1.0, -1.0, 1.0, 1.0])  # sensor_from_depth, as in the real Kinoptic calibrations
M_WORLD2VGA = np.diag([100.0, 100.0, 100.0, 1.0])  # Panoptic world (cm) from Kinoptic world (m)
_CM_FROM_M = np.diag([100.0, 100.0, 100.0, 1.0])


def _scale_translation(T: np.ndarray, factor: float) -> np.ndarray:
    out = np.array(T, dtype=float)
    out[:3, 3] *= factor
    return out


def sensor_matrices(color_from_depth_mm: np.ndarray, color_from_world_cm: np.ndarray) -> dict[str, np.ndarray]:
    """(4, 4) color_from_depth (mm) and color_from_world (cm) -> M_depth, M_color, M_world2sensor (metres)."""
    depth_from_color_m = _scale_translation(np.linalg.inv(color_from_depth_mm), 1e-3)
    M_color = M_DEPTH @ depth_from_color_m
    return {"M_depth": M_DEPTH.copy(), "M_color": M_color,
            "M_world2sensor": M_color @ _scale_translation(color_from_world_cm, 1e-2)}


def depth_from_world_cm(sensor: KinectSensor, M_world2vga: np.ndarray) -> np.ndarray:
    """(4, 4) depth camera pose, Panoptic world (cm) -> depth camera (cm): x_depth = R @ X_world + t_cm."""
    depth_from_kinoptic_m = np.linalg.inv(sensor.M_depth) @ sensor.M_world2sensor
    return _CM_FROM_M @ depth_from_kinoptic_m @ np.linalg.inv(M_world2vga)


def depth_pixels_to_world_cm(uv_px: np.ndarray, depth_mm: np.ndarray, sensor: KinectSensor,
                             M_world2vga: np.ndarray, *, correct_bias: bool = True) -> np.ndarray:
    """Depth readings -> Panoptic world points (cm).

    Args:
        uv_px: (K, 2) depth-image pixels (OpenCV convention); depth_mm: (K,) measured z along the optical axis.
        sensor: the Kinect's calibration; M_world2vga: Panoptic cm from Kinoptic m (the bundle's).
        correct_bias: undo ``measured = true * (1 + depth_scale) + depth_bias_mm`` first.
    Returns:
        (K, 3) world points, cm (NaN where the depth is 0 = no reading).
    """
    z_mm = np.asarray(depth_mm, dtype=float)
    if correct_bias:
        z_mm = (z_mm - sensor.depth_bias_mm) / (1.0 + sensor.depth_scale)
    z_mm = np.where(np.asarray(depth_mm) > 0, z_mm, np.nan)
    xn = pixels_to_normalized(uv_px, K_to_intr(sensor.K_depth), sensor.dist_depth)
    X_depth_cm = np.concatenate([xn, np.ones((len(xn), 1))], axis=1) * (z_mm / 10.0)[:, None]
    world_from_depth = np.linalg.inv(depth_from_world_cm(sensor, M_world2vga))
    return X_depth_cm @ world_from_depth[:3, :3].T + world_from_depth[:3, 3]


def depth_map_to_world_cm(depth_map_mm: np.ndarray, sensor: KinectSensor, M_world2vga: np.ndarray,
                          *, correct_bias: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Every valid pixel of a (h, w) uint16 depth map -> ((K, 3) world points cm, (K, 2) their pixels)."""
    v, u = np.nonzero(depth_map_mm > 0)
    uv = np.stack([u, v], axis=1).astype(float)
    return depth_pixels_to_world_cm(uv, depth_map_mm[v, u], sensor, M_world2vga, correct_bias=correct_bias), uv
