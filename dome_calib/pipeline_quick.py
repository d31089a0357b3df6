"""Quick recalibration after a hardware change (`calibrate --prior OLD --only-changed`).

1. ``sfm`` on the first ``quick_scenes`` scenes only (default 1): matched observations and a rough reconstruction.
2. ``detect``: the reconstruction is put in the prior's frame (robust similarity, generous threshold); every
   camera is then held at its PRIOR calibration and only the points are fitted (robust loss). A camera that
   moved, turned or was replaced cannot explain its observations: its residual RMS stands out (a 1 deg turn is
   ~13 px on a VGA camera, a 2 cm shift ~4 px at the tent, a 4 % focal change ~10 px at the image edge, against
   ~0.2 px of feature noise). Two rounds: the second refits the points without the cameras flagged in the first,
   so a whole disturbed panel cannot drag the points with it. Cameras the prior does not know are changed too.
3. ``quick_ba``: bundle adjustment with only the changed cameras' poses free (and the points); then with all
   their parameters free: cameras whose residual RMS the new intrinsics lower by more than 4 % are replaced
   cameras and keep them, the others only moved and are re-posed with the prior's lens. Every other camera stays
   bit-identical to the prior, which also fixes the gauge and the world frame.
"""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from dome_calib.align import AlignOptions, align_cameras, sim3_apply, transform_cameras
from dome_calib.ba.problem import ParamGroup, camera_to_params
from dome_calib.ba.solver import bundle_adjust
from dome_calib.bundle import Bundle
from dome_calib.compare import CameraChange, camera_error
from dome_calib.normalize import Normalized, WorldReference
from dome_calib.pipeline_stages import SfmOutcome, ba_options, observation_residuals, run_ba_stage, run_sfm_stage

QUICK_BA = dataclasses.replace(ba_options(), compute_uncertainty=False)  # few free cameras: not needed

logger = logging.getLogger(__name__)

QUICK_SCENES = 1
ALIGN_MAX_ERROR_CM = 3.0  # the reconstruction before bundle adjustment is good to ~1 cm
RMS_FACTOR = 5.0  # changed: per-camera RMS under the prior above this many times the median ...
RMS_FLOOR_PX = 1.0  # ... and above this
#: A changed camera gets new intrinsics if freeing them lowers its RMS by more than this factor. Fitting 9 more
#: parameters to pure noise over N observations lowers it by sqrt((2N - 6) / (2N - 15)) (< 1.005 for N >= 900).
#: Set from one case (panel bench): a camera with a 4 % shorter focal, re-posed with its old lens, fits only 7 %
#: worse (the pose moves 9 cm along the axis instead); cameras that only moved: at most 1.5 %.
RELENS_RMS_RATIO = 1.04


def _robust_camera_rms(problem, used: np.ndarray) -> np.ndarray:
    """(C,) per-coordinate RMS of each camera's observations after trimming its worst 10 % (matching outliers)."""
    res = observation_residuals(problem)
    err = np.linalg.norm(res, axis=1)
    out = np.full(problem.n_cameras, np.nan)
    for c in range(problem.n_cameras):
        e = err[(problem.camera_index == c) & used & np.isfinite(err)]
        if len(e) >= 5:
            e = np.sort(e)[: max(5, int(0.9 * len(e)))]
            out[c] = np.sqrt(np.mean(e ** 2) / 2)
    return out


def detect_changed(sfm: SfmOutcome, prior: Bundle) -> dict:
    """Cameras inconsistent with the prior (see the module docstring) -> RMS px under the prior, plus the
    similarity that put the reconstruction in the prior's frame."""
    problem = sfm.problem
    sfm_cams = {n: problem.camera(n) for n in problem.camera_names}
    alignment = align_cameras(sfm_cams, prior.cameras, AlignOptions(max_error_cm=ALIGN_MAX_ERROR_CM))
    held = problem.copy()
    for i, n in enumerate(held.camera_names):
        if n in prior.cameras:
            held.camera_params[i] = camera_to_params(prior.cameras[n])
    held.points_cm = sim3_apply(alignment.tgt_from_src, problem.points_cm)
    held.fix(ParamGroup.ALL)
    new = [n for n in held.camera_names if n not in prior.cameras]
    flagged: set[str] = set(new)
    rms = np.full(held.n_cameras, np.nan)
    for _ in range(2):
        keep = ~np.isin(held.camera_index, [held.camera_position(n) for n in sorted(flagged)])
        fit = held.copy()
        fit.camera_index, fit.point_index, fit.uv_px = held.camera_index[keep], held.point_index[keep], held.uv_px[keep]
        fit.validate()
        result = bundle_adjust(fit, dataclasses.replace(QUICK_BA, outlier_rounds=1))
        held.points_cm = result.problem.points_cm
        rms = _robust_camera_rms(held, np.ones(held.n_observations, bool))
        ok = np.isfinite(rms)
        limit = max(RMS_FLOOR_PX, RMS_FACTOR * float(np.median(rms[ok]))) if ok.any() else RMS_FLOOR_PX
        flagged = set(new) | {n for n, r in zip(held.camera_names, rms) if np.isfinite(r) and r > limit}
    logger.info("quick recalibration: %d camera(s) inconsistent with the prior (limit %.2f px)", len(flagged), limit)
    return {"changed": sorted(flagged), "rms_under_prior_px": {n: float(r) for n, r in zip(held.camera_names, rms)},
            "limit_px": limit, "alignment": alignment, "held_points_cm": held.points_cm}


def run_quick(*, capture: Path, out: Path, seq: str, scenes: list[str], expected: list[str], prior: Bundle,
              options, stage, seconds: dict[str, float], resumed: list[str]):
    """The --only-changed run (called by :func:`dome_calib.pipeline.run_calibration`)."""
    from dome_calib.pipeline import finish

    work = Path(options.work_dir) if options.work_dir else out.with_name(out.name + ".work")
    sfm = stage("sfm", lambda: run_sfm_stage(capture, work / "sfm", prior=prior, progress=options.progress,
                                             scenes=scenes[:QUICK_SCENES]))
    det = stage("detect", lambda: detect_changed(sfm, prior))
    changed = det["changed"]

    def quick_ba():
        problem = sfm.problem.copy()
        sfm_in_prior = transform_cameras({n: problem.camera(n) for n in changed}, det["alignment"].tgt_from_src)
        for i, n in enumerate(problem.camera_names):
            cam = sfm_in_prior[n] if n in changed or n not in prior.cameras else prior.cameras[n]
            problem.camera_params[i] = camera_to_params(cam)
        problem.points_cm = det["held_points_cm"]
        problem.fix(ParamGroup.ALL)
        if not changed:
            return run_ba_stage(problem, progress=options.progress, options=QUICK_BA), []
        # A moved camera keeps its lens: re-pose first. Then everything of the changed cameras free; a camera whose
        # residual RMS the new intrinsics lower by more than noise fitting would (RELENS_RMS_RATIO) was replaced and
        # keeps them; the others keep the prior's lens (pose alone is the better-determined estimate).
        problem.unfix(ParamGroup.POSE, cameras=changed)
        posed = run_ba_stage(problem, progress=options.progress, options=QUICK_BA)
        trial = posed.problem.copy()
        trial.unfix(ParamGroup.ALL, cameras=changed)
        free_all = run_ba_stage(trial, progress=options.progress, options=QUICK_BA)
        rms_posed = _robust_camera_rms(posed.problem, posed.inlier)
        rms_free = _robust_camera_rms(free_all.problem, free_all.inlier)
        relensed = [n for n in changed if n not in prior.cameras
                    or rms_posed[problem.camera_position(n)] > RELENS_RMS_RATIO * rms_free[problem.camera_position(n)]]
        if not relensed:
            return posed, []
        if len(relensed) == len(changed):
            return free_all, relensed
        final = posed.problem.copy()
        final.unfix(ParamGroup.ALL, cameras=relensed)
        return run_ba_stage(final, progress=options.progress, options=QUICK_BA), relensed

    ba, relensed = stage("quick_ba", quick_ba)
    cameras = dict(prior.cameras)
    cameras.update({n: ba.cameras[n] for n in changed})
    changes = {}
    for n in changed:
        err = camera_error(ba.cameras[n], prior.cameras[n]) if n in prior.cameras else None
        reasons = [f"residual {det['rms_under_prior_px'][n]:.1f} px under the prior calibration"]
        if err is None:
            reasons = ["new camera (not in the prior)"]
        else:
            reasons.append(f"moved {err.center_cm:.1f} cm, rotated {err.rotation_deg:.2f} deg")
            if n in relensed:
                reasons.append(f"new intrinsics (focal {err.focal_pct:.1f} %, distortion {err.distortion_px:.1f} px):"
                               " replaced?")
        changes[n] = CameraChange(name=n, moved_cm=err.center_cm if err else float("nan"),
                                  rotated_deg=err.rotation_deg if err else float("nan"),
                                  focal_pct=err.focal_pct if err else float("nan"),
                                  distortion_px=err.distortion_px if err else float("nan"), reasons=reasons)
    normalized = Normalized(cameras=cameras, reference=WorldReference.PRIOR, alignment=det["alignment"],
                            reference_source=f"{options.prior} (unchanged cameras held)")
    return finish(out=out, seq=seq, expected=expected, failures=sfm.failures, normalized=normalized,
                  residuals=ba.residuals, prior=prior, options=options, seconds=seconds, resumed=resumed,
                  sfm=sfm, ba=ba, changes=changes, ba_scale=1.0,
                  source=f"dome-calib calibrate --only-changed {capture.name} ({len(changed)} cameras re-estimated)")
