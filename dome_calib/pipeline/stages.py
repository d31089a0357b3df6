"""The calibrate pipeline's two heavy stages, as thin adapters over the SfM front end (``projector``) and the
bundle adjustment (:mod:`dome_calib.ba`): what they return is what the pipeline keeps in its work folder.

The SfM hands its own :class:`projector.observations.Observations`; :func:`problem_from_observations` builds the
solver's :class:`BAProblem` from them here, so neither side knows the other's types.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pycolmap

from dome_calib.ba.lens_model import LensModelOptions, select_lens_model, warm_solver
from dome_calib.ba.problem import BAProblem
from dome_calib.ba.result import BAResult
from dome_calib.ba.schur import Workspace
from dome_calib.ba.solver import BAOptions, bundle_adjust, solution_uncertainty
from dome_calib.bundle import Bundle, Camera
from dome_calib.camera import project
from dome_calib.errors import CaptureError
from dome_calib.residuals import Residuals, observed_minus_projected
from dome_calib.executor import Executor
from dome_calib.pipeline.types import BAOutcome, SfmOutcome
from dome_calib.progress import ProgressTasks
from dome_calib.reasons import Reason, ReasonCode, reason
from projector.observations import Observations
from projector.sfm import SfmOptions, report_dict, run_sfm

logger = logging.getLogger(__name__)


def observation_residuals(problem: BAProblem) -> np.ndarray:
    """(M, 2) observed - projected pixels for every observation at the problem's current parameters."""
    out = np.full((problem.n_observations, 2), np.nan)
    order = np.argsort(problem.camera_index, kind="stable")
    bounds = np.searchsorted(problem.camera_index[order], np.arange(problem.n_cameras + 1))
    for c in range(problem.n_cameras):
        rows = order[bounds[c]:bounds[c + 1]]
        if not len(rows):
            continue
        cam = problem.camera(problem.camera_names[c])
        proj = project(problem.points_cm[problem.point_index[rows]], cam.R[None], cam.t_cm[None], cam.intr[None],
                       cam.dist[None])
        out[rows] = observed_minus_projected(problem.uv_px[rows], proj.uv_px[0])
    return out


def residuals_of(problem: BAProblem, inlier: np.ndarray | None = None) -> Residuals:
    """The report's :class:`Residuals` of the (inlier) observations."""
    res = observation_residuals(problem)
    keep = np.all(np.isfinite(res), axis=1) if inlier is None else (inlier & np.all(np.isfinite(res), axis=1))
    return Residuals(camera_names=list(problem.camera_names), camera_index=problem.camera_index[keep],
                     residual_px=res[keep], uv_px=problem.uv_px[keep])


def problem_from_observations(observations: Observations) -> BAProblem:
    """The bundle-adjustment problem of the SfM's observations (everything free; fix what must stay)."""
    return BAProblem.from_cameras(observations.cameras, observations.scene_points_cm,
                                  camera_index=observations.camera_index, point_index=observations.point_index,
                                  uv_px=observations.uv_px, camera_names=observations.camera_names)


def quiet_colmap() -> None:
    """COLMAP's INFO lines drown the progress display: keep warnings and errors (unless debugging)."""
    if not logger.isEnabledFor(logging.DEBUG):
        pycolmap.logging.minloglevel = max(int(pycolmap.logging.minloglevel), 1)
        os.environ.setdefault("GLOG_minloglevel", "1")  # worker processes of the feature/matching executor


def run_sfm_stage(capture: Path, work_dir: Path, *, prior: Bundle | None, progress: ProgressTasks | None = None,
                  scenes: list[str] | None = None, executor: Executor | None = None,
                  cameras: list[str] | None = None) -> SfmOutcome:
    """Features, pairs, matching, per-scene mapping and merging (:func:`projector.sfm.run_sfm`), seeded by the
    prior bundle or, without one, the nominal dome layout. Raises CaptureError if no scene reconstructs."""
    quiet_colmap()
    result = run_sfm(capture, work_dir, SfmOptions(scenes=scenes, progress=progress, cameras=cameras),
                     prior=prior, executor=executor)
    if result.observations is None:
        why = "; ".join(f"{f.scene or 'capture'}: {f.reason}" for f in result.failures if not f.camera)
        raise CaptureError(f"{capture}: no scene could be reconstructed ({why or 'no registered cameras'})")
    problem, dropped = prune_problem(problem_from_observations(result.observations),
                                     prior=prior.cameras if prior is not None else None)
    return SfmOutcome(problem=problem, failures={**result.unregistered, **dropped}, stats=report_dict(result))


def refine_notes(unreadable: Mapping[str, str] | list[str]) -> dict[str, Reason]:
    """Per camera, the images of it the keypoint refinement could not read (its keypoints there stay as SIFT put
    them; :attr:`projector.refine.RefineReport.unreadable_images`, ``"scene/camera" -> why``): a reason to check it."""
    if not isinstance(unreadable, Mapping):  # a work folder of before: paths only
        unreadable = {f"{Path(p).parent.name}/{Path(p).stem}": f"unreadable ({p})" for p in unreadable}
    why: dict[str, list[str]] = {}
    for key, text in sorted(unreadable.items()):
        scene, camera = key.rsplit("/", 1)
        why.setdefault(camera, []).append(f"{scene}: {text}")
    return {c: reason(ReasonCode.KEYPOINTS_NOT_REFINED, f"keypoints not refined, image not read ({'; '.join(w)})")
            for c, w in why.items()}


#: Gate between SfM and BA: a camera needs this many observations, and a centre inside the gate, to enter the
#: bundle adjustment (SfM can leave a camera km away). The gate follows the prior's size and unit: a sphere around
#: the point the prior's cameras look at (least-squares meeting point of their optical axes) of CENTER_GATE_FACTOR
#: x their median distance from it (the Panoptic dome: 4 x 2.78 m = 11 m; one panel gives the same); without a
#: usable prior (none, or axes too close to parallel), the design's: MAX_CENTER_RADIUS_CM around the origin.
MIN_CAMERA_OBSERVATIONS = 50
CENTER_GATE_FACTOR = 4.0
MAX_CENTER_RADIUS_CM = 1000.0
_MIN_AXIS_SPREAD = 0.01  # smallest eigenvalue of sum(I - d d^T) / n: axes spread over more than ~6 degrees


def center_gate(prior: Mapping[str, Camera] | None) -> tuple[np.ndarray, float, str]:
    """(centre, radius, description) of the position gate for SfM cameras, in the prior's frame and unit."""
    if prior and len(prior) >= 2:
        centers = np.array([c.center_cm for c in prior.values()])
        axes = np.array([c.R[2] for c in prior.values()])  # optical axes in the world
        proj = np.eye(3) - axes[:, :, None] * axes[:, None, :]
        A = proj.sum(axis=0)
        if np.linalg.eigvalsh(A)[0] > _MIN_AXIS_SPREAD * len(prior):
            looked_at = np.linalg.solve(A, np.einsum("nij,nj->i", proj, centers))
            spread = float(np.median(np.linalg.norm(centers - looked_at, axis=1)))
            if spread > 0:
                radius = CENTER_GATE_FACTOR * spread
                return looked_at, radius, (f"the gate of radius {radius:.4g} around the point the prior's cameras "
                                           f"look at ({CENTER_GATE_FACTOR:g} x their median distance from it, in "
                                           "the prior's unit)")
    return np.zeros(3), MAX_CENTER_RADIUS_CM, f"the gate of radius {MAX_CENTER_RADIUS_CM:g} cm around the dome centre"


def prune_problem(problem: BAProblem, *, min_observations: int = MIN_CAMERA_OBSERVATIONS,
                  prior: Mapping[str, Camera] | None = None) -> tuple[BAProblem, dict[str, str]]:
    """Drop cameras the bundle adjustment cannot use (too few observations, outside :func:`center_gate` of the
    prior) with their observations, then points left with fewer than 2 observations. Returns the problem and
    camera -> reason. CaptureError (one line, saying why) if no camera is left."""
    counts = np.bincount(problem.camera_index, minlength=problem.n_cameras)
    centre, radius, gate = center_gate(prior)
    dropped, far = {}, {}
    for i, n in enumerate(problem.camera_names):
        distance = float(np.linalg.norm(problem.camera(n).center_cm - centre))
        if counts[i] < min_observations:
            dropped[n] = f"only {counts[i]} observations after SfM (need {min_observations})"
        elif not distance <= radius:
            far[n] = distance
            dropped[n] = f"SfM placed it {distance:.4g} from the centre, outside {gate}"
    if len(dropped) == problem.n_cameras:
        n_few = len(dropped) - len(far)
        example = f" (e.g. {min(far)} at {far[min(far)]:.4g})" if far else ""
        raise CaptureError(f"SfM: all {problem.n_cameras} cameras left out of the bundle adjustment: {len(far)} placed "
                           f"outside {gate}{example}, {n_few} with fewer than {min_observations} observations; is the "
                           "prior in the capture's unit (cm) and frame?")
    if not dropped:
        return problem, {}
    keep_cam = np.array([n not in dropped for n in problem.camera_names])
    obs = keep_cam[problem.camera_index]
    pt_counts = np.bincount(problem.point_index[obs], minlength=problem.n_points)
    obs &= pt_counts[problem.point_index] >= 2
    keep_pt = np.bincount(problem.point_index[obs], minlength=problem.n_points) >= 2
    new_cam = np.cumsum(keep_cam) - 1
    new_pt = np.cumsum(keep_pt) - 1
    starts = np.concatenate([[0], np.cumsum([keep_pt[a:b].sum() for a, b in
                                             zip(problem.scene_point_start[:-1], problem.scene_point_start[1:])])])
    names = [n for n in problem.camera_names if n not in dropped]
    pruned = BAProblem(camera_names=names, cameras=[c for c, k in zip(problem.cameras, keep_cam) if k],
                       camera_params=problem.camera_params[keep_cam], free=problem.free[keep_cam],
                       points_cm=problem.points_cm[keep_pt], scene_names=list(problem.scene_names),
                       scene_point_start=starts.astype(np.int64), camera_index=new_cam[problem.camera_index[obs]],
                       point_index=new_pt[problem.point_index[obs]], uv_px=problem.uv_px[obs])
    for n, why in dropped.items():
        logger.warning("camera %s left out of the bundle adjustment: %s", n, why)
    return pruned, dropped


def ba_options() -> BAOptions:
    """The bundle adjustment as calibrate runs it (the solver's defaults: Huber, outlier rounds, then least
    squares), with the parameter uncertainties the report uses to flag poorly determined cameras and the lens
    model selection uses to choose each camera's free lens terms."""
    return BAOptions(compute_uncertainty=True)


def _with_uncertainty(result: BAResult, options: BAOptions, workspace: Workspace | None = None) -> BAResult:
    """The result with its camera uncertainties (the covariance, not the solve, can fail on a near-singular
    system: then without them, with a warning)."""
    try:
        result.uncertainty = solution_uncertainty(result, n_threads=options.n_threads, workspace=workspace)
    except np.linalg.LinAlgError as exc:
        logger.warning("bundle adjustment: no parameter uncertainties (%s)", exc)
    return result


def run_ba_stage(problem: BAProblem, *, options: BAOptions | None = None,
                 lens: LensModelOptions | None = None) -> BAOutcome:
    """Bundle adjustment with the outlier schedule (:func:`dome_calib.ba.bundle_adjust`); the problem's free mask
    is the most that is refined (quick recalibration frees only the changed cameras).

    When the solver computes uncertainties (calibrate's :func:`ba_options`), each camera's lens model is chosen
    first (:func:`dome_calib.ba.lens_model.select_lens_model`, rule ``lens``: a solve with the focal lengths as
    the only free lens terms, then only the lens terms the observations determine or need are freed for the
    final solve; the others stay at the prior). Without uncertainties (the quick path's solver options) the
    given free mask is used as it is, in one solve."""
    options = options or ba_options()
    lens_model = None
    t0, cpu0 = time.perf_counter(), time.process_time()
    if options.compute_uncertainty:
        solve_only = dataclasses.replace(options, compute_uncertainty=False)  # uncertainties once, at the end
        # one workspace for every solve, quadratic model and the uncertainties: their large arrays share pages
        workspace = Workspace()
        result, chosen = select_lens_model(problem, warm_solver(solve_only, workspace), lens,
                                           n_threads=options.n_threads, workspace=workspace)
        result = _with_uncertainty(result, options, workspace)
        del workspace
        lens_model = chosen.as_dict()
    else:
        result = bundle_adjust(problem, options)
    refined = result.problem
    used = np.asarray(result.used, dtype=bool)
    sigma, rot_sigma = {}, {}
    if result.uncertainty is not None:
        u = result.uncertainty
        s3 = u.sigma_center_centroid_cm if u.sigma_center_centroid_cm is not None else u.sigma_center_cm
        sigma = {n: float(np.linalg.norm(s3[i])) for i, n in enumerate(refined.camera_names)
                 if refined.free[i].any() and np.all(np.isfinite(s3[i]))}
        rot_sigma = {n: float(np.linalg.norm(u.sigma_rot_deg[i])) for i, n in enumerate(refined.camera_names)
                     if refined.free[i].any() and np.all(np.isfinite(u.sigma_rot_deg[i]))}
    projected_px = refined.uv_px + np.asarray(result.residuals_px)  # the solver's residual: projected - observed
    return BAOutcome(problem=refined, cameras={n: refined.camera(n) for n in refined.camera_names},
                     residuals=Residuals(camera_names=list(refined.camera_names), camera_index=refined.camera_index[used],
                                         residual_px=observed_minus_projected(refined.uv_px[used], projected_px[used]),
                                         uv_px=refined.uv_px[used]),
                     inlier=used,
                     stats={"iterations": len(result.iterations), "cost": result.cost, "rms_px": result.rms_px,
                            "sigma_px": result.sigma_px, "n_used": int(used.sum()),
                            "n_rejected": int((~used).sum()), "seconds": time.perf_counter() - t0,
                            "cpu_seconds": time.process_time() - cpu0,
                            "iterations_per_solve": lens_model["iterations_per_solve"] if lens_model else
                            [len(result.iterations)],
                            "solves": lens_model["solves"] if lens_model else 1,
                            "termination": list(result.termination)},
                     center_sigma=sigma, rotation_sigma_deg=rot_sigma, lens_model=lens_model)
