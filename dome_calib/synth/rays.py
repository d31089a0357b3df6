"""Camera rays through the real (distorted) camera model, fast enough for millions of pixels.

The undistortion is computed exactly by :func:`dome_calib.camera.pixels_to_normalized` on a grid every
``GRID_STEP_PX`` pixels; any other pixel position starts from a bilinear interpolation of that grid (error
< 0.01 px) and takes one Newton step on ``distort(xn) = xd`` (quadratic convergence: error < 1e-6 px, tested
against ``pixels_to_normalized``). This is ~10x faster than running the full Newton solve at every pixel.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates

from dome_calib.bundle import Camera
from dome_calib.camera import distort_with_jacobians, pixels_to_normalized
from dome_calib.errors import DomeCalibError

#: Rays are processed in chunks this long: temporaries stay in cache (2.5x faster than 1 << 20).
CHUNK_RAYS = 1 << 14


def _newton_undistort_step(xn: np.ndarray, xd: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """One Newton step on distort(xn) = xd (analytic 2x2 Jacobian, solved in closed form)."""
    f, J, _ = distort_with_jacobians(xn, dist)
    r = f - xd
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    step_x = (J[:, 1, 1] * r[:, 0] - J[:, 0, 1] * r[:, 1]) / det
    step_y = (J[:, 0, 0] * r[:, 1] - J[:, 1, 0] * r[:, 0]) / det
    return xn - np.stack([step_x, step_y], axis=1)


class CameraRays:
    """World rays of one camera (origin = camera centre, cm) through arbitrary pixel positions.

    ``base_dirs`` (h*w, 3): unit world directions through the centres of a grid of ``shape`` = (h, w) samples,
    row-major, computed once and reused for every scene. With ``scale`` = 1 the grid is the pixel grid; with
    ``scale`` < 1 it is a coarser grid of round(W*scale) x round(H*scale) samples covering the image with the same
    centre-aligned convention as ``cv2.resize`` (sample j sits at pixel (j + 0.5) / scale - 0.5).
    """

    GRID_STEP_PX = 8.0

    def __init__(self, cam: Camera, scale: float = 1.0) -> None:
        self.cam = cam
        self.origin_cm = cam.center_cm
        w, h = cam.resolution
        self.resolution = (w, h)
        self.shape = (int(round(h * scale)), int(round(w * scale)))
        self.scale_xy = (self.shape[1] / w, self.shape[0] / h)
        step = self.GRID_STEP_PX
        self._u0 = self._v0 = -2.0 * step
        ug = self._u0 + step * np.arange(int(np.ceil((w + 4 * step) / step)) + 1)
        vg = self._v0 + step * np.arange(int(np.ceil((h + 4 * step) / step)) + 1)
        uu, vv = np.meshgrid(ug, vg)
        self._grid = pixels_to_normalized(np.stack([uu, vv], axis=-1), cam.intr, cam.dist)
        if not np.all(np.isfinite(self._grid)):
            raise DomeCalibError(f"camera {cam.name}: distortion {np.round(cam.dist, 4).tolist()} cannot be inverted "
                                 "over the image (the lens model folds back)")
        sx, sy = self.scale_xy
        u, v = np.meshgrid((np.arange(self.shape[1]) + 0.5) / sx - 0.5, (np.arange(self.shape[0]) + 0.5) / sy - 0.5)
        self.base_dirs = self.dirs_at(np.stack([u.ravel(), v.ravel()], axis=1))

    def normalized(self, uv_px: np.ndarray) -> np.ndarray:
        """(N, 2) OpenCV pixels -> (N, 2) undistorted normalised coordinates [x/z, y/z]."""
        intr, dist = self.cam.intr, self.cam.dist
        uv_px = np.asarray(uv_px, dtype=float)
        out = np.empty_like(uv_px)
        for i in range(0, len(uv_px), CHUNK_RAYS):
            uv = uv_px[i:i + CHUNK_RAYS]
            coords = np.stack([(uv[:, 1] - self._v0) / self.GRID_STEP_PX, (uv[:, 0] - self._u0) / self.GRID_STEP_PX])
            x0 = np.stack([map_coordinates(self._grid[..., k], coords, order=1, mode="nearest") for k in range(2)],
                          axis=1)
            xd = (uv - intr[2:4]) / intr[0:2]
            out[i:i + CHUNK_RAYS] = _newton_undistort_step(x0, xd, dist)
        return out

    def dirs_at(self, uv_px: np.ndarray) -> np.ndarray:
        """(N, 2) pixels -> (N, 3) world unit ray directions."""
        xn = self.normalized(uv_px)
        R = self.cam.R
        inv_norm = 1.0 / np.sqrt(xn[:, 0] ** 2 + xn[:, 1] ** 2 + 1.0)
        # d_world = R^T d_cam, written out: (N, 3) @ (3, 3) matmuls are slow for tall arrays
        return (xn[:, 0:1] * R[0] + xn[:, 1:2] * R[1] + R[2]) * inv_norm[:, None]
