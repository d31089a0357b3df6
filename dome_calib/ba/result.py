"""What a bundle adjustment returns: refined problem, per-camera residual statistics, log, uncertainties."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dome_calib.ba.evaluate import residuals
from dome_calib.ba.gauge import Gauge
from dome_calib.ba.problem import BAProblem
from dome_calib.ba.schur import Structure
from dome_calib.bundle import Bundle


@dataclass(kw_only=True)
class IterationLog:
    """One accepted LM iteration. cost = 0.5 * sum rho(|r|^2) (px^2); rms_px per coordinate over the stage's
    observations (plain, whatever the loss); step_norm in parameter units; lam the damping after the step;
    factorisations: of the reduced camera system in this iteration (one per step tried; 0 for a step on the last
    iteration's factor, :func:`dome_calib.ba.schur.chord_step`); shortened: the step taken is the last rejected
    step shortened along its direction (``BAOptions.shorten_rejected_steps``), not counted in rejected_steps."""

    stage: int
    iteration: int
    cost: float
    rms_px: float
    step_norm: float
    lam: float
    rejected_steps: int
    time_s: float
    factorisations: int = 1
    reduced_systems: int = 1  # built in this iteration (a retry on the same system builds none)
    shortened: bool = False


@dataclass(kw_only=True)
class CameraUncertainty:
    """Standard deviations (C, ...) from the reduced camera system, scaled by the estimated pixel noise.

    sigma_intr_px (C, 4) [fx, fy, cx, cy]; sigma_dist (C, 5); sigma_rot_deg (C, 3) of the rotation vector;
    sigma_center_cm (C, 3) of the camera centre, relative to the gauge (the held reference camera and scale);
    sigma_center_centroid_cm (C, 3) or None: the same in the gauge of the camera centroid, mean orientation and
    mean radius (what matters after normalisation to the world frame). Held parameters have zero sigma.
    """

    sigma_intr_px: np.ndarray
    sigma_dist: np.ndarray
    sigma_rot_deg: np.ndarray
    sigma_center_cm: np.ndarray
    sigma_center_centroid_cm: np.ndarray | None


@dataclass(kw_only=True)
class BAResult:
    """Result of :func:`dome_calib.ba.bundle_adjust`.

    problem: refined copy of the input (same observations and free mask). inlier (M,) bool: observations
    within the outlier threshold; used (M,) bool: those in the final solve (inliers of points still seen at
    least twice). residuals_px (M, 2) projected - observed (the solver's sign) at the solution for every
    observation. camera_rms_px (C,) per-coordinate RMS of used observations; camera_n_obs (C,) used count;
    camera_n_rejected (C,). cost: 0.5 * sum |r|^2 over used observations (px^2) (the final stage's loss);
    rms_px per coordinate; sigma_px = sqrt(2 cost / (2 n_used - n_params)) (noise estimate); n_params: free
    camera parameters + 3 x refined points.
    """

    problem: BAProblem
    used: np.ndarray
    inlier: np.ndarray
    residuals_px: np.ndarray
    camera_rms_px: np.ndarray
    camera_n_obs: np.ndarray
    camera_n_rejected: np.ndarray
    cost: float
    rms_px: float
    sigma_px: float
    n_params: int
    gauge: Gauge
    iterations: list[IterationLog]
    termination: list[str]
    outlier_threshold_px: float | None
    uncertainty: CameraUncertainty | None = None
    time_s: float = 0.0
    extra: dict = field(default_factory=dict)

    def to_bundle(self, **kwargs) -> Bundle:
        """The refined cameras as a :class:`Bundle` (see :meth:`BAProblem.to_bundle` for the arguments)."""
        return self.problem.to_bundle(**kwargs)

    def camera_report(self) -> dict[str, dict]:
        """Per camera (by name): rms_px, n_obs, n_rejected and, if computed, the standard deviations."""
        out = {}
        for i, name in enumerate(self.problem.camera_names):
            row = {"rms_px": float(self.camera_rms_px[i]), "n_obs": int(self.camera_n_obs[i]),
                   "n_rejected": int(self.camera_n_rejected[i])}
            u = self.uncertainty
            if u is not None:
                row |= {"sigma_intr_px": u.sigma_intr_px[i].tolist(), "sigma_dist": u.sigma_dist[i].tolist(),
                        "sigma_rot_deg": u.sigma_rot_deg[i].tolist(), "sigma_center_cm": u.sigma_center_cm[i].tolist()}
                if u.sigma_center_centroid_cm is not None:
                    row["sigma_center_centroid_cm"] = u.sigma_center_centroid_cm[i].tolist()
            out[name] = row
        return out


def camera_statistics(problem: BAProblem, st: Structure, inlier: np.ndarray, *, gauge: Gauge,
                      iterations: list[IterationLog], termination: list[str],
                      outlier_threshold_px: float | None) -> BAResult:
    """Residual statistics of a refined problem for the observations of structure ``st``."""
    C, M = problem.n_cameras, problem.n_observations
    r = residuals(problem.camera_params, problem.points_cm, problem.camera_index, problem.point_index,
                  problem.uv_px)
    used = np.zeros(M, dtype=bool)
    used[st.obs] = True
    sq = np.where(used, np.sum(np.nan_to_num(r, nan=0.0) ** 2, axis=1), 0.0)
    n_obs = np.bincount(problem.camera_index[used], minlength=C)
    sum_sq = np.bincount(problem.camera_index, weights=sq, minlength=C)
    cam_rms = np.sqrt(sum_sq / np.maximum(2 * n_obs, 1))
    cam_rms[n_obs == 0] = np.nan
    n_rejected = np.bincount(problem.camera_index[~inlier], minlength=C)
    cost = 0.5 * float(sq.sum())
    n_used = int(used.sum())
    n_params = len(st.free_flat) + 3 * int(st.live_points.sum())
    dof = max(2 * n_used - n_params, 1)
    return BAResult(problem=problem, used=used, inlier=inlier.copy(), residuals_px=r, camera_rms_px=cam_rms, camera_n_obs=n_obs,
                    camera_n_rejected=n_rejected, cost=cost, rms_px=float(np.sqrt(2 * cost / max(2 * n_used, 1))),
                    sigma_px=float(np.sqrt(2 * cost / dof)), n_params=n_params, gauge=gauge,
                    iterations=iterations, termination=termination, outlier_threshold_px=outlier_threshold_px)
