"""Fixing the 7-dof similarity gauge of a bundle adjustment.

Reprojections do not change if the whole scene (cameras and points) is rotated, translated and scaled, so
the normal equations are singular in 7 directions.

**In the solve** (mode ``auto`` with no camera pose held by the caller): inner constraints on the cameras. The
7 directions, expressed in the free camera parameters (:func:`similarity_directions`: a world translation
``tau`` moves ``t`` by ``-R tau``, a world rotation ``omega`` moves the rotation vector by ``-J_r(r)^-1 omega``, a
scale moves ``t`` by ``t``), are added to the reduced camera system as a rank-7 term of unit weight in the
Levenberg-Marquardt scaling (:func:`inner_constraint_basis`): the system stays positive definite and every step
is orthogonal to them, so the dome's pose, orientation and scale (all cameras together) do not move. Holding
one camera's pose and one translation component instead ties the whole frame to that camera's own fit: when its
principal point or focal length is freed, the frame has to turn and scale around it, a direction the
reduced system sees only through that one camera. Measured on the full dome's lens-model solve: 96 % of the
cameras' motion over 12 crawling iterations was such a similarity (0.5 deg, 0.4 % scale; 3.1 cm median
centre motion, 0.13 cm after removing it). The world frame is set afterwards by normalisation anyway.

**For the uncertainties** (and when the caller holds poses), the gauge is held exactly, like COLMAP's
TWO_CAMS_FROM_WORLD gauge:

- the full pose (rotation vector and translation) of a reference camera A fixes rotation and translation (6);
- one translation component of a second camera B fixes the scale (1). Scaling about A's centre changes
  ``t_B`` by ``-R_B (c_B - c_A)`` per unit scale; we hold the component where that is largest.

For the uncertainties this is exact and simple (the 7 unknowns leave the system, which stays positive definite
for a plain Cholesky; no weight to tune): they are relative to camera A and to the A-B scale, and
:mod:`dome_calib.ba.uncertainty` also gives centre uncertainties in the gauge of the camera centroid (the one
that matters after normalisation). The inner constraints' unit weight needs no tuning either: the steps are
orthogonal to the 7 directions whatever the weight, which only keeps the system positive definite.

If the user already holds the poses of two or more cameras (e.g. only replaced cameras free), the gauge is
fixed by those and nothing is added; with one held pose only the scale component is added.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from dome_calib.ba.problem import ROT, TRANS, BAProblem, BAProblemError
from dome_calib.ties import LENGTH_QUANTUM_CM, argmax_first
from dome_calib.rotation import right_jacobian, rotvec_to_matrix

logger = logging.getLogger(__name__)


class GaugeMode(StrEnum):
    AUTO = "auto"  # inner constraints when no pose is held, else the user's held poses (plus a scale component)
    TWO_CAMERAS = "two_cameras"  # always hold camera A's pose and one translation component of camera B
    USER = "user"  # the user's fixed parameters fix the gauge (checked: >= 2 cameras with fixed pose)


@dataclass(kw_only=True)
class Gauge:
    """The gauge of a solve. ``held`` (C, 15) bool: parameters held for the gauge only (in the solve, or with
    ``inner`` only for the uncertainties: the solve then used inner constraints and moved them)."""

    mode: GaugeMode
    reference_camera: str | None
    scale_camera: str | None
    scale_component: int | None  # 0, 1, 2 = t_x, t_y, t_z of the scale camera
    held: np.ndarray
    inner: bool = False

    def describe(self) -> str:
        if self.reference_camera is None and self.scale_camera is None:
            return "gauge fixed by the user's fixed camera poses"
        parts = []
        if self.reference_camera is not None:
            parts.append(f"pose of {self.reference_camera} held")
        if self.scale_camera is not None:
            parts.append(f"t_{'xyz'[self.scale_component]} of {self.scale_camera} held (scale)")
        held = ", ".join(parts)
        return f"inner constraints on all camera poses in the solve; for the uncertainties {held}" if self.inner else held


def choose_gauge(problem: BAProblem, *, mode: GaugeMode | str = GaugeMode.AUTO,
                 reference_camera: str | None = None, scale_camera: str | None = None,
                 obs_mask: np.ndarray | None = None) -> Gauge:
    """Choose the parameters to hold (see the module docstring).

    Default reference camera: the camera with the most observations among those whose pose is free; default
    scale camera: among the cameras with at least the median observation count, the one whose best translation
    component moves most under a scale change about A.
    """
    mode = GaugeMode(mode)
    C = problem.n_cameras
    held = np.zeros((C, 15), dtype=bool)
    pose_fixed = ~problem.free[:, 0:6].any(axis=1)
    obs = problem.camera_index if obs_mask is None else problem.camera_index[obs_mask]
    counts = np.bincount(obs, minlength=C)
    n_fixed = int(pose_fixed.sum())
    if mode is GaugeMode.USER or (mode is GaugeMode.AUTO and n_fixed >= 2):
        if n_fixed < 2:
            raise BAProblemError(f"gauge mode 'user' needs the poses of >= 2 cameras fixed; {n_fixed} are")
        return Gauge(mode=mode, reference_camera=None, scale_camera=None, scale_component=None, held=held)
    params = problem.camera_params
    if reference_camera is not None:
        a = problem.camera_position(reference_camera)
    elif mode is GaugeMode.AUTO and n_fixed == 1:
        a = int(np.flatnonzero(pose_fixed)[0])
    else:
        a = int(np.argmax(np.where(pose_fixed, -1, counts)))
    R = rotvec_to_matrix(params[:, ROT])
    centres = -np.einsum("cji,cj->ci", R, params[:, TRANS])
    # d t_B / d scale (about A's centre) = -R_B (c_B - c_A)
    d_t = -np.einsum("cij,cj->ci", R, centres - centres[a])
    free_t = problem.free[:, TRANS]
    score = np.where(free_t, np.abs(d_t), 0.0)
    if scale_camera is not None:
        b = problem.camera_position(scale_camera)
    else:
        eligible = (counts >= np.median(counts[counts > 0])) if counts.any() else np.ones(C, bool)
        eligible[a] = False
        b = argmax_first(np.where(eligible, score.max(axis=1), -1.0), LENGTH_QUANTUM_CM)  # equal: first camera
    if b == a:
        raise BAProblemError("gauge: the scale camera must differ from the reference camera")
    k = argmax_first(score[b], LENGTH_QUANTUM_CM)
    if score[b, k] <= 1e-6 * (1.0 + np.abs(centres).max()):
        raise BAProblemError(f"gauge: camera {problem.camera_names[b]} cannot fix the scale "
                             f"(its centre coincides with {problem.camera_names[a]}'s or its translation is fixed)")
    if not pose_fixed[a]:
        held[a, 0:6] = problem.free[a, 0:6]
    held[b, 3 + k] = True
    inner = (mode is GaugeMode.AUTO and reference_camera is None and scale_camera is None
             and bool(problem.free[:, 0:6].all()))
    gauge = Gauge(mode=mode, reference_camera=problem.camera_names[a] if not pose_fixed[a] else None,
                  scale_camera=problem.camera_names[b], scale_component=k, held=held, inner=inner)
    logger.info("gauge: %s", gauge.describe())
    return gauge


def similarity_directions(camera_params: np.ndarray) -> np.ndarray:
    """(C, 15, 7) change of each camera's parameters under the 7 infinitesimal world similarities (translation x, y,
    z; rotation about x, y, z; scale) that leave every reprojection unchanged (the points move with the world).
    Intrinsics do not change. With x_cam = R X + t: X -> X + tau needs t -> t - R tau; X -> X + omega x X needs
    R -> R exp(-[omega]x), i.e. r -> r - J_r(r)^-1 omega for the additive rotation-vector update the solver uses
    (its Jacobians are d/dr of R(r), R(r + dr) = R exp([J_r(r) dr]x)); X -> (1 + s) X needs t -> (1 + s) t."""
    C = len(camera_params)
    N = np.zeros((C, 15, 7))
    R = rotvec_to_matrix(camera_params[:, ROT])
    N[:, 3:6, 0:3] = -R
    N[:, 0:3, 3:6] = -np.linalg.inv(right_jacobian(camera_params[:, ROT]))
    N[:, 3:6, 6] = camera_params[:, TRANS]
    return N


def inner_constraint_basis(camera_params: np.ndarray, free: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(C * 15, 7) B with S + B B^T the reduced system under inner constraints (module docstring), for the active
    cameras' parameters (C, 15), their free mask and the Levenberg-Marquardt scaling diagonal ``scale`` (C, 15):
    in the scaled unknowns y = sqrt(scale) x the 7 directions get an orthonormal basis Q and weight 1 (the scaled
    system's diagonal is at most 1), B = sqrt(scale) Q. Fixed parameters have zero rows."""
    d = np.sqrt(scale).reshape(-1)
    N = similarity_directions(camera_params) * free[:, :, None]
    Q, _ = np.linalg.qr(N.reshape(-1, 7) * d[:, None])
    return Q * d[:, None]
