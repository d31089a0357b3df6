"""Calibrate the Kinects of a capture folder against a dome bundle: the stage behind ``dome-calib kinect``.

Per sensor: detect the board in every IR/colour pair (rejecting frames with a reason), calibrate the IR camera
and the depth-to-colour transform jointly (:mod:`dome_calib.kinect.stereo`), fit the depth bias
(:mod:`dome_calib.kinect.depth_bias`), and place the depth camera in the world through the bundle's pose of the
Kinect's colour camera ``50_<nn>`` (:mod:`dome_calib.kinect.world`).

Colour intrinsics: by default the colour camera's intrinsics and distortion are taken from the dome bundle and
held fixed. The dome calibration estimates them from thousands of observations spread over the whole image and
the whole capture volume, far better than a few dozen board views; they are also the intrinsics its world pose
was estimated with, so replacing them would make the colour camera disagree with the dome. Holding them fixed
also removes 9 unknowns from the stereo problem. ``--estimate-color-intrinsics`` refines them instead (for a
dome bundle whose Kinect colour cameras are only nominal).
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import numpy as np

from dome_calib.bundle import Bundle, Camera, KinectCalibration, KinectSensor
from dome_calib.camera import intr_to_K
from dome_calib.errors import CaptureError
from dome_calib.layout import check_dome_scale
from dome_calib.kinect.board import Checkerboard
from dome_calib.kinect.depth_bias import DepthBiasOptions, DepthBiasResult, fit_depth_bias
from dome_calib.kinect.detect import (DetectOptions, SensorFrames, check_sensor_frames, detect_board,
                                      find_sensor_frames, read_depth_mm, read_gray)
from dome_calib.kinect.stereo import StereoOptions, StereoResult, calibrate_stereo
from dome_calib.kinect.world import M_WORLD2VGA, sensor_matrices
from dome_calib.options import AtLeast, Field, Lax, options

logger = logging.getLogger(__name__)

IR_SIZE = (512, 424)


class ColorIntrinsics(StrEnum):
    BUNDLE = "bundle"  # the dome bundle's colour-camera intrinsics, held fixed (default)
    ESTIMATE = "estimate"  # refined with the stereo calibration, starting from the bundle's


@options
class KinectCalibOptions:
    board: Checkerboard = field(default_factory=Checkerboard)
    ir_size: tuple[AtLeast(1), AtLeast(1)] = IR_SIZE
    color_intrinsics: Annotated[ColorIntrinsics, Lax] = ColorIntrinsics.BUNDLE
    min_frames: AtLeast(1) = 4  # usable board pairs needed per sensor
    # a frame whose RMS exceeds this x the median frame's is dropped
    max_frame_rms_factor: Annotated[float, Field(ge=1)] = 4.0
    detect: DetectOptions = field(default_factory=DetectOptions)
    depth_bias: DepthBiasOptions = field(default_factory=DepthBiasOptions)
    reweight_rounds: AtLeast(0) = 2


@dataclass(kw_only=True)
class FrameStatus:
    index: int
    used: bool
    reason: str = ""  # why the frame was rejected


@dataclass(kw_only=True)
class SensorCalibration:
    """One sensor's result: frame bookkeeping, the stereo solution, the depth bias, and the kcalibration entry."""

    name: str
    color_camera: str
    frames: list[FrameStatus]
    stereo: StereoResult
    depth_bias: DepthBiasResult | None
    sensor: KinectSensor
    used_indices: list[int]  # frame indices of the rows of the corner arrays (and of the stereo board poses)
    ir_corners_px: np.ndarray  # (F, N, 2) detected corners of the used frames, canonical order
    color_corners_px: np.ndarray  # (F, N, 2)

    @property
    def frames_used(self) -> int:
        return sum(f.used for f in self.frames)

    @property
    def baseline_mm(self) -> float:
        """Distance between the depth and colour camera centres, mm."""
        return float(np.linalg.norm(self.stereo.t_mm))

    def summary(self) -> dict:
        """Plain data for the CLI and reports."""
        rejected = [f for f in self.frames if not f.used]
        return {
            "sensor": self.name, "color_camera": self.color_camera, "frames_used": self.frames_used,
            "frames_rejected": len(rejected), "rejected": {f.index: f.reason for f in rejected},
            "rms_ir_px": round(self.stereo.rms_ir_px, 4), "rms_color_px": round(self.stereo.rms_color_px, 4),
            "baseline_mm": round(self.baseline_mm, 2), "ir_focal_px": round(float(self.stereo.ir_intr[:2].mean()), 2),
            "depth_bias_mm": None if self.depth_bias is None else round(self.depth_bias.depth_bias_mm, 2),
            "depth_scale": None if self.depth_bias is None else round(self.depth_bias.depth_scale, 5),
        }


def _detect_frames(frames: SensorFrames, color_size: tuple[int, int], opts: KinectCalibOptions,
                   on_frame: Callable[[], None] | None,
                   ) -> tuple[list[FrameStatus], dict[int, tuple[np.ndarray, np.ndarray]]]:
    statuses, found = [], {}
    for k in frames.indices:
        ir = detect_board(read_gray(frames.ir[k], opts.ir_size, "IR"), opts.board, opts.detect, "IR")
        col = detect_board(read_gray(frames.color[k], color_size, "colour"), opts.board, opts.detect, "colour")
        reasons = [d.reason for d in (ir, col) if not d.ok]
        statuses.append(FrameStatus(index=k, used=not reasons, reason="; ".join(reasons)))
        if not reasons:
            found[k] = (ir.corners_px, col.corners_px)
        if on_frame is not None:
            on_frame()
    return statuses, found


def calibrate_sensor(frames: SensorFrames, color_cam: Camera, opts: KinectCalibOptions | None = None,
                     on_frame: Callable[[], None] | None = None) -> SensorCalibration:
    """Calibrate one Kinect from its frames and its colour camera (intrinsics, world pose) in the dome bundle.

    Raises :class:`CaptureError` if the board is found in no frame, or in fewer than ``opts.min_frames``.
    """
    opts = opts or KinectCalibOptions()
    statuses, found = _detect_frames(frames, color_cam.resolution, opts, on_frame)
    by_index = {s.index: s for s in statuses}
    if not found:
        first = statuses[0].reason if statuses else "no frames"
        raise CaptureError(f"{frames.folder}: no board found in any of {len(statuses)} frames (frame "
                           f"{statuses[0].index}: {first})")
    stereo_opts = StereoOptions(estimate_color_intrinsics=opts.color_intrinsics == ColorIntrinsics.ESTIMATE,
                                reweight_rounds=opts.reweight_rounds)
    obj = opts.board.object_points_mm()
    while True:
        if len(found) < opts.min_frames:
            raise CaptureError(f"{frames.folder}: the board was usable in only {len(found)} of {len(statuses)} frames "
                               f"(need {opts.min_frames}); first rejection: "
                               f"{next((s.reason for s in statuses if not s.used), '-')}")
        keys = sorted(found)
        ir_px = np.array([found[k][0] for k in keys])
        col_px = np.array([found[k][1] for k in keys])
        stereo = calibrate_stereo(obj, ir_px, col_px, opts.ir_size, color_cam.intr, color_cam.dist, stereo_opts)
        score = np.maximum(stereo.frame_rms_ir_px / max(stereo.sigma_ir_px, 1e-9),
                           stereo.frame_rms_color_px / max(stereo.sigma_color_px, 1e-9))
        worst = int(np.argmax(score))
        if score[worst] <= opts.max_frame_rms_factor * np.median(score):
            break
        k = keys[worst]
        by_index[k].used, by_index[k].reason = False, (
            f"inconsistent corners (reprojection RMS IR {stereo.frame_rms_ir_px[worst]:.2f} px, colour "
            f"{stereo.frame_rms_color_px[worst]:.2f} px)")
        del found[k]
    depth_maps, corners, used_pos = [], [], []
    for i, k in enumerate(keys):
        if k in frames.depth:
            depth_maps.append(read_depth_mm(frames.depth[k], opts.ir_size))
            corners.append(found[k][0])
            used_pos.append(i)
    bias = None
    if depth_maps:
        bias = fit_depth_bias(depth_maps, corners, stereo.board_R[used_pos], stereo.board_t_mm[used_pos],
                              stereo.ir_intr, stereo.ir_dist, opts.board, opts.depth_bias)
    if bias is None:
        logger.warning("%s: no depth maps of the board; depth bias left at 0", frames.name)
    matrices = sensor_matrices(stereo.color_from_depth_mm, color_cam.cam_from_world)
    sensor = KinectSensor(
        name=frames.name, K_depth=intr_to_K(stereo.ir_intr), dist_depth=stereo.ir_dist.copy(), depth_size=opts.ir_size,
        K_color=intr_to_K(stereo.color_intr), dist_color=stereo.color_dist.copy(), color_size=color_cam.resolution,
        **matrices,
        depth_bias_mm=0.0 if bias is None else bias.depth_bias_mm,
        depth_scale=0.0 if bias is None else bias.depth_scale,
        extra={"colorCamera": color_cam.name, "framesUsed": len(keys), "rmsIrPx": stereo.rms_ir_px,
               "rmsColorPx": stereo.rms_color_px},
    )
    return SensorCalibration(name=frames.name, color_camera=color_cam.name, frames=statuses, stereo=stereo,
                             depth_bias=bias, sensor=sensor, used_indices=keys, ir_corners_px=ir_px,
                             color_corners_px=col_px)


def color_camera_name(sensor: str) -> str:
    """'KINECTNODE3' -> '50_03'."""
    return f"50_{int(sensor.removeprefix('KINECTNODE')):02d}"


def calibrate_kinect_folder(kinect_folder: str | Path, bundle: Bundle, opts: KinectCalibOptions | None = None,
                            on_frame: Callable[[], None] | None = None) -> tuple[list[SensorCalibration], Bundle]:
    """Calibrate every ``KINECTNODE<n>`` of a folder; return the per-sensor results and the updated bundle.

    The returned bundle is ``bundle`` with its ``kinect`` calibration set (nothing is written here). Sensors of an
    earlier kcalibration that were not recalibrated are kept if that file used the same world convention.
    Raises :class:`CaptureError` for a folder, sensor or frame that cannot be used (one line naming it).
    """
    opts = opts or KinectCalibOptions()
    check_dome_scale(bundle.cameras, f"the dome bundle (calibration_{bundle.seq}.json)")  # metres would misplace them
    all_frames = find_sensor_frames(kinect_folder)
    for name, frames in all_frames.items():  # every sensor and image header before the first detection
        if color_camera_name(name) not in bundle.cameras:
            raise CaptureError(f"{Path(kinect_folder) / name}: the bundle has no colour camera "
                               f"{color_camera_name(name)} to place this Kinect")
        check_sensor_frames(frames, opts.ir_size, bundle.cameras[color_camera_name(name)].resolution)
    results = [calibrate_sensor(frames, bundle.cameras[color_camera_name(name)], opts, on_frame)
               for name, frames in all_frames.items()]
    sensors: dict[str, KinectSensor] = {}
    if bundle.kinect is not None and np.allclose(bundle.kinect.M_world2vga, M_WORLD2VGA):
        sensors.update(bundle.kinect.sensors)
    elif bundle.kinect is not None:
        logger.warning("the bundle's old kcalibration uses another Kinoptic world; its sensors are dropped")
    sensors.update({r.name: r.sensor for r in results})
    sensors = dict(sorted(sensors.items(), key=lambda kv: int(kv[0].removeprefix("KINECTNODE"))))
    kinect = KinectCalibration(sensors=sensors, M_world2vga=M_WORLD2VGA.copy(),
                               calib_data_source=f"dome-calib kinect {Path(kinect_folder).name}",
                               panoptic_calib_data_source=f"calibration_{bundle.seq}.json")
    updated = Bundle(seq=bundle.seq, cameras=bundle.cameras, calib_data_source=bundle.calib_data_source,
                     kinect=kinect, sync=bundle.sync)
    return results, updated
