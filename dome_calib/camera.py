"""The OpenCV pinhole camera with five distortion parameters [k1, k2, p1, p2, k3], vectorised.

Chain: world (cm) -> camera (x_cam = R @ X_world + t_cm) -> normalised (x/z, y/z) -> distorted -> pixel.
Pixel convention: OpenCV's, the centre of the top-left pixel is (0, 0). COLMAP puts it at (0.5, 0.5):
convert with :func:`opencv_to_colmap_px` / :func:`colmap_to_opencv_px`.

Intrinsics are packed as ``intr = [fx, fy, cx, cy]`` (px) and distortion as ``dist = [k1, k2, p1, p2, k3]``.
Every function broadcasts over leading dimensions, so one call handles (N,) points of one camera,
(C, N) points of C cameras, or (M,) observations each with its own camera parameters (bundle adjustment).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dome_calib.rotation import d_rotate_d_rotvec, rotvec_to_matrix

#: Depth (same unit as the camera translation) below which a point counts as behind the camera.
MIN_DEPTH = 1e-9
COLMAP_PIXEL_OFFSET_PX = 0.5


def opencv_to_colmap_px(uv_px: np.ndarray) -> np.ndarray:
    """OpenCV pixel coordinates (top-left pixel centre at 0, 0) -> COLMAP's (top-left pixel centre at 0.5, 0.5)."""
    return np.asarray(uv_px, dtype=float) + COLMAP_PIXEL_OFFSET_PX


def colmap_to_opencv_px(uv_px: np.ndarray) -> np.ndarray:
    """COLMAP pixel coordinates -> OpenCV pixel coordinates."""
    return np.asarray(uv_px, dtype=float) - COLMAP_PIXEL_OFFSET_PX


def K_to_intr(K: np.ndarray) -> np.ndarray:
    """(..., 3, 3) camera matrices -> (..., 4) [fx, fy, cx, cy]."""
    K = np.asarray(K, dtype=float)
    return np.stack([K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]], axis=-1)


def intr_to_K(intr: np.ndarray) -> np.ndarray:
    """(..., 4) [fx, fy, cx, cy] -> (..., 3, 3) camera matrices with zero skew."""
    intr = np.asarray(intr, dtype=float)
    K = np.zeros((*intr.shape[:-1], 3, 3))
    K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2] = intr[..., 0], intr[..., 1], intr[..., 2], intr[..., 3]
    K[..., 2, 2] = 1.0
    return K


def distort(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply lens distortion to normalised coordinates.

    Args:
        xn: (..., 2) undistorted normalised coordinates (x/z, y/z).
        dist: (..., 5) [k1, k2, p1, p2, k3], broadcast against ``xn``'s leading dimensions.
    Returns:
        (..., 2) distorted normalised coordinates.
    """
    xn = np.asarray(xn, dtype=float)
    dist = np.asarray(dist, dtype=float)
    k1, k2, p1, p2, k3 = (dist[..., i] for i in range(5))
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    return np.stack([xd, yd], axis=-1)


def distort_with_jacobians(xn: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`distort` plus its Jacobians: returns distorted (..., 2), d/d xn (..., 2, 2) and d/d dist (..., 2, 5)."""
    k1, k2, p1, p2, k3 = (dist[..., i] for i in range(5))
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    d_radial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4  # d radial / d r2
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    J_xn = np.empty((*x.shape, 2, 2))
    J_xn[..., 0, 0] = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
    J_xn[..., 0, 1] = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    J_xn[..., 1, 0] = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    J_xn[..., 1, 1] = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
    J_dist = np.empty((*x.shape, 2, 5))
    J_dist[..., 0, 0], J_dist[..., 1, 0] = x * r2, y * r2
    J_dist[..., 0, 1], J_dist[..., 1, 1] = x * r4, y * r4
    J_dist[..., 0, 2], J_dist[..., 1, 2] = xy2, r2 + 2.0 * y * y
    J_dist[..., 0, 3], J_dist[..., 1, 3] = r2 + 2.0 * x * x, xy2
    J_dist[..., 0, 4], J_dist[..., 1, 4] = x * r4 * r2, y * r4 * r2
    return np.stack([xd, yd], axis=-1), J_xn, J_dist


def undistort(xd: np.ndarray, dist: np.ndarray, *, max_iterations: int = 30, tol: float = 1e-15) -> np.ndarray:
    """Invert :func:`distort` by Newton's method: distorted -> undistorted normalised coordinates.

    Converges to machine precision inside the image of any real dome camera (tested at every pixel of a
    VGA camera with k1 = -0.32 to 1e-6 px round trip; in practice ~1e-12 px). Points whose Newton iteration
    does not converge (far outside the lens's monotonic range) come back as NaN.
    """
    xd = np.asarray(xd, dtype=float)
    dist = np.broadcast_to(np.asarray(dist, dtype=float), (*xd.shape[:-1], 5))
    xn = xd.copy()
    for _ in range(max_iterations):
        f, J, _ = distort_with_jacobians(xn, dist)
        r = f - xd
        det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
        step = np.stack([J[..., 1, 1] * r[..., 0] - J[..., 0, 1] * r[..., 1],
                         J[..., 0, 0] * r[..., 1] - J[..., 1, 0] * r[..., 0]], axis=-1) / det[..., None]
        xn = xn - step
        if np.nanmax(np.abs(step), initial=0.0) < tol:
            break
    residual = np.abs(distort(xn, dist) - xd).max(axis=-1)
    xn[~(residual < 1e-9)] = np.nan
    return xn


def pixels_to_normalized(uv_px: np.ndarray, intr: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(..., 2) OpenCV pixels -> (..., 2) undistorted normalised coordinates (rays [x, y, 1] in the camera frame).

    ``intr`` (..., 4) and ``dist`` (..., 5) broadcast against the leading dimensions of ``uv_px``: pass (4,) and
    (5,) for one camera, or ``intr[:, None]`` with (C, N, 2) pixels of C cameras.
    """
    intr = np.asarray(intr, dtype=float)
    xd = (np.asarray(uv_px, dtype=float) - intr[..., 2:4]) / intr[..., 0:2]
    return undistort(xd, dist)


def max_valid_radius2(dist: np.ndarray, r2_cap: float = 4.0) -> np.ndarray:
    """Largest r^2 (normalised) up to which the radial distortion r*(1+k1 r^2+k2 r^4+k3 r^6) still increases.

    Beyond it the OpenCV model folds points back into the image; projections there are not physical.
    Args: dist (..., 5). Returns (...,) r^2 limits, capped at ``r2_cap``.
    """
    d = np.asarray(dist, dtype=float)
    k1, k2, k3 = d[..., 0], d[..., 1], d[..., 4]
    r2 = np.linspace(0.0, r2_cap, 4001)
    # d/dr [r (1 + k1 r^2 + k2 r^4 + k3 r^6)] = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6
    slope = 1 + 3 * k1[..., None] * r2 + 5 * k2[..., None] * r2**2 + 7 * k3[..., None] * r2**3
    bad = slope <= 0
    first_bad = np.where(bad.any(axis=-1), bad.argmax(axis=-1), len(r2) - 1)
    return r2[np.maximum(first_bad - 1, 0)]


class Projection:
    """Result of :func:`project`.

    uv_px: (..., 2) OpenCV pixels; NaN where the point is behind the camera.
    depth: (...,) z in the camera frame (same unit as t, cm for the dome).
    in_front: (...,) bool, depth > MIN_DEPTH.
    in_lens: (...,) bool, in front and inside the distortion model's monotonic range (a physical projection);
        computed on first use.
    """

    def __init__(self, uv_px: np.ndarray, depth: np.ndarray, in_front: np.ndarray, r2: np.ndarray, dist: np.ndarray):
        self.uv_px, self.depth, self.in_front = uv_px, depth, in_front
        self._r2, self._dist = r2, dist

    @cached_property
    def in_lens(self) -> np.ndarray:
        r2_max = max_valid_radius2(self._dist)
        return self.in_front & (self._r2 <= (r2_max[..., None] if self._r2.ndim > r2_max.ndim else r2_max))

    def in_image(self, resolution: np.ndarray) -> np.ndarray:
        """(...,) bool: physically projected and inside [-0.5, w - 0.5] x [-0.5, h - 0.5]; resolution (..., 2)."""
        wh = np.asarray(resolution, dtype=float)
        if wh.ndim == 2 and self.uv_px.ndim == 3:
            wh = wh[:, None, :]
        inside = np.all((self.uv_px >= -0.5) & (self.uv_px <= wh - 0.5), axis=-1)
        return self.in_lens & inside


def project(X_world: np.ndarray, R: np.ndarray, t: np.ndarray, intr: np.ndarray, dist: np.ndarray) -> Projection:
    """Project world points into cameras.

    Args:
        X_world: (N, 3) points shared by all cameras, or (..., N, 3).
        R: (C, 3, 3) cam_from_world rotations (or (3, 3) for one camera); t: (C, 3) translations, same unit as X.
        intr: (C, 4) [fx, fy, cx, cy] px; dist: (C, 5) [k1, k2, p1, p2, k3].
    Returns:
        :class:`Projection` with arrays of shape (C, N, ...) (or (N, ...) for one camera).
    Example:
        >>> p = project(points_cm, cam.R[None], cam.t_cm[None], cam.intr[None], cam.dist[None])
    """
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    X = np.asarray(X_world, dtype=float)
    X_cam = X @ np.swapaxes(R, -1, -2) + t[..., None, :]
    depth = X_cam[..., 2]
    in_front = depth > MIN_DEPTH
    xn = X_cam[..., :2] / np.where(in_front, depth, np.nan)[..., None]
    d = np.asarray(dist, dtype=float)
    f = np.asarray(intr, dtype=float)[..., None, :]
    uv = distort(xn, d[..., None, :])
    uv *= f[..., 0:2]
    uv += f[..., 2:4]
    r2 = np.einsum("...i,...i->...", xn, xn)
    return Projection(uv_px=uv, depth=depth, in_front=in_front, r2=r2, dist=d)


@dataclass(frozen=True)
class ProjectionJacobians:
    """Pixel residual model and its analytic Jacobians, per observation (M of them).

    uv_px (M, 2); depth (M,); d_point (M, 2, 3); d_rotvec (M, 2, 3); d_t (M, 2, 3);
    d_intr (M, 2, 4) for [fx, fy, cx, cy]; d_dist (M, 2, 5) for [k1, k2, p1, p2, k3].
    """

    uv_px: np.ndarray
    depth: np.ndarray
    d_point: np.ndarray
    d_rotvec: np.ndarray
    d_t: np.ndarray
    d_intr: np.ndarray
    d_dist: np.ndarray


def project_with_jacobians(
    X_world: np.ndarray, rotvec: np.ndarray, t: np.ndarray, intr: np.ndarray, dist: np.ndarray,
    R: np.ndarray | None = None,
) -> ProjectionJacobians:
    """Project M observations, each with its own camera, and return the analytic Jacobians.

    Args:
        X_world (M, 3); rotvec (M, 3) cam_from_world rotation vectors; t (M, 3); intr (M, 4); dist (M, 5);
        R: optional (M, 3, 3) matrices of ``rotvec`` (saves recomputing them when cameras are gathered).
    The rotation Jacobian is with respect to the rotation vector itself (additive updates r + dr).
    Points behind the camera get NaN pixels; the caller decides what to do with them.
    """
    rotvec = np.asarray(rotvec, dtype=float)
    X = np.asarray(X_world, dtype=float)
    if R is None:
        R = rotvec_to_matrix(rotvec)
    X_rot = np.einsum("mij,mj->mi", R, X)
    X_cam = X_rot + t
    z = X_cam[:, 2]
    inv_z = np.where(z > MIN_DEPTH, 1.0 / np.where(z > MIN_DEPTH, z, 1.0), np.nan)
    xn = X_cam[:, :2] * inv_z[:, None]
    xd, J_xn, J_dist_n = distort_with_jacobians(xn, np.asarray(dist, dtype=float))
    intr = np.asarray(intr, dtype=float)
    fxy = intr[:, 0:2]
    uv = xd * fxy + intr[:, 2:4]
    # d xn / d X_cam = [[1/z, 0, -x/z], [0, 1/z, -y/z]]
    d_xn_d_Xc = np.zeros((len(z), 2, 3))
    d_xn_d_Xc[:, 0, 0] = inv_z
    d_xn_d_Xc[:, 1, 1] = inv_z
    d_xn_d_Xc[:, :, 2] = -xn * inv_z[:, None]
    d_uv_d_Xc = fxy[:, :, None] * (J_xn @ d_xn_d_Xc)
    d_intr = np.zeros((len(z), 2, 4))
    d_intr[:, 0, 0], d_intr[:, 1, 1] = xd[:, 0], xd[:, 1]
    d_intr[:, 0, 2] = d_intr[:, 1, 3] = 1.0
    return ProjectionJacobians(
        uv_px=uv,
        depth=z,
        d_point=d_uv_d_Xc @ R,
        d_rotvec=d_uv_d_Xc @ d_rotate_d_rotvec(rotvec, R, X),
        d_t=d_uv_d_Xc,
        d_intr=d_intr,
        d_dist=fxy[:, :, None] * J_dist_n,
    )
