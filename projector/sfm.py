"""The projector-pattern SfM front end in one call: capture folder -> cameras, points and observations of all scenes.

:func:`run_sfm` is a straight run of the stages (hloc style), each also callable on its own:

    features   every scene's images         :func:`projector.scene.scene_features` (:mod:`projector.features`)
    pairs      prior-based, or by the reference's geometry   :func:`projector.scene.select_pairs`,
                                                             :func:`projector.scene.known_scene_pairs`
    matching   verified matches per pair    :func:`projector.scene.match_scene` (:mod:`projector.matching`)
    mapping    the reference with GLOMAP, the others at its poses   :func:`projector.scene.scene_models`
               (:mod:`projector.mapping`, :mod:`projector.known_scene`)
    merge      every scene into the prior's frame   :func:`projector.merge.merge_scenes`
    refine     every track's keypoints across its views   :func:`projector.refine.refine_observations` (each
               image's work a task on the executor: :mod:`projector.refine_images`)

Order: the reference scene (the most images with features, ties by name) is matched and mapped with GLOMAP,
refining focal lengths; every other scene is matched on fewer pairs chosen by the reference's geometry and
triangulated with the cameras held at the reference's poses and intrinsics (:mod:`projector.known_scene`),
falling back on the full pair set and GLOMAP when that gives too little (logged, and said in the report).
``SfmOptions.known_poses.enabled = False``, or a reference with fewer than ``known_poses.min_images`` images (40: a
small capture's GLOMAP runs take seconds), maps every scene with GLOMAP on the prior's pairs, holding the prior's
intrinsics (slower on the dome; measured in the README). The reference's GLOMAP runs in a thread while the process
pool extracts the other scenes' features; the later scenes are matched, then triangulated together
(:func:`projector.scene.scene_models`: the same result).

Work folder layout (everything resumable)::

    WORK/<scene>/database.db     COLMAP database (open it in COLMAP with CAPTURE/scenes/<scene> as image folder)
    WORK/<scene>/pairs.txt       the matched pairs, one "a.png b.png" per line
    WORK/<scene>/sparse/<k>/     pycolmap models of GLOMAP (the reference scene, and any scene that fell back);
                                 written into WORK/<scene>/.sparse.new.*/ and renamed when complete
    WORK/<scene>/known/model/    pycolmap model of a scene triangulated with the reference's poses
    WORK/<scene>/known/reference.json   the reference model it was made from (a digest: reused only if it matches)
"""
from __future__ import annotations

import contextlib
import json
import logging
import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from dome_calib.bundle import Bundle, Camera
from dome_calib.bundle_io import load_bundle
from dome_calib.errors import CaptureError
from dome_calib.executor import Executor, is_remote
from dome_calib.executor.local import make_executor
from dome_calib.io_utils import atomic_write_text
from dome_calib.layout import nominal_dome
from projector.database import camera_of_image
from projector.features import nominal_camera
from projector.mapping import SceneModel
from projector.merge import MergeOptions, MergeResult, merge_scenes
from projector.refine import RefineReport, refine_observations
from projector.scene import known_scene_pairs, scene_models, select_pairs
from projector.sfm_types import CameraFailure, SceneStats, SfmOptions, SfmResult

__all__ = ["CameraFailure", "SfmOptions", "SfmResult", "known_scene_pairs", "report_dict", "run_sfm", "select_pairs"]

logger = logging.getLogger(__name__)


def prior_cameras(prior: Bundle | Mapping[str, Camera] | str | Path | None) -> dict[str, Camera]:
    """The prior's cameras by name (a Bundle, cameras, or a bundle folder); the nominal dome when None."""
    if prior is None:
        return dict(nominal_dome("full", 0).cameras)
    if isinstance(prior, (str, Path)):
        return dict(load_bundle(prior).cameras)
    if isinstance(prior, Bundle):
        return dict(prior.cameras)
    return dict(prior)


def list_scenes(capture_dir: Path, wanted: list[str] | None) -> list[str]:
    scenes_dir = capture_dir / "scenes"
    if not scenes_dir.is_dir():
        raise CaptureError(f"{capture_dir}: no scenes/ folder (expected CAPTURE/scenes/<scene>/<camera>.png)")
    found = sorted(p.name for p in scenes_dir.iterdir() if p.is_dir() and any(p.glob("*.png")))
    if wanted:
        missing = [s for s in wanted if s not in found]
        if missing:
            raise CaptureError(f"{scenes_dir}: scene {missing[0]!r} not found (have: {', '.join(found)})")
        found = list(wanted)
    if not found:
        raise CaptureError(f"{scenes_dir}: no scene folder with PNG images")
    return found


def run_sfm(
    capture_dir: str | Path, work_dir: str | Path, options: SfmOptions | None = None,
    prior: Bundle | Mapping[str, Camera] | str | Path | None = None, executor: Executor | None = None,
) -> SfmResult:
    """Run the whole front end on a capture folder: features, pairs, matching, mapping, merge (module docstring).

    Args:
        capture_dir: ``CAPTURE`` with ``scenes/<scene>/<camera>.png``.
        work_dir: where databases and models go (reruns reuse them).
        prior: a previous calibration (Bundle, cameras by name, or a bundle folder); default the nominal dome
            layout. It seeds intrinsics, pair selection and the output frame (cm, Panoptic world).
        executor: task executor for features, matching and the refinement's image work (default: local process pool).
    Returns:
        :class:`SfmResult`; ``observations`` is None only if no scene reconstructed (``failures`` says why).
    Example:
        >>> result = run_sfm("capture", "work", prior="previous_bundle")
        >>> result.observations.camera_names[:3], len(result.observations.uv_px)
    """
    options = options or SfmOptions()
    capture_dir, work_dir = Path(capture_dir), Path(work_dir)
    scenes = list(options.scenes) if options.cameras is not None and options.scenes else list_scenes(capture_dir, options.scenes)
    prior_cams = prior_cameras(prior)
    t0 = time.perf_counter()
    # our own pool is stopped at once (workers quiet) if a scene fails or the run is interrupted
    with make_executor(options.num_workers) if executor is None else contextlib.nullcontext(executor) as pool:
        # every scene: features, the reference (pairs, matching, GLOMAP), the others at its poses
        models = scene_models(capture_dir, work_dir, scenes, prior_cams, options, pool)
        stats, options, ref_options = models.scenes, models.options, models.reference_options
        t_scenes = time.perf_counter() - t0
        # merge: every scene into the prior's frame
        t1 = time.perf_counter()
        merge_options = replace(options.merge, use_colmap_intrinsics=options.merge.use_colmap_intrinsics
                                or ref_options.mapping.refine_focal_length or options.mapping.refine_principal_point)
        merged, merge_failures = _merge(stats, prior_cams, merge_options)
        t_merge = time.perf_counter() - t1
        # refine: every track's keypoints aligned across its views, each image's work where the image is: on a
        # cluster, the node that extracted its features; here, in threads (no patches moved between processes)
        observations, refined = merged.observations if merged else None, None
        if observations is not None and options.refine.enabled:
            observations, refined = refine_observations(observations, lambda s: capture_dir / "scenes" / s,
                                                        options.refine, executor=pool if is_remote(pool) else None)
    failures = _scene_failures(stats) + merge_failures + _refine_failures(refined)
    cameras = merged.observations.cameras if merged else {}
    seconds = {"features": sum(s.features.seconds for s in stats.values()),
               "matching": sum(s.matches.seconds for s in stats.values()),
               "mapping": sum(s.model.seconds for s in stats.values()),
               "scenes": t_scenes, "merge": t_merge, "refine": refined.seconds if refined else 0.0,
               "total": time.perf_counter() - t0}
    result = SfmResult(observations=observations, cameras=cameras, scenes=stats,
                       failures=failures, unregistered=_unregistered(stats, cameras, failures),
                       scene_alignment=merged.scene_alignment if merged else {},
                       prior_alignment=merged.prior_alignment if merged else None, seconds=seconds, refine=refined)
    atomic_write_text(work_dir / "sfm_report.json", json.dumps(report_dict(result), indent=1))
    return result


def _scene_failures(stats: Mapping[str, SceneStats]) -> list[CameraFailure]:
    """Per scene: the cameras whose features failed, those its model did not register, and a model that failed."""
    failures: list[CameraFailure] = []
    for s in stats.values():
        failures += [CameraFailure(camera=c, scene=s.scene, stage="features", reason=r)
                     for c, r in sorted(s.features.failures.items())]
        failures += [CameraFailure(camera=c, scene=s.scene, stage="mapping", reason=r)
                     for c, r in sorted(s.model.unregistered.items())]
        if s.model.failure:
            failures.append(CameraFailure(camera="", scene=s.scene, stage="mapping", reason=s.model.failure))
    return failures


def _refine_failures(refined: RefineReport | None) -> list[CameraFailure]:
    """The images the refinement could not read (their keypoints stay as SIFT put them), per camera and scene."""
    return [CameraFailure(camera=key.rsplit("/", 1)[1], scene=key.rsplit("/", 1)[0], stage="refine", reason=why)
            for key, why in (refined.unreadable_images.items() if refined else ())]


def _merge(stats: Mapping[str, SceneStats], prior_cams: Mapping[str, Camera], options: MergeOptions
           ) -> tuple[MergeResult | None, list[CameraFailure]]:
    """The scenes merged into the prior's frame (None when no scene can be) and the merge's failures. Cameras seen
    in the images but unknown to the prior get nominal intrinsics (their poses from the scenes)."""
    cameras = dict(prior_cams)
    for s in stats.values():
        for c in s.model.registered:
            if c not in cameras:
                rec = s.model.reconstruction
                rec_cam = rec.camera(rec.find_image_with_name(f"{c}.png").camera_id)
                cameras[c] = nominal_camera(c, (rec_cam.width, rec_cam.height))
    try:
        merged = merge_scenes([s.model for s in stats.values()], cameras, options, align_to=set(prior_cams))
    except ValueError as exc:
        return None, [CameraFailure(camera="", scene="", stage="merge", reason=str(exc))]
    return merged, ([CameraFailure(camera="", scene=sc, stage="merge", reason=r)
                     for sc, r in merged.unaligned_scenes.items()]
                    + [CameraFailure(camera=c, scene=sc, stage="merge", reason=r)
                       for (sc, c), r in merged.excluded.items()])


def _unregistered(stats: Mapping[str, SceneStats], cameras: Mapping[str, Camera],
                  failures: list[CameraFailure]) -> dict[str, str]:
    """Cameras seen in the images but registered in no scene, with every reason the scenes gave."""
    reasons: dict[str, list[str]] = {}
    for f in failures:
        if f.camera:
            reasons.setdefault(f.camera, []).append(f"{f.scene}: {f.reason}")
    seen = sorted({c for s in stats.values() for c in (*s.features.num_features, *s.features.failures)})
    unregistered = {c: "; ".join(reasons.get(c, ["not registered"])) for c in seen if c not in cameras}
    for c, r in unregistered.items():
        logger.warning("camera %s not registered in any scene: %s", c, r)
    return unregistered


def num_observations(model: SceneModel) -> int:
    """Observations (track elements) of the scene's points in its registered cameras' images."""
    rec = model.reconstruction
    if rec is None:
        return 0
    registered = set(model.registered)
    return sum(rec.image(i).num_points3D for i in rec.reg_image_ids() if camera_of_image(rec.image(i).name) in registered)


def report_dict(result: SfmResult) -> dict:
    """JSON-ready summary: per scene counts, failures per camera, alignment residuals."""
    return {
        "registered_cameras": sorted(result.cameras),
        "unregistered": result.unregistered,
        "failures": [f.__dict__ for f in result.failures],
        "scenes": {s: {"images": len(st.features.num_features) + len(st.features.failures),
                       "features_mean": (sum(st.features.num_features.values()) / max(len(st.features.num_features), 1)),
                       "pairs": st.pairs, "verified_pairs": st.matches.num_verified_pairs,
                       "inlier_matches": st.matches.num_inlier_matches, "registered": len(st.model.registered),
                       "mapping": st.mapping, **({"fallback": st.fallback} if st.fallback else {}),
                       "points": st.model.reconstruction.num_points3D() if st.model.reconstruction else 0,
                       "observations": num_observations(st.model),
                       "seconds": {"features": round(st.features.seconds, 1), "matching": round(st.matches.seconds, 1),
                                   "mapping": round(st.model.seconds, 1)}}
                   for s, st in result.scenes.items()},
        # scene -> merged frame residuals are in the reference scene's units; the prior alignment's scale makes cm
        "scene_alignment_rms_cm": {s: a.inlier_rms * result.prior_alignment.scale
                                   for s, a in result.scene_alignment.items()} if result.prior_alignment else None,
        "prior_alignment_rms_cm": result.prior_alignment.inlier_rms if result.prior_alignment else None,
        "seconds": result.seconds,
        "refine": result.refine.as_dict() if result.refine else None,
    }
