"""Depth(IR)-to-colour stereo calibration from checkerboard corners: initialisation and joint refinement.

Unknowns: IR intrinsics [fx, fy, cx, cy] and distortion [k1, k2, p1, p2, k3]; the colour camera's intrinsics and
distortion (held fixed by default, see :class:`StereoOptions`); the rigid ``color_from_depth`` transform
(rotation vector, translation mm); and every board pose ``depth_from_board`` (rotation vector, translation mm).
Residuals: IR corners reprojected by the board pose, colour corners reprojected by ``color_from_depth`` composed
with the board pose, each divided by its camera's corner noise, estimated from the residuals and re-solved (the
colour camera, at 3x the IR resolution, sees the corners more precisely and gets the larger weight). Per-frame
noise weights are an option (``frame_prior_obs``): they help when the noise truly varies by frame, but did not
on the rendered captures of ``bench/kinect.py``, so they are off by default.
Solver: ``scipy.optimize.least_squares`` (Levenberg-Marquardt) with analytic Jacobians from
:func:`dome_calib.camera.project_with_jacobians`.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from dome_calib.rotation import rotation_angle_deg
from dome_calib.camera import K_to_intr, intr_to_K, project_with_jacobians
from dome_calib.cv_threads import one_cv_thread
from dome_calib.rotation import d_rotate_d_rotvec, rotvec_to_matrix
from dome_calib.options import AtLeast, options
from dome_calib.schema import PosFinite


@options
class StereoOptions:
    """``estimate_color_intrinsics``: refine the colour camera's intrinsics too (default False: keep the dome's)."""

    estimate_color_intrinsics: bool = False
    reweight_rounds: AtLeast(0) = 2  # solves after the first, each with the noise re-estimated from the residuals
    # per-frame noise weights: the frame's residuals shrunk towards the camera's noise with this many coordinates
    # weight; None = one noise level per camera (default: on rendered boards per-frame weights did not help)
    frame_prior_obs: PosFinite | None = None
    max_nfev: AtLeast(1) = 200


@dataclass(kw_only=True)
class StereoResult:
    """Calibration of one depth-colour pair. Per-frame arrays are in the order of the input frames.

    ``color_from_depth``: x_color = R @ x_depth + t_mm. ``board_R``/``board_t_mm``: depth_from_board per frame.
    RMS values are pixel residual norms sqrt(mean |r|^2); sigma_*_px the per-coordinate noise used as weight.
    """

    ir_intr: np.ndarray
    ir_dist: np.ndarray
    color_intr: np.ndarray
    color_dist: np.ndarray
    R: np.ndarray
    t_mm: np.ndarray
    board_R: np.ndarray
    board_t_mm: np.ndarray
    rms_ir_px: float
    rms_color_px: float
    frame_rms_ir_px: np.ndarray
    frame_rms_color_px: np.ndarray
    sigma_ir_px: float
    sigma_color_px: float

    @property
    def color_from_depth_mm(self) -> np.ndarray:
        """(4, 4) depth camera -> colour camera, translation mm."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t_mm
        return T


def _pose_to_matrix(rotvec: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotvec_to_matrix(rotvec), t
    return T


def initial_estimate(obj_mm: np.ndarray, ir_px: np.ndarray, color_px: np.ndarray, ir_size: tuple[int, int],
                     color_intr: np.ndarray, color_dist: np.ndarray) -> dict[str, np.ndarray]:
    """Closed-form-ish start: IR by ``cv2.calibrateCamera``, colour board poses by PnP, extrinsic by averaging.

    Args: obj_mm (N, 3); ir_px, color_px (F, N, 2) corners of the same F frames. Returns a dict of arrays.
    """
    obj = [obj_mm.astype(np.float32)] * len(ir_px)
    with one_cv_thread():  # OpenCV's threads sum in the order they finish (dome_calib.cv_threads)
        _, K_ir, d_ir, rvecs, tvecs = cv2.calibrateCamera(obj, [p.astype(np.float32) for p in ir_px],
                                                          tuple(ir_size), None, None)
    K_col = intr_to_K(color_intr)
    rel = []
    for f in range(len(ir_px)):
        ok, rv, tv = cv2.solvePnP(obj_mm, color_px[f], K_col, np.asarray(color_dist, float))
        T_cb = _pose_to_matrix(rv.ravel(), tv.ravel())
        rel.append(T_cb @ np.linalg.inv(_pose_to_matrix(rvecs[f].ravel(), tvecs[f].ravel())))
    rel = np.array(rel)
    return {
        "ir_intr": K_to_intr(K_ir), "ir_dist": d_ir.ravel()[:5],
        "ext_rotvec": Rotation.from_matrix(rel[:, :3, :3]).mean().as_rotvec(),
        "ext_t": np.median(rel[:, :3, 3], axis=0),
        "board_rotvec": np.array([r.ravel() for r in rvecs]), "board_t": np.array([t.ravel() for t in tvecs]),
    }


class _Problem:
    """Residuals and the dense analytic Jacobian of the joint IR + colour reprojection problem."""

    def __init__(self, obj_mm: np.ndarray, ir_px: np.ndarray, color_px: np.ndarray, color_intr: np.ndarray,
                 color_dist: np.ndarray, estimate_color: bool) -> None:
        self.F, self.N = ir_px.shape[:2]
        self.X = np.tile(obj_mm, (self.F, 1))  # (M, 3), M = F * N
        self.frame = np.repeat(np.arange(self.F), self.N)
        self.obs_ir, self.obs_col = ir_px.reshape(-1, 2), color_px.reshape(-1, 2)
        self.color_intr, self.color_dist = np.asarray(color_intr, float), np.asarray(color_dist, float)
        self.estimate_color = estimate_color
        n_cam = 9 + (9 if estimate_color else 0)
        self.i_ext = n_cam  # rotvec (3), t (3)
        self.i_board = n_cam + 6
        self.n_params = self.i_board + 6 * self.F
        self.w_ir = np.ones(len(self.X))  # per-observation weights 1 / sigma (set per frame and camera)
        self.w_col = np.ones(len(self.X))

    def pack(self, p: dict[str, np.ndarray]) -> np.ndarray:
        parts = [p["ir_intr"], p["ir_dist"]]
        if self.estimate_color:
            parts += [p["color_intr"], p["color_dist"]]
        parts += [p["ext_rotvec"], p["ext_t"], np.hstack([p["board_rotvec"], p["board_t"]]).ravel()]
        return np.concatenate(parts)

    def unpack(self, x: np.ndarray) -> dict[str, np.ndarray]:
        boards = x[self.i_board:].reshape(self.F, 6)
        return {
            "ir_intr": x[0:4], "ir_dist": x[4:9],
            "color_intr": x[9:13] if self.estimate_color else self.color_intr,
            "color_dist": x[13:18] if self.estimate_color else self.color_dist,
            "ext_rotvec": x[self.i_ext:self.i_ext + 3], "ext_t": x[self.i_ext + 3:self.i_ext + 6],
            "board_rotvec": boards[:, :3], "board_t": boards[:, 3:],
        }

    def evaluate(self, x: np.ndarray, with_jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        p = self.unpack(x)
        M, f = len(self.X), self.frame
        rb, tb = p["board_rotvec"][f], p["board_t"][f]
        Rb = rotvec_to_matrix(rb)
        ir = project_with_jacobians(self.X, rb, tb, np.tile(p["ir_intr"], (M, 1)), np.tile(p["ir_dist"], (M, 1)), R=Rb)
        X_depth = np.einsum("mij,mj->mi", Rb, self.X) + tb
        col = project_with_jacobians(X_depth, np.tile(p["ext_rotvec"], (M, 1)), np.tile(p["ext_t"], (M, 1)),
                                     np.tile(p["color_intr"], (M, 1)), np.tile(p["color_dist"], (M, 1)))
        r = np.concatenate([((ir.uv_px - self.obs_ir) * self.w_ir[:, None]).ravel(),
                            ((col.uv_px - self.obs_col) * self.w_col[:, None]).ravel()])
        r = np.nan_to_num(r, nan=1e6)  # a board behind a camera: a huge residual the solver backs away from
        if not with_jacobian:
            return r, None
        J = np.zeros((4 * M, self.n_params))
        rows_ir = (2 * np.arange(M))[:, None] + np.arange(2)  # (M, 2)
        rows_col = rows_ir + 2 * M
        board_cols = self.i_board + 6 * f[:, None] + np.arange(6)  # (M, 6)

        def put(rows: np.ndarray, cols: np.ndarray, block: np.ndarray, w: np.ndarray) -> None:
            J[rows[:, :, None], cols[:, None, :] if cols.ndim == 2 else cols[None, None, :]] = block * w[:, None, None]

        put(rows_ir, np.arange(0, 4), ir.d_intr, self.w_ir)
        put(rows_ir, np.arange(4, 9), ir.d_dist, self.w_ir)
        put(rows_ir, board_cols, np.concatenate([ir.d_rotvec, ir.d_t], axis=-1), self.w_ir)
        if self.estimate_color:
            put(rows_col, np.arange(9, 13), col.d_intr, self.w_col)
            put(rows_col, np.arange(13, 18), col.d_dist, self.w_col)
        ext_cols = np.arange(self.i_ext, self.i_ext + 6)
        put(rows_col, ext_cols, np.concatenate([col.d_rotvec, col.d_t], axis=-1), self.w_col)
        d_board = np.concatenate([col.d_point @ d_rotate_d_rotvec(rb, Rb, self.X), col.d_point], axis=-1)
        put(rows_col, board_cols, d_board, self.w_col)
        return r, J

    def split_rms(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unweighted per-observation residual norms (M,) for IR and colour."""
        w_ir, w_col = self.w_ir, self.w_col
        self.w_ir, self.w_col = np.ones_like(w_ir), np.ones_like(w_col)
        r, _ = self.evaluate(x, False)
        self.w_ir, self.w_col = w_ir, w_col
        M = len(self.X)
        return np.linalg.norm(r[:2 * M].reshape(M, 2), axis=1), np.linalg.norm(r[2 * M:].reshape(M, 2), axis=1)


def _frame_sigma(err: np.ndarray, frame: np.ndarray, sigma: float, dof: float, prior_obs: float) -> np.ndarray:
    """Per-frame corner noise (F,) px from residual norms (M,), shrunk towards the camera's ``sigma``."""
    n = np.bincount(frame) * 2.0  # coordinates per frame
    var_f = np.bincount(frame, weights=err**2) / dof
    return np.sqrt((var_f + prior_obs * sigma**2) / (n + prior_obs)).clip(min=1e-6)


def refine_stereo(obj_mm: np.ndarray, ir_px: np.ndarray, color_px: np.ndarray, start: dict[str, np.ndarray],
                  color_intr: np.ndarray, color_dist: np.ndarray, opts: StereoOptions | None = None) -> StereoResult:
    """Joint least squares over IR intrinsics, extrinsic and board poses (and colour intrinsics if asked)."""
    opts = opts or StereoOptions()
    prob = _Problem(obj_mm, ir_px, color_px, color_intr, color_dist, opts.estimate_color_intrinsics)
    x = prob.pack({**start, "color_intr": np.asarray(color_intr, float), "color_dist": np.asarray(color_dist, float)})
    cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def fun(x: np.ndarray) -> np.ndarray:
        r, J = prob.evaluate(x, True)
        cache["last"] = (x.copy(), J)
        return r

    def jac(x: np.ndarray) -> np.ndarray:
        if "last" in cache and np.array_equal(cache["last"][0], x):
            return cache["last"][1]
        return prob.evaluate(x, True)[1]

    n_obs = 2 * len(prob.X)
    for round_ in range(1 + opts.reweight_rounds):
        x = least_squares(fun, x, jac=jac, method="lm", x_scale="jac", max_nfev=opts.max_nfev * len(x)).x
        e_ir, e_col = prob.split_rms(x)
        dof = max(1.0 - prob.n_params / (2 * n_obs), 0.1)  # residual degrees of freedom per observation
        sigma_ir = float(np.sqrt(np.mean(e_ir**2) / 2 / dof))
        sigma_col = float(np.sqrt(np.mean(e_col**2) / 2 / dof))
        if round_ < opts.reweight_rounds and opts.frame_prior_obs is None:
            prob.w_ir = np.full(len(prob.X), 1.0 / max(sigma_ir, 1e-6))
            prob.w_col = np.full(len(prob.X), 1.0 / max(sigma_col, 1e-6))
        elif round_ < opts.reweight_rounds:
            prob.w_ir = 1.0 / _frame_sigma(e_ir, prob.frame, sigma_ir, dof, opts.frame_prior_obs)[prob.frame]
            prob.w_col = 1.0 / _frame_sigma(e_col, prob.frame, sigma_col, dof, opts.frame_prior_obs)[prob.frame]
    p = prob.unpack(x)
    e_ir, e_col = e_ir.reshape(prob.F, prob.N), e_col.reshape(prob.F, prob.N)
    return StereoResult(
        ir_intr=p["ir_intr"].copy(), ir_dist=p["ir_dist"].copy(), color_intr=np.array(p["color_intr"], float),
        color_dist=np.array(p["color_dist"], float), R=rotvec_to_matrix(p["ext_rotvec"]), t_mm=p["ext_t"].copy(),
        board_R=rotvec_to_matrix(p["board_rotvec"]), board_t_mm=p["board_t"].copy(),
        rms_ir_px=float(np.sqrt(np.mean(e_ir**2))), rms_color_px=float(np.sqrt(np.mean(e_col**2))),
        frame_rms_ir_px=np.sqrt(np.mean(e_ir**2, axis=1)), frame_rms_color_px=np.sqrt(np.mean(e_col**2, axis=1)),
        sigma_ir_px=sigma_ir, sigma_color_px=sigma_col,
    )


def calibrate_stereo(obj_mm: np.ndarray, ir_px: np.ndarray, color_px: np.ndarray, ir_size: tuple[int, int],
                     color_intr: np.ndarray, color_dist: np.ndarray, opts: StereoOptions | None = None) -> StereoResult:
    """Initialise and refine. obj_mm (N, 3); ir_px, color_px (F, N, 2) OpenCV px; colour intrinsics (4,), (5,).

    Example:
        >>> res = calibrate_stereo(board.object_points_mm(), ir, col, (512, 424), cam.intr, cam.dist)
        >>> res.t_mm  # depth -> colour translation, mm (about [-52.8, 0, 0] for a Kinect v2)
    """
    start = initial_estimate(obj_mm, ir_px, color_px, ir_size, color_intr, color_dist)
    return refine_stereo(obj_mm, ir_px, color_px, start, color_intr, color_dist, opts)


def opencv_stereo_calibrate(obj_mm: np.ndarray, ir_px: np.ndarray, color_px: np.ndarray, ir_size: tuple[int, int],
                            color_intr: np.ndarray, color_dist: np.ndarray, *, fix_color: bool = True) -> dict:
    """OpenCV's recipe on the same corners, the peer the benchmark compares against.

    ``cv2.calibrateCamera`` for the IR camera, then ``cv2.stereoCalibrate`` with ``CALIB_FIX_INTRINSIC``
    (``fix_color``) or ``CALIB_USE_INTRINSIC_GUESS`` (both cameras' intrinsics refined with the extrinsic).
    Returns {"ir_intr", "ir_dist", "color_intr", "color_dist", "R", "t_mm", "rms_px"}.
    """
    obj = [obj_mm.astype(np.float32)] * len(ir_px)
    ir = [p.astype(np.float32) for p in ir_px]
    col = [p.astype(np.float32) for p in color_px]
    flags = cv2.CALIB_FIX_INTRINSIC if fix_color else cv2.CALIB_USE_INTRINSIC_GUESS
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    with one_cv_thread():  # OpenCV's threads sum in the order they finish (dome_calib.cv_threads)
        _, K_ir, d_ir, _, _ = cv2.calibrateCamera(obj, ir, tuple(ir_size), None, None)
        rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
            obj, ir, col, K_ir, d_ir, intr_to_K(color_intr), np.asarray(color_dist, float).reshape(1, 5),
            tuple(ir_size), flags=flags, criteria=criteria)
    return {"ir_intr": K_to_intr(K1), "ir_dist": D1.ravel()[:5], "color_intr": K_to_intr(K2),
            "color_dist": D2.ravel()[:5], "R": R, "t_mm": T.ravel(), "rms_px": float(rms)}


def rotation_error_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle (deg) of R_a @ R_b^T (a scalar :func:`dome_calib.align.rotation_angle_deg`)."""
    return float(rotation_angle_deg(R_a, R_b))
