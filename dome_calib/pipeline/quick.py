"""Quick recalibration after a hardware change (`calibrate --prior OLD --only-changed`).

The prior is right for most cameras, so one scene is enough and no mapping is needed:

1. ``match``: features, prior-based pairs (fewer per camera than a full run) and verified matches of the first
   scene (:func:`projector.scene.match_scene`). Images larger than DETECT_MAX_IMAGE_PX (HD, Kinect colour) are
   reduced by an integer factor for this round (their keypoints are still in full-resolution pixels).
2. ``detect``: every verified pair is tested against the PRIOR's relative pose and lenses (Sampson distance,
   :mod:`projector.consistency`); cameras most of whose pairs disagree are suspects (greedy, worst first, so
   an unchanged camera beside a disturbed panel is cleared once the panel is flagged). Cameras the prior does
   not know are suspects too. Only reads the database.
3. ``suspect_match``: a suspect whose image was reduced gets its features again at full resolution (its old
   features and matches are dropped first, so a rerun redoes exactly this); the suspects are then matched with
   more unchanged partners.
4. ``quick_ba``: the tent is triangulated from the unchanged partners of the suspects at their prior
   calibration (:func:`projector.known_poses.triangulate_known`); each suspect is registered against those
   points (absolute pose); bundle adjustment with only the suspects' poses free (and the points), then with
   all their parameters free: a camera whose residual RMS the new intrinsics lower by more than noise fitting
   would (RELENS_RMS_RATIO) was replaced and keeps them; the others keep the prior's lens. A suspect is
   confirmed as changed when its new calibration explains its observations clearly better than the prior
   (CONFIRM_RMS_RATIO); the others keep the prior bit for bit, as does every camera that was not a suspect,
   which also fixes the gauge and the world frame.
"""
from __future__ import annotations

import contextlib
import dataclasses
import logging
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import pycolmap

from dome_calib.align import Alignment
from dome_calib.ba.problem import ParamGroup, camera_to_params
from dome_calib.bundle import Bundle, CameraType
from dome_calib.compare import CameraChange, camera_error
from dome_calib.errors import DomeCalibError
from dome_calib.pipeline.capture import capture_nodes
from dome_calib.pipeline.cluster import cluster_section, open_executor, settle_cluster_stats
from dome_calib.executor import Executor, is_remote
from dome_calib.executor.local import make_executor
from dome_calib.normalize import Normalized, WorldReference
from dome_calib.pipeline.finish import finish
from dome_calib.pipeline.stages import (ba_options, observation_residuals, problem_from_observations,
                                        quiet_colmap, refine_notes, run_ba_stage)
from dome_calib.residuals import Residuals
from dome_calib.pipeline.types import BAOutcome, Calibrated, CalibrationInputs, CalibrationResult
from dome_calib.pipeline.workstate import WorkState
from dome_calib.progress import ProgressTasks
from dome_calib.reasons import ReasonCode, reason
from projector.consistency import changed_cameras, pair_errors
from projector.database import camera_of_image, drop_features
from projector.features import extract_features, nominal_camera, reduction_factor
from projector.known_poses import observations_from_known, register_cameras, triangulate_known, verified_partners
from projector.matching import match_pairs
from projector.pairs import PairOptions, pairs_from_prior
from projector.refine import refine_observations
from projector.scene import mapper_image_dir, match_scene, read_pairs, write_pairs
from projector.sfm_types import SfmOptions

QUICK_BA = dataclasses.replace(ba_options(), compute_uncertainty=False)  # few free cameras: not needed

logger = logging.getLogger(__name__)

#: Longer side (px) above which an image is reduced for the first round. 960 halves the HD and Kinect colour
#: images (1920x1080). An HD focal length is about twice a VGA camera's (1,455 against 745 px median on the dome),
#: so a halved HD image resolves the tent about as finely as a VGA camera, which is what detection needs; a halved
#: Kinect colour image (1,056 px) at 0.7 of that. Measured on one HD image of the full bench: SIFT 0.62 ->
#: 0.15 s, 5,698 -> 1,145 keypoints, which lie a median 0.14 px from a full-resolution keypoint. Suspects among
#: them are extracted again at full resolution before they are re-estimated.
DETECT_MAX_IMAGE_PX = 960
#: Pairs per camera in the first matching round (enough to judge every camera against the prior) ...
DETECT_PAIRS_PER_CAMERA = 12
#: ... and partners among the unchanged cameras matched to each suspect afterwards (its registration).
SUSPECT_PAIRS_PER_CAMERA = 25
#: A camera gets new intrinsics if freeing them lowers its RMS by more than this factor. Fitting 9 more
#: parameters to pure noise over N observations lowers it by sqrt((2N - 6) / (2N - 15)) (1.006 for N = 400).
#: Measured on the panel bench (one scene, 410-900 observations per camera): the camera with a 4 % shorter focal,
#: re-posed with its old lens, fits 4.0 % worse (the pose moves 9 cm along the axis instead); the 23 cameras that
#: only moved: at most 1.4 % (their free fit also moves the shared points). The threshold sits between.
RELENS_RMS_RATIO = 1.025
#: A suspect changed if its observations fit the prior this many times worse than its new calibration (an
#: unchanged camera: ~1; a 1 deg turn: ~10 px against a few tenths).
CONFIRM_RMS_RATIO = 1.5


@dataclass(kw_only=True)
class MatchedScene:
    """Stage ``match``: one scene's features, pairs and verified matches, in ``database``."""

    scene: str
    database: Path
    image_dir: Path
    cameras: list[str]  # cameras with features
    failures: dict[str, str]  # camera -> why its image is unusable
    pairs: int
    verified_pairs: int
    inlier_matches: int
    seconds: dict[str, float]  # features, matching


@dataclass(kw_only=True)
class Suspects:
    """Stage ``detect``: cameras inconsistent with the prior (or unknown to it); VGA panels suspect as a whole."""

    suspects: list[str]
    unknown: list[str]  # cameras the prior does not know
    bad_pair_px: float  # Sampson distance above which a pair disagrees with the prior
    panels: list[int] = field(default_factory=list)  # VGA panels suspect as a whole (the pairs leaving them bad)
    held_pair_px: float = float("nan")  # median Sampson distance (px) of the pairs of two non-suspects (nan: none)
    held_cameras: int = 0  # cameras with a verified pair that are not suspects (the ones the quick path holds)


@dataclass(kw_only=True)
class SuspectMatches:
    """Stage ``suspect_match``: suspects extracted again at full resolution (their first-round pairs matched
    again), and the extra pairs matched."""

    full_resolution: list[str]  # suspects whose first-round features came from a reduced image
    extra_pairs: int
    seconds: dict[str, float]  # features, matching


@dataclass(kw_only=True)
class Reestimated:
    """Stage ``quick_ba``: the suspects re-estimated, and which of them changed."""

    ba: BAOutcome | None  # None: no suspect, or none could be registered
    changed: list[str] = field(default_factory=list)
    relensed: list[str] = field(default_factory=list)  # changed cameras that got new intrinsics
    failed: dict[str, str] = field(default_factory=dict)  # suspect -> why it could not be re-estimated
    rms_prior_px: dict[str, float] = field(default_factory=dict)  # per suspect, under the prior
    rms_new_px: dict[str, float] = field(default_factory=dict)  # per suspect, re-estimated
    points: int = 0
    observations: int = 0
    held_cameras: int = 0  # unchanged partners the points were triangulated from
    unreadable: dict[str, str] = field(default_factory=dict)  # "scene/camera" -> why the refinement could not read it


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


def _options(progress: ProgressTasks | None, pairs_per_camera: int, max_image_size_px: int = 0) -> SfmOptions:
    options = SfmOptions(progress=progress)
    options.pairs.max_pairs_per_camera = pairs_per_camera
    options.features.max_image_size_px = max_image_size_px
    return options


def match_first_scene(capture: Path, work: Path, scene: str, prior: Bundle, progress: ProgressTasks | None, *,
                      executor: Executor | None = None, cameras: list[str] | None = None) -> MatchedScene:
    """Stage ``match``: features, pairs and verified matches of one scene, in ``work/<scene>/database.db``
    (``cameras``: the images are on the capture nodes, read by the executor's workers there)."""
    quiet_colmap()
    options = _options(progress, DETECT_PAIRS_PER_CAMERA, DETECT_MAX_IMAGE_PX)
    options.cameras = cameras
    with make_executor() if executor is None else contextlib.nullcontext(executor) as pool:
        feats, pairs, matches = match_scene(capture, work, scene, dict(prior.cameras), options, pool)
    return MatchedScene(scene=scene, database=work / scene / "database.db",
                        image_dir=mapper_image_dir(capture, work, scene, options),
                        cameras=sorted(feats.num_features), failures=dict(feats.failures), pairs=len(pairs),
                        verified_pairs=matches.num_verified_pairs, inlier_matches=matches.num_inlier_matches,
                        seconds={"features": feats.seconds, "matching": matches.seconds})


def detect_suspects(matched: MatchedScene, prior: Bundle) -> Suspects:
    """Stage ``detect``: cameras inconsistent with the prior, or unknown to it (module docstring)."""
    errors = pair_errors(str(matched.database), prior.cameras)
    panels = {n: c.panel for n, c in prior.cameras.items() if c.type == CameraType.VGA}  # rigid groups
    verdict = changed_cameras(errors, group_of=panels)
    unknown = [n for n in matched.cameras if n not in prior.cameras]
    # a panel suspect as a whole: all of its cameras with an image, also those without a usable pair
    on_panels = [n for n in matched.cameras if panels.get(n, -1) in verdict.changed_groups]
    suspects = sorted(set(verdict.changed) | set(verdict.unchecked) | set(unknown) | set(on_panels))
    for panel, (fraction, n_bad) in sorted(verdict.changed_groups.items()):
        logger.info("quick recalibration: panel %d suspect as a whole (%d of the pairs leaving it bad, %.0f %%)",
                    panel, n_bad, 100 * fraction)
    logger.info("quick recalibration: %d suspect camera(s) (bad pair above %.2f px)", len(suspects),
                verdict.bad_pair_px)
    s = set(suspects)
    held_errors = [e for (a, b), e in errors.items() if a not in s and b not in s]
    return Suspects(suspects=suspects, unknown=unknown, bad_pair_px=verdict.bad_pair_px,
                    panels=sorted(verdict.changed_groups),
                    held_pair_px=float(np.median(held_errors)) if held_errors else float("nan"),
                    held_cameras=len({n for pair in errors for n in pair} - s))


#: The quick path holds every camera it does not suspect at the prior: the prior still holds when at least
#: MIN_HELD_CAMERAS of them remain and their pairs agree with it to feature noise (a few tenths of a pixel; a
#: dome whose cameras all moved 2 cm: 1-4 px).
MIN_HELD_CAMERAS = 2
MAX_HELD_PAIR_PX = 1.0


class PriorNoLongerHolds(DomeCalibError):
    """--only-changed with a prior that most of the dome no longer agrees with."""


def check_prior_holds(det: Suspects, prior_source: str | Path, n_cameras: int) -> None:
    """PriorNoLongerHolds (one line, "run a full calibration") when the cameras the quick path would hold at the
    prior are too few or disagree with it themselves (MIN_HELD_CAMERAS, MAX_HELD_PAIR_PX)."""
    if det.held_cameras < MIN_HELD_CAMERAS:
        why = f"{len(det.suspects)} of {n_cameras} cameras disagree with it, {det.held_cameras} left to hold"
    elif not det.held_pair_px <= MAX_HELD_PAIR_PX:
        why = (f"even the {det.held_cameras} cameras that look unchanged disagree with it (median epipolar error "
               f"{det.held_pair_px:.2f} px, feature noise is a few tenths)")
    else:
        return
    raise PriorNoLongerHolds(f"--prior {prior_source}: no longer holds for this capture ({why}): too much changed for "
                             "--only-changed; run a full calibration (without --only-changed)")


def _image_sizes(database: str | Path) -> dict[str, tuple[int, int]]:
    """Camera name -> (width, height) of its image, as the scene database holds it."""
    with pycolmap.Database.open(str(database)) as db:
        cams = {camera_of_image(im.name): db.read_camera(im.camera_id) for im in db.read_all_images()}
    return {n: (c.width, c.height) for n, c in cams.items()}


def reduced_cameras(database: Path, cameras: list[str]) -> list[str]:
    """Those of ``cameras`` whose first-round features came from a reduced image (by the image size)."""
    sizes = _image_sizes(database)
    return [n for n in cameras if n in sizes and reduction_factor(*sizes[n], DETECT_MAX_IMAGE_PX) > 1]


def match_suspects(matched: MatchedScene, det: Suspects, prior: Bundle, capture: Path,
                   progress: ProgressTasks | None, *,
                   executor: Executor | None = None) -> SuspectMatches:
    """Stage ``suspect_match``: reduced suspects extracted again at full resolution (on the capture nodes when
    the executor's workers are there) and their first-round pairs matched again (those of ``pairs.txt``, so that
    a rerun after an interruption restores them all), then every suspect matched with SUSPECT_PAIRS_PER_CAMERA
    unchanged partners; ``pairs.txt`` then lists every pair matched."""
    suspects, seconds = det.suspects, {"features": 0.0, "matching": 0.0}
    full = reduced_cameras(matched.database, suspects)
    options = _options(progress, 0)
    pairs_file = matched.database.parent / "pairs.txt"
    first_round = read_pairs(pairs_file)
    with make_executor() if executor is None else contextlib.nullcontext(executor) as pool:
        again: list = []
        if full:
            dropped = drop_features(matched.database, full)
            feats = extract_features(capture / "scenes" / matched.scene, matched.database, prior=prior.cameras,
                                     options=options.features, executor=pool, scene=matched.scene, cameras=full)
            seconds["features"] = feats.seconds
            f = set(full)
            again = sorted(set(dropped) | {p for p in first_round if p[0] in f or p[1] in f})
            logger.info("quick recalibration: %d suspect(s) extracted again at full resolution", len(full))
        known = [n for n in matched.cameras if n in prior.cameras]
        s = set(suspects)
        extra = [p for p in pairs_from_prior(prior.cameras, known,
                                             PairOptions(max_pairs_per_camera=SUSPECT_PAIRS_PER_CAMERA))
                 if (p[0] in s) != (p[1] in s)]
        if extra or again:
            report = match_pairs(str(matched.database), sorted(set(extra) | set(again)), options=options.matching,
                                 executor=pool, scene=matched.scene)
            seconds["matching"] = report.seconds
            write_pairs(pairs_file, sorted(set(first_round) | set(extra) | set(again)))
    return SuspectMatches(full_resolution=full, extra_pairs=len(extra), seconds=seconds)


def reestimate(matched: MatchedScene, det: Suspects, prior: Bundle, work: Path, *, capture: Path | None = None,
               executor: Executor | None = None) -> Reestimated:
    """Stage ``quick_ba``: triangulate with the unchanged cameras, register and refine the suspects. The keypoint
    refinement's image work runs on ``executor`` with the scene's images as the capture has them (``capture``;
    default the mapper's image folder): on a cluster, where the images are."""
    suspects = det.suspects
    if not suspects:
        return Reestimated(ba=None)
    s = set(suspects)
    database = str(matched.database)
    graph = verified_partners(database)
    partners = {p for n in suspects for p in graph.get(n, ())} - s  # unchanged cameras paired with a suspect
    if len(partners) < MIN_HELD_CAMERAS:  # the known-pose triangulation needs two posed images
        raise PriorNoLongerHolds(f"the suspects ({', '.join(suspects[:3])}{', ...' if len(suspects) > 3 else ''}) "
                                 f"share verified pairs with {len(partners)} unchanged camera(s), need "
                                 f"{MIN_HELD_CAMERAS}: run a full calibration (without --only-changed)")
    cameras = dict(prior.cameras)
    if det.unknown:
        sizes = _image_sizes(database)
        for n in det.unknown:
            cameras[n] = nominal_camera(n, sizes[n])
    rec = triangulate_known(database, str(matched.image_dir), work / "known_points", cameras, partners)
    regs, failed = register_cameras(database, rec, cameras, suspects)
    for n, why in failed.items():
        logger.warning("quick recalibration: %s could not be re-estimated: %s", n, why)
    if not regs:
        return Reestimated(ba=None, failed=failed)
    observations = observations_from_known(rec, cameras, regs, matched.scene)
    # issue 36: every track's keypoints aligned across its views (projector.refine), as in the full calibration
    image_dir = capture / "scenes" / matched.scene if capture is not None else matched.image_dir
    observations, refined = refine_observations(observations, {matched.scene: image_dir},
                                                executor=executor if is_remote(executor) else None)
    problem = problem_from_observations(observations)
    free = sorted(regs)
    # the suspects' observations under the prior, against points the unchanged cameras triangulated
    under_prior = problem.copy()
    for n in free:
        if n in prior.cameras:
            under_prior.camera_params[under_prior.camera_position(n)] = camera_to_params(prior.cameras[n])
    rms_prior = _robust_camera_rms(under_prior, np.ones(problem.n_observations, bool))
    problem.fix(ParamGroup.ALL)
    problem.unfix(ParamGroup.POSE, cameras=free)
    posed = run_ba_stage(problem, options=QUICK_BA)
    trial = posed.problem.copy()
    trial.unfix(ParamGroup.ALL, cameras=free)
    free_all = run_ba_stage(trial, options=QUICK_BA)
    rms_posed = _robust_camera_rms(posed.problem, posed.inlier)
    rms_free = _robust_camera_rms(free_all.problem, free_all.inlier)
    pos = {n: problem.camera_position(n) for n in free}
    relensed = [n for n in free if n not in prior.cameras or rms_posed[pos[n]] > RELENS_RMS_RATIO * rms_free[pos[n]]]
    if not relensed:
        ba = posed
    elif len(relensed) == len(free):
        ba = free_all
    else:
        final = posed.problem.copy()
        final.unfix(ParamGroup.ALL, cameras=relensed)
        ba = run_ba_stage(final, options=QUICK_BA)
    rms_new = _robust_camera_rms(ba.problem, ba.inlier)
    changed = [n for n in free if n not in prior.cameras
               or not rms_prior[pos[n]] <= CONFIRM_RMS_RATIO * rms_new[pos[n]]]
    cleared = sorted(set(free) - set(changed))
    if cleared:
        logger.info("quick recalibration: %s consistent with the prior after all (kept)", ", ".join(cleared))
    return Reestimated(ba=ba, changed=changed, relensed=[n for n in relensed if n in changed], failed=failed,
                       rms_prior_px={n: float(rms_prior[pos[n]]) for n in free},
                       rms_new_px={n: float(rms_new[pos[n]]) for n in free},
                       points=problem.n_points, observations=problem.n_observations, held_cameras=len(partners),
                       unreadable=refined.unreadable_images)


def changes_of(est: Reestimated, prior: Bundle) -> dict[str, CameraChange]:
    """The changed cameras with the reasons the report gives (residual under the prior, motion, new lens)."""
    changes = {}
    for n in est.changed:
        err = camera_error(est.ba.cameras[n], prior.cameras[n]) if n in prior.cameras else None
        if err is None:
            reasons = [reason(ReasonCode.NEW_CAMERA, "new camera (not in the prior)")]
        else:
            reasons = [reason(ReasonCode.RESIDUAL_UNDER_PRIOR, f"residual {est.rms_prior_px[n]:.1f} px under the "
                              f"prior calibration ({est.rms_new_px[n]:.2f} px now)"),
                       reason(ReasonCode.MOVED, f"moved {err.center_cm:.1f} cm, rotated {err.rotation_deg:.2f} deg")]
            if n in est.relensed:
                reasons.append(reason(ReasonCode.INTRINSICS_CHANGED, f"new intrinsics (focal {err.focal_pct:.1f} %, "
                                      f"distortion {err.distortion_px:.1f} px): replaced?"))
        changes[n] = CameraChange(name=n, moved_cm=err.center_cm if err else float("nan"),
                                  rotated_deg=err.rotation_deg if err else float("nan"),
                                  focal_pct=err.focal_pct if err else float("nan"),
                                  distortion_px=err.distortion_px if err else float("nan"), reasons=reasons)
    return changes


def run_quick(inputs: CalibrationInputs, state: WorkState) -> CalibrationResult:
    """The --only-changed run: match one scene, find the suspects, re-estimate them, then :func:`finish`."""
    prior, progress = inputs.prior, inputs.options.progress
    work = state.folder / "quick"
    scene = inputs.scenes[0]
    options = inputs.options
    cameras = list(inputs.expected) if options.scheduler and capture_nodes(inputs.capture) else None
    cluster: dict = {}
    with open_executor(inputs.capture, options.scheduler, cluster) as executor:
        matched = state.run("match", partial(match_first_scene, inputs.capture, work, scene, prior, progress,
                                             executor=executor, cameras=cameras))
        det = state.run("detect", partial(detect_suspects, matched, prior))
        check_prior_holds(det, inputs.options.prior, len(matched.cameras))
        extra = state.run("suspect_match", partial(match_suspects, matched, det, prior, inputs.capture, progress,
                                                   executor=executor))
        est = state.run("quick_ba", partial(reestimate, matched, det, prior, work, capture=inputs.capture,
                                            executor=executor))
    cluster = settle_cluster_stats(state.folder / "cluster.json", cluster, resumed=all(
        s in state.resumed for s in ("match", "detect", "suspect_match", "quick_ba")))
    failures = {n: f"no usable image in {scene}: {why}" for n, why in matched.failures.items()}
    failures.update({n: f"changed since the prior but not re-estimated: {why}" for n, why in est.failed.items()})
    cameras = {n: c for n, c in prior.cameras.items() if n not in est.failed}
    cameras.update({n: est.ba.cameras[n] for n in est.changed})
    held = sorted(n for n in matched.cameras if n in prior.cameras and n not in est.changed and n not in est.failed)
    normalized = Normalized(cameras=cameras, reference=WorldReference.PRIOR, alignment=Alignment.identity(held),
                            reference_source=f"{inputs.options.prior} (unchanged cameras held)")
    unchecked = {n: reason(ReasonCode.NOT_CHECKED, f"not checked against the prior: no usable image in {scene} "
                           f"({why}); prior kept")
                 for n, why in matched.failures.items() if n in cameras and n not in est.changed}
    sigma_cm = est.ba.center_sigma if est.ba is not None else {}  # the prior's frame: already cm
    notes = {n: r for n, r in refine_notes(getattr(est, "unreadable", {})).items() if n in cameras}  # {}: before
    calibrated = Calibrated(normalized=normalized, failures=failures, changes=changes_of(est, prior),
                            notes={**notes, **unchecked},
                            residuals=est.ba.residuals if est.ba is not None else Residuals.empty(),
                            center_sigma_cm=sigma_cm,
                            rotation_sigma_deg=getattr(est.ba, "rotation_sigma_deg", {}) if est.ba is not None else {},
                            held={n: "held from the prior (agrees with it)" if n not in unchecked else
                                  "held from the prior (not checked)" for n in cameras if n not in est.changed},
                            cluster=cluster_section(cluster, ["re-estimation (known-pose triangulation, bundle adjustment)"]),
                            source=f"dome-calib calibrate --only-changed {inputs.capture.name} "
                                   f"({len(est.changed)} cameras re-estimated)")
    stats = {"scene": scene, "pairs": matched.pairs, "verified_pairs": matched.verified_pairs,
             "inlier_matches": matched.inlier_matches, "suspects": det.suspects, "suspect_panels": det.panels,
             "bad_pair_px": det.bad_pair_px, "full_resolution": extra.full_resolution,
             "extra_pairs": extra.extra_pairs, "points": est.points, "observations": est.observations,
             "held_cameras": est.held_cameras,
             "seconds": {**matched.seconds, **{f"suspect_{k}": v for k, v in extra.seconds.items()}}}
    return dataclasses.replace(finish(inputs, state, calibrated), ba=est.ba, stats={"quick": stats, "cluster": cluster})
