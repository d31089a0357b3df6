"""The calibration checkerboard: its corner coordinates and its appearance, and a ray-cast renderer of it.

Board frame (mm): x along the rows of inner corners (``cols`` of them), y down the board, z into the board
(away from a camera that sees its printed face). Inner corner (c, r) sits at (c * square_mm, r * square_mm, 0)
and has index ``r * cols + c`` - the order :mod:`dome_calib.kinect.detect` returns detections in. The squares
run one square beyond the inner corners on each side; the cell whose top-left corner is inner corner (0, 0)
is black, so the board's orientation is unambiguous.

The renderer casts one ray per sub-pixel sample through the distorted camera model
(:func:`dome_calib.camera.pixels_to_normalized`) and intersects it with the board plane, so corners land
where the camera model puts them, to a small fraction of a pixel.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.camera import distort, pixels_to_normalized, project


@dataclass(kw_only=True, frozen=True)
class Checkerboard:
    """A printed checkerboard. ``cols`` x ``rows`` inner corners, squares of ``square_mm``, white border."""

    cols: int = 9
    rows: int = 6
    square_mm: float = 60.0
    border_mm: float = 40.0  # white margin around the outer squares

    @property
    def pattern_size(self) -> tuple[int, int]:
        """(cols, rows) as OpenCV's ``patternSize``."""
        return (self.cols, self.rows)

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    def object_points_mm(self) -> np.ndarray:
        """(cols * rows, 3) inner corners in the board frame, mm, index r * cols + c."""
        c, r = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([c.ravel(), r.ravel(), np.zeros(c.size)], axis=-1) * self.square_mm

    def outline_mm(self, samples_per_side: int = 16) -> np.ndarray:
        """(4 * samples_per_side, 3) points along the physical board edge (squares plus border), mm."""
        lo = -self.square_mm - self.border_mm
        hx, hy = self.cols * self.square_mm + self.border_mm, self.rows * self.square_mm + self.border_mm
        s = np.linspace(0.0, 1.0, samples_per_side, endpoint=False)
        xs, ys = lo + s * (hx - lo), lo + s * (hy - lo)
        edges = [np.c_[xs, np.full_like(s, lo)], np.c_[np.full_like(s, hx), ys],
                 np.c_[xs[::-1] + (hx - lo) / samples_per_side, np.full_like(s, hy)],
                 np.c_[np.full_like(s, lo), ys[::-1] + (hy - lo) / samples_per_side]]
        xy = np.concatenate(edges)
        return np.c_[xy, np.zeros(len(xy))]

    def reflectance(self, xy_mm: np.ndarray, blur_mm: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Printed reflectance at board points: (values in [0, 1] (0 black, 1 white), on_board bool).

        ``xy_mm`` (..., 2) board coordinates; ``blur_mm`` (...) half-width of a linear ramp across square edges
        (the footprint of one render sample), an analytic anti-aliasing that supersampling then refines.
        """
        return self.reflectance_xy(xy_mm[..., 0], xy_mm[..., 1], blur_mm)

    def reflectance_xy(self, x_mm: np.ndarray, y_mm: np.ndarray,
                       blur_mm: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`reflectance` with the board coordinates as two arrays (saves stacking in the renderer)."""
        u = x_mm / self.square_mm
        v = y_mm / self.square_mm
        w = np.maximum(np.asarray(blur_mm) / self.square_mm, 1e-6)

        def ramp(a: np.ndarray) -> np.ndarray:  # (-1)^floor(a), ramped to 0 at the square edges
            sign = 1.0 - 2.0 * (np.floor(a) % 2)
            return sign * np.clip(np.abs(a - np.round(a)) / w, 0.0, 1.0)

        checker = 0.5 - 0.5 * ramp(u) * ramp(v)  # cell (i, j) black when i + j is even (dtype follows xy_mm)
        in_squares = (u >= -1) & (u <= self.cols) & (v >= -1) & (v <= self.rows)
        b = self.border_mm / self.square_mm
        on_board = (u >= -1 - b) & (u <= self.cols + b) & (v >= -1 - b) & (v <= self.rows + b)
        return np.where(in_squares, checker, 1.0), on_board


@dataclass(kw_only=True, frozen=True)
class RayGrid:
    """Per-pixel rays of one camera and their derivative w.r.t. the pixel, for fast sub-pixel sampling.

    xn (H, W, 2) undistorted normalised coordinates of the pixel centres; d_xn_d_uv (H, W, 2, 2). A sample at
    pixel + (du, dv), |du|, |dv| < 0.5, gets the ray xn + d_xn_d_uv @ (du, dv) (first order; the distortion's
    curvature over half a pixel is far below 1e-4 px for any Kinect lens).
    """

    xn: np.ndarray
    d_xn_d_uv: np.ndarray
    intr: np.ndarray
    dist: np.ndarray

    @classmethod
    def build(cls, intr: np.ndarray, dist: np.ndarray, size: tuple[int, int], *, stride_px: int = 8) -> RayGrid:
        """Rays of every pixel of a ``size`` = (w, h) image.

        Exact rays (:func:`pixels_to_normalized`) on a grid every ``stride_px`` pixels, expanded to all pixels to
        first order and polished by three quasi-Newton steps against the forward model (error < 1e-4 px).
        """
        w, h = size
        intr, dist = np.asarray(intr, dtype=float), np.asarray(dist, dtype=float)
        uc, vc = np.meshgrid(np.arange(0, w + stride_px, stride_px, dtype=float),
                             np.arange(0, h + stride_px, stride_px, dtype=float))
        xn_c = pixels_to_normalized(np.stack([uc, vc], axis=-1), intr, dist)
        inv_c = np.linalg.inv(_d_uv_d_xn(xn_c, intr, dist))
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        iu, iv = np.rint(u / stride_px).astype(int), np.rint(v / stride_px).astype(int)
        J = inv_c[iv, iu]  # (h, w, 2, 2) d xn / d uv at the nearest grid node
        uv = np.stack([u, v], axis=-1)
        xn = xn_c[iv, iu] + np.einsum("...ij,...j->...i", J, uv - np.stack([uc[iv, iu], vc[iv, iu]], axis=-1))
        for _ in range(3):  # quasi-Newton polish: uv(xn) must equal the pixel
            residual = distort(xn, dist) * intr[:2] + intr[2:] - uv
            xn -= np.einsum("...ij,...j->...i", J, residual)
        return cls(xn=xn, d_xn_d_uv=J.astype(np.float32), intr=intr, dist=dist)


def _d_uv_d_xn(xn: np.ndarray, intr: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(..., 2, 2) Jacobian of pixel w.r.t. normalised coordinates, by central differences of the forward model."""
    eps = 1e-6
    steps = (np.array([eps, 0.0]), np.array([0.0, eps]))
    cols = [(distort(xn + e, dist) - distort(xn - e, dist)) / (2 * eps) for e in steps]
    return np.stack(cols, axis=-1) * intr[:2, None]


@dataclass(kw_only=True, frozen=True)
class BoardRender:
    """One camera's view of the board. All arrays (H, W).

    reflectance: mean printed reflectance over the pixel's samples (background samples count 0);
    coverage: fraction of samples on the board; depth_mm: z where the pixel-centre ray meets the board's plane
    (NaN outside the rendered region or behind the camera; use ``coverage`` to know if it hits the board);
    cos_incidence: |cos| of the angle between the pixel ray and the board normal (0 where depth_mm is NaN).
    """

    reflectance: np.ndarray
    coverage: np.ndarray
    depth_mm: np.ndarray
    cos_incidence: np.ndarray


def board_roi(board: Checkerboard, rays: RayGrid, R: np.ndarray, t_mm: np.ndarray) -> tuple[slice, slice] | None:
    """Pixel rows/cols (slices) that can see the board, or None if it is not in view."""
    h, w = rays.xn.shape[:2]
    p = project(board.outline_mm(), R, t_mm, rays.intr, rays.dist)
    if not np.all(p.in_lens):
        return (slice(0, h), slice(0, w))  # a board crossing the lens's valid range: render everything
    lo = np.floor(p.uv_px.min(axis=0)).astype(int) - 2
    hi = np.ceil(p.uv_px.max(axis=0)).astype(int) + 3
    lo, hi = np.maximum(lo, 0), np.minimum(hi, [w, h])
    if np.any(hi <= lo):
        return None
    return (slice(lo[1], hi[1]), slice(lo[0], hi[0]))


def render_board(board: Checkerboard, rays: RayGrid, R: np.ndarray, t_mm: np.ndarray, *,
                 supersample: int = 4) -> BoardRender:
    """Ray-cast the board seen by a camera with ``cam_from_board`` = (R (3, 3), t_mm (3,)).

    Each pixel is sampled on a ``supersample`` x ``supersample`` grid; corners are sub-pixel accurate.
    """
    h, w = rays.xn.shape[:2]
    out = BoardRender(reflectance=np.zeros((h, w)), coverage=np.zeros((h, w)), depth_mm=np.full((h, w), np.nan),
                      cos_incidence=np.zeros((h, w)))
    roi = board_roi(board, rays, R, t_mm)
    if roi is None:
        return out
    # float32 samples: 1e-7 relative precision is < 1e-4 px and < 1e-3 mm on the board, and twice as fast
    x0, y0 = (rays.xn[roi][..., i].astype(np.float32) for i in range(2))
    J = rays.d_xn_d_uv[roi]
    j00, j01, j10, j11 = (np.ascontiguousarray(J[..., a, b], dtype=np.float32)
                          for a, b in ((0, 0), (0, 1), (1, 0), (1, 1)))
    Rf = np.asarray(R, dtype=float)
    n = Rf[:, 2]  # plane: n . X = offset (camera frame, mm)
    offset = float(n @ t_mm)
    c = Rf.T @ np.asarray(t_mm, dtype=float)  # board xy = z * (R^T ray)[:2] - (R^T t)[:2]
    blur_per_mm = np.float32(0.5 / (np.mean(rays.intr[:2]) * supersample))
    k = supersample
    steps = (np.arange(k) + 0.5) / k - 0.5
    acc = np.zeros(x0.shape, np.float32)
    cover = np.zeros(x0.shape, np.float32)
    f32 = np.float32
    for dv in steps:
        for du in steps:
            x = x0 + j00 * f32(du) + j01 * f32(dv)
            y = y0 + j10 * f32(du) + j11 * f32(dv)
            denom = x * f32(n[0]) + y * f32(n[1]) + f32(n[2])
            ok = np.abs(denom) > 1e-12
            z = np.where(ok, f32(offset) / np.where(ok, denom, f32(1.0)), f32(-1.0))
            bx = z * (x * f32(Rf[0, 0]) + y * f32(Rf[1, 0]) + f32(Rf[2, 0])) - f32(c[0])
            by = z * (x * f32(Rf[0, 1]) + y * f32(Rf[1, 1]) + f32(Rf[2, 1])) - f32(c[1])
            value, on = board.reflectance_xy(bx, by, np.abs(z) * blur_per_mm)
            on &= z > 0
            acc += np.where(on, value, f32(0.0))
            cover += on
    out.reflectance[roi] = acc / k**2
    out.coverage[roi] = cover / k**2
    ray0 = np.concatenate([rays.xn[roi], np.ones((*x0.shape, 1))], axis=-1)  # float64 for the depth map
    denom0 = ray0 @ R[:, 2]
    z0 = float(R[:, 2] @ t_mm) / np.where(np.abs(denom0) > 1e-12, denom0, np.nan)
    out.depth_mm[roi] = np.where(z0 > 0, z0, np.nan)
    out.cos_incidence[roi] = np.where(z0 > 0, np.abs(denom0) / np.linalg.norm(ray0, axis=-1), 0.0)
    return out
