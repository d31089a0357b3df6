"""The camera model of :mod:`dome_calib.camera` laid out for batched point solvers: P points x V views.

The views' parameters are split into (V,) component arrays so every operation is a plain (P, V) array
operation broadcast along the last axis, and the heavy arrays are float32 (world points and camera
translations stay within ~1e-5 cm, pixels within ~1e-4 px, far below detection noise); sums and solves are
float64. This is what lets one core triangulate >100 frames of 19 joints in 520 views per second. The
Jacobian is the point block of :func:`dome_calib.camera.project_with_jacobians` (``d_point``); the tests check
both against it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.camera import MIN_DEPTH
from dome_calib.jit import njit
from dome_calib.recon.project import ViewSet

F32 = np.float32
#: Columns of :func:`camera_table`: R (row-major, 9), t_cm (3), fx, fy, cx, cy, k1, k2, p1, p2, k3, r2_max.
CAMERA_COLUMNS = 22


def camera_table(views: ViewSet) -> np.ndarray:
    """(V, CAMERA_COLUMNS) float64: each view's parameters in one row (see CAMERA_COLUMNS), for compiled loops
    (:mod:`dome_calib.recon.people.compiled`)."""
    V = len(views.names)
    return np.ascontiguousarray(np.concatenate([views.R.reshape(V, 9), views.t_cm.reshape(V, 3), views.intr[:, :4],
                                                views.dist[:, :5], views.r2_max.reshape(V, 1)], axis=1),
                                dtype=np.float64)


@dataclass(frozen=True)
class Evaluation:
    """Projection of P points in V views: residual components r_u, r_v (P, V) px (NaN behind / outside the lens);
    with Jacobians: ``J`` (P, 6, V) = [du/dX, du/dY, du/dZ, dv/dX, dv/dY, dv/dZ]."""

    r_u: np.ndarray
    r_v: np.ndarray
    J: np.ndarray | None


class CameraKernel:
    """Float32 component arrays of a :class:`ViewSet` and the batched projection / Jacobian / normal equations;
    ``table``: the views' parameters in float64 rows (:func:`camera_table`)."""

    def __init__(self, views: ViewSet) -> None:
        V = len(views.names)
        self.V = V
        self.R = [[views.R[:, i, k].astype(F32) for k in range(3)] for i in range(3)]
        self.t = [views.t_cm[:, i].astype(F32) for i in range(3)]
        self.fx, self.fy, self.cx, self.cy = (views.intr[:, i].astype(F32) for i in range(4))
        self.k1, self.k2, self.p1, self.p2, self.k3 = (views.dist[:, i].astype(F32) for i in range(5))
        self.r2_max = views.r2_max.astype(F32)
        self.table = camera_table(views)

    def per_point(self, cols: np.ndarray) -> CameraKernel:
        """The kernel of each point's own views: (P, K) positions ``cols`` into these views -> a kernel whose
        component arrays are (P, K) (the same float32 numbers, broadcast per point instead of per view), for
        points seen in a few of many views (``table`` is not carried)."""
        out = object.__new__(CameraKernel)
        out.V = cols.shape[1]
        out.R = [[a[cols] for a in row] for row in self.R]
        out.t = [a[cols] for a in self.t]
        out.fx, out.fy, out.cx, out.cy = (a[cols] for a in (self.fx, self.fy, self.cx, self.cy))
        out.k1, out.k2, out.p1, out.p2, out.k3 = (a[cols] for a in (self.k1, self.k2, self.p1, self.p2, self.k3))
        out.r2_max = self.r2_max[cols]
        out.table = None
        return out

    def camera_points(self, X_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(P, 3) world cm -> x, y, z (P, V) camera-frame cm."""
        X = np.asarray(X_world, dtype=F32)
        X0, X1, X2 = X[:, 0:1], X[:, 1:2], X[:, 2:3]
        R = self.R
        return tuple(X0 * R[i][0] + X1 * R[i][1] + X2 * R[i][2] + self.t[i] for i in range(3))  # type: ignore

    def evaluate(self, X_world: np.ndarray, u_obs: np.ndarray, v_obs: np.ndarray, *, jacobian: bool) -> Evaluation:
        """Residuals (projection - observation) of (P, 3) points against (P, V) observed pixels, optional Jacobian."""
        xc, yc, zc = self.camera_points(X_world)
        front = zc > MIN_DEPTH
        inv_z = F32(1.0) / np.where(front, zc, np.nan).astype(F32)
        x, y = xc * inv_z, yc * inv_z
        xd, yd, a, b, d, r2 = self.distort(x, y, jacobian=jacobian)
        lens = r2 <= self.r2_max
        r_u = np.where(lens, xd * self.fx + self.cx - u_obs, np.nan)
        r_v = np.where(lens, yd * self.fy + self.cy - v_obs, np.nan)
        if not jacobian:
            return Evaluation(r_u, r_v, None)
        su, sv = self.fx * inv_z, self.fy * inv_z
        a, b_u, e_u = su * a, su * b, -(a * x + b * y) * su
        c_v, d, e_v = sv * b, sv * d, -(b * x + d * y) * sv
        R = self.R
        J = np.empty((len(r_u), 6, self.V), dtype=F32)
        for k in range(3):
            J[:, k] = a * R[0][k] + b_u * R[1][k] + e_u * R[2][k]
            J[:, 3 + k] = c_v * R[0][k] + d * R[1][k] + e_v * R[2][k]
        return Evaluation(r_u, r_v, J)

    def distort(self, x: np.ndarray, y: np.ndarray, *, jacobian: bool = True) -> tuple:
        """Distorted (xd, yd) of (P, V) normalised coordinates, the entries a = dxd/dx, b = dxd/dy = dyd/dx,
        d = dyd/dy of the distortion Jacobian (None unless ``jacobian``), and r2 = x^2 + y^2."""
        xx, yy, xy = x * x, y * y, x * y
        r2 = xx + yy
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * xx)
        yd = y * radial + self.p1 * (r2 + 2.0 * yy) + 2.0 * self.p2 * xy
        if not jacobian:
            return xd, yd, None, None, None, r2
        two_dr = 2.0 * (self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2))
        b = xy * two_dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        a = radial + xx * two_dr + 2.0 * self.p1 * y + 6.0 * self.p2 * x
        d = radial + yy * two_dr + 6.0 * self.p1 * y + 2.0 * self.p2 * x
        return xd, yd, a, b, d, r2

    def undistort(self, u_px: np.ndarray, v_px: np.ndarray, *, iterations: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """(P, V) pixels -> undistorted normalised (x, y) by Newton's method with the explicit 2x2 inverse.

        Float32, used to initialise the solvers only. On the real Panoptic lenses (tested against
        :func:`dome_calib.camera.pixels_to_normalized`) two iterations are within 0.02 px everywhere in the image,
        three reach the float32 floor (~3e-4 px). One compiled pass (:func:`_undistort`: the numpy expression of
        :meth:`distort`, operation for operation in float32, so the same numbers to the last bit).
        """
        u = np.ascontiguousarray(np.broadcast_to(np.asarray(u_px, dtype=F32), np.shape(u_px)))
        v = np.ascontiguousarray(np.broadcast_to(np.asarray(v_px, dtype=F32), np.shape(u_px)))
        shape = u.shape
        u, v = u.reshape(-1, self.V), v.reshape(-1, self.V)
        x, y = np.empty_like(u), np.empty_like(u)
        lens = (self.fx, self.fy, self.cx, self.cy, self.k1, self.k2, self.p1, self.p2, self.k3)
        if self.fx.ndim == 2:  # per point (:meth:`per_point`): one row of P * K entries, each with its own view
            u, v, x, y = u.reshape(1, -1), v.reshape(1, -1), x.reshape(1, -1), y.reshape(1, -1)
            lens = tuple(np.ascontiguousarray(a).reshape(-1) for a in lens)
        _undistort(u, v, *lens, int(iterations), x, y)
        return x.reshape(shape), y.reshape(shape)

    def reprojection_error_px(self, X_world: np.ndarray, u_obs: np.ndarray, v_obs: np.ndarray) -> np.ndarray:
        """(P, V) pixel distance between projections and observations (NaN behind the camera / outside the lens)."""
        ev = self.evaluate(X_world, u_obs, v_obs, jacobian=False)
        return np.sqrt(ev.r_u * ev.r_u + ev.r_v * ev.r_v)


def normal_equations(ev: Evaluation, weight: np.ndarray, penalty_px: float) -> tuple[np.ndarray, ...]:
    """Gauss-Newton system of ``sum_v w |r|^2`` per point: H (P, 3, 3), g (P, 3), cost (P,) (float64).

    Views with weight 0 are ignored; a weighted view whose residual became NaN (the point moved behind it)
    costs ``penalty_px^2`` and contributes no gradient.
    """
    w = weight.astype(F32)
    lost = (w > 0) & ~np.isfinite(ev.r_u)
    r_u = np.where(np.isfinite(ev.r_u) & (w > 0), ev.r_u, 0.0).astype(F32)
    r_v = np.where(np.isfinite(ev.r_v) & (w > 0), ev.r_v, 0.0).astype(F32)
    cost = np.einsum("pv,pv->p", w, r_u * r_u + r_v * r_v, dtype=np.float64)
    cost += np.einsum("pv->p", np.where(lost, w, 0.0), dtype=np.float64) * penalty_px**2
    if ev.J is None:
        return None, None, cost  # type: ignore[return-value]
    J = np.where(lost[:, None, :], F32(0.0), ev.J)
    wJ = J * w[:, None, :]
    M = (wJ @ np.swapaxes(J, 1, 2)).astype(np.float64)  # (P, 6, 6)
    H = M[:, :3, :3] + M[:, 3:, 3:]
    g = (wJ[:, :3] @ r_u[..., None] + wJ[:, 3:] @ r_v[..., None])[..., 0].astype(np.float64)
    return H, g, cost


@njit(nogil=True, boundscheck=False)
def _undistort(u, v, fx, fy, cx, cy, k1, k2, p1, p2, k3, iterations, x_out, y_out):  # pragma: no cover - compiled
    """:meth:`CameraKernel.undistort` of (M, V) float32 pixels: every operation of the numpy code in the same
    order, in float32 (no fused multiply-add: numba contracts nothing without fastmath)."""
    one, two, three, six = np.float32(1.0), np.float32(2.0), np.float32(3.0), np.float32(6.0)
    for m in range(u.shape[0]):
        for k in range(u.shape[1]):
            xd0 = (u[m, k] - cx[k]) / fx[k]
            yd0 = (v[m, k] - cy[k]) / fy[k]
            x, y = xd0, yd0
            for _ in range(iterations):
                xx, yy, xy = x * x, y * y, x * y
                r2 = xx + yy
                radial = one + r2 * (k1[k] + r2 * (k2[k] + r2 * k3[k]))
                xd = x * radial + two * p1[k] * xy + p2[k] * (r2 + two * xx)
                yd = y * radial + p1[k] * (r2 + two * yy) + two * p2[k] * xy
                two_dr = two * (k1[k] + r2 * (two * k2[k] + three * k3[k] * r2))
                b = xy * two_dr + two * p1[k] * x + two * p2[k] * y
                a = radial + xx * two_dr + two * p1[k] * y + six * p2[k] * x
                d = radial + yy * two_dr + six * p1[k] * y + two * p2[k] * x
                ex, ey = xd - xd0, yd - yd0
                inv_det = one / (a * d - b * b)
                x = x - (d * ex - b * ey) * inv_det
                y = y - (a * ey - b * ex) * inv_det
            x_out[m, k] = x
            y_out[m, k] = y
