"""Depth bias of a Kinect: offset and scale of the measured depth against the board plane.

Model (the one :class:`dome_calib.bundle.KinectSensor` stores): ``measured_mm = true_mm * (1 + depth_scale) +
depth_bias_mm``, depth being z along the depth camera's optical axis. The true depth of a pixel comes from the
board pose found by the stereo calibration (in the depth camera's frame): the pixel's ray, from the calibrated IR
intrinsics, meets the board plane at z. Only pixels well inside the detected corner grid are used; the fit is a
straight line in (true, measured), robust to flying pixels by iterated median-absolute-deviation clipping.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import cv2
import numpy as np

from dome_calib.camera import pixels_to_normalized
from dome_calib.kinect.board import Checkerboard
from dome_calib.options import AtLeast, Field, options
from dome_calib.schema import PosFinite


@options
class DepthBiasOptions:
    min_pixels: AtLeast(1) = 200  # fewer valid board pixels in all frames: no estimate
    clip_sigma: PosFinite = 4.0  # residuals beyond this many robust sigmas are dropped, then the line is refit
    shrink: Annotated[float, Field(gt=0, le=1)] = 0.9  # board region = the corner grid's outline shrunk about its centre by this factor


@dataclass(kw_only=True)
class DepthBiasResult:
    """Fitted bias; ``residual_mm`` is the robust std of measured minus model; range over the used pixels."""

    depth_bias_mm: float
    depth_scale: float
    residual_mm: float
    n_pixels: int
    n_frames: int
    min_depth_mm: float
    max_depth_mm: float

    def correct(self, measured_mm: np.ndarray) -> np.ndarray:
        """Measured depth -> true depth (mm)."""
        return (np.asarray(measured_mm, dtype=float) - self.depth_bias_mm) / (1.0 + self.depth_scale)


def board_mask(corners_px: np.ndarray, board: Checkerboard, size: tuple[int, int], shrink: float) -> np.ndarray:
    """(h, w) bool: pixels inside the quadrilateral of the outermost inner corners, shrunk about its centre."""
    g = corners_px.reshape(board.rows, board.cols, 2)
    quad = np.array([g[0, 0], g[0, -1], g[-1, -1], g[-1, 0]])
    quad = quad.mean(axis=0) + shrink * (quad - quad.mean(axis=0))
    mask = np.zeros((size[1], size[0]), np.uint8)
    cv2.fillConvexPoly(mask, np.round(quad * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def plane_depth_mm(uv_px: np.ndarray, intr: np.ndarray, dist: np.ndarray, R: np.ndarray,
                   t_mm: np.ndarray) -> np.ndarray:
    """z (mm) where the rays of pixels (K, 2) meet the plane z_board = 0 of a board at cam_from_board (R, t_mm)."""
    xn = pixels_to_normalized(uv_px, intr, dist)
    rays = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)
    normal = R[:, 2]
    return float(normal @ t_mm) / (rays @ normal)


def fit_line_robust(true_mm: np.ndarray, measured_mm: np.ndarray,
                    clip_sigma: float) -> tuple[float, float, float, np.ndarray]:
    """measured = a * true + b with iterated MAD clipping; returns (a, b, robust sigma, inlier mask)."""
    keep = np.isfinite(true_mm) & np.isfinite(measured_mm)
    a, b, sigma = 1.0, 0.0, np.inf
    for _ in range(6):
        A = np.stack([true_mm[keep], np.ones(keep.sum())], axis=1)
        a, b = np.linalg.lstsq(A, measured_mm[keep], rcond=None)[0]
        res = measured_mm - (a * true_mm + b)
        sigma = 1.4826 * float(np.median(np.abs(res[keep] - np.median(res[keep]))))
        new_keep = np.isfinite(res) & (np.abs(res) <= clip_sigma * max(sigma, 1e-6))
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return float(a), float(b), sigma, keep


def fit_depth_bias(depth_maps_mm: list[np.ndarray], ir_corners_px: list[np.ndarray], board_R: np.ndarray,
                   board_t_mm: np.ndarray, ir_intr: np.ndarray, ir_dist: np.ndarray, board: Checkerboard,
                   opts: DepthBiasOptions | None = None) -> DepthBiasResult | None:
    """Fit the bias from F frames: depth maps (h, w) uint16 mm (0 = none), IR corners (N, 2), poses (F, 3, 3), (F, 3).

    Returns None when fewer than ``opts.min_pixels`` board pixels have a depth reading.
    """
    opts = opts or DepthBiasOptions()
    true_all, meas_all = [], []
    frames = 0
    for depth, corners, R, t in zip(depth_maps_mm, ir_corners_px, board_R, board_t_mm):
        h, w = depth.shape
        mask = board_mask(corners, board, (w, h), opts.shrink) & (depth > 0)
        v, u = np.nonzero(mask)
        if len(u) == 0:
            continue
        frames += 1
        true_all.append(plane_depth_mm(np.stack([u, v], axis=1).astype(float), ir_intr, ir_dist, R, t))
        meas_all.append(depth[v, u].astype(float))
    if not true_all or sum(len(t) for t in true_all) < opts.min_pixels:
        return None
    true_mm, meas_mm = np.concatenate(true_all), np.concatenate(meas_all)
    a, b, sigma, keep = fit_line_robust(true_mm, meas_mm, opts.clip_sigma)
    return DepthBiasResult(depth_bias_mm=b, depth_scale=a - 1.0, residual_mm=sigma, n_pixels=int(keep.sum()),
                           n_frames=frames, min_depth_mm=float(true_mm[keep].min()),
                           max_depth_mm=float(true_mm[keep].max()))
