"""Kinect v2 depth-colour calibration from checkerboards, and Kinect depth cameras in the dome's world.

Stages: :mod:`~dome_calib.kinect.detect` (frames, corners, rejection reasons) -> :mod:`~dome_calib.kinect.stereo`
(IR intrinsics + depth-to-colour transform, joint least squares) -> :mod:`~dome_calib.kinect.depth_bias`
(offset and scale of the depth) -> :mod:`~dome_calib.kinect.world` (kcalibration matrices, depth -> world).
:func:`calibrate_kinect_folder` runs them all for ``dome-calib kinect``.
"""
from dome_calib.kinect.board import Checkerboard
from dome_calib.kinect.calibrate import (ColorIntrinsics, KinectCalibOptions, SensorCalibration,
                                         calibrate_kinect_folder, calibrate_sensor)
from dome_calib.kinect.world import M_WORLD2VGA, depth_from_world_cm, depth_map_to_world_cm, depth_pixels_to_world_cm

__all__ = [
    "Checkerboard", "ColorIntrinsics", "KinectCalibOptions", "SensorCalibration", "calibrate_kinect_folder",
    "calibrate_sensor", "M_WORLD2VGA", "depth_from_world_cm", "depth_map_to_world_cm", "depth_pixels_to_world_cm",
]
