"""Fixing the 7-dof similarity gauge of a bundle adjustment explicitly.

Reprojections do not change if the whole scene (cameras and points) is rotated, translated and scaled, so
the normal equations are singular in 7 directions. We remove them exactly by holding parameters constant,
like COLMAP's TWO_CAMS_FROM_WORLD gauge:

- the full pose (rotation vector and translation) of a reference camera A fixes rotation and translation (6);
- one translation component of a second camera B fixes the scale (1). Scaling about A's centre changes
  ``t_B`` by ``-R_B (c_B - c_A)`` per unit scale; we hold the component where that is largest.

Why this choice rather than a prior or inner constraints: it is exact (no weight to tune, nothing drifts), it
removes the 7 unknowns from the reduced camera system so that stays positive definite for a plain Cholesky,
it is the same gauge as the COLMAP peer in the benchmark, and the world frame is set afterwards by
normalisation (a similarity) anyway. Parameter uncertainties are therefore relative to camera A and to the
A-B scale; :mod:`dome_calib.ba.uncertainty` also gives centre uncertainties in the gauge of the camera
centroid (the one that matters after normalisation).

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
from dome_calib.rotation import rotvec_to_matrix

logger = logging.getLogger(__name__)


class GaugeMode(StrEnum):
    AUTO = "auto"  # two cameras unless the user's fixed poses already fix the gauge
    TWO_CAMERAS = "two_cameras"  # always hold camera A's pose and one translation component of camera B
    USER = "user"  # the user's fixed parameters fix the gauge (checked: >= 2 cameras with fixed pose)


@dataclass(kw_only=True)
class Gauge:
    """What was held to fix the gauge. ``held`` (C, 15) bool: parameters held for the gauge only."""

    mode: GaugeMode
    reference_camera: str | None
    scale_camera: str | None
    scale_component: int | None  # 0, 1, 2 = t_x, t_y, t_z of the scale camera
    held: np.ndarray

    def describe(self) -> str:
        if self.reference_camera is None and self.scale_camera is None:
            return "gauge fixed by the user's fixed camera poses"
        parts = []
        if self.reference_camera is not None:
            parts.append(f"pose of {self.reference_camera} held")
        if self.scale_camera is not None:
            parts.append(f"t_{'xyz'[self.scale_component]} of {self.scale_camera} held (scale)")
        return ", ".join(parts)


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
    gauge = Gauge(mode=mode, reference_camera=problem.camera_names[a] if not pose_fixed[a] else None,
                  scale_camera=problem.camera_names[b], scale_component=k, held=held)
    logger.info("gauge: %s", gauge.describe())
    return gauge
