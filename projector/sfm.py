"""The projector-pattern SfM front end in one call: capture folder -> cameras, points and observations of all scenes.

Stages (each also callable on its own, hloc style): :func:`projector.features.extract_features`,
:func:`projector.pairs.pairs_from_prior` / ``pairs_exhaustive``, :func:`projector.matching.match_pairs`,
:func:`projector.mapping.map_scene`, :func:`projector.known_scene.map_known_scene`,
:func:`projector.merge.merge_scenes`.

Order: the reference scene (the most images with features, ties by name) is matched and mapped with GLOMAP,
refining focal lengths; every other scene is matched on fewer pairs chosen by the reference's geometry
(:func:`known_scene_pairs`) and triangulated with the cameras held at the reference's poses and intrinsics
(:mod:`projector.known_scene`), falling back on the full pair set and GLOMAP when that gives too little (logged, and
said in the report). ``SfmOptions.known_poses.enabled = False``, or a reference with fewer than
``known_poses.min_images`` images (40: a small capture's GLOMAP runs take seconds), maps every scene with GLOMAP
on the prior's pairs, holding the prior's intrinsics (slower on the dome; measured in the README).

Overlap (the same result, the two cores kept busy): the likely reference (the most images, ties by name:
:func:`likely_reference`) has its features extracted and is matched first, then GLOMAP maps it in a thread while the
process pool extracts the other scenes' features (``SfmOptions.map_reference_early``; not on a rerun that finds
the other scenes' databases: their features are finished first, and the reference is then known). Should another
scene then have more images with features, it is the reference and the likely one's matches and model are dropped
(:func:`projector.database.drop_matches`) before it is matched as a later scene. Each later scene is triangulated
at the reference's poses in a thread while the next one is matched, one at a time (:func:`known_model`); a
fallback to GLOMAP runs after all are matched. The threads use no executor. Measured on the panel bench: 2-3 s
of its minute.

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
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

from dome_calib.align import AlignmentError, align_cameras, transform_cameras
from dome_calib.bundle import Bundle, Camera
from dome_calib.bundle_io import load_bundle
from dome_calib.errors import CaptureError
from dome_calib.io_utils import atomic_write_text
from dome_calib.layout import nominal_dome
from dome_calib.executor import Executor, make_executor
from projector.features import FeatureOptions, FeatureReport, extract_features, nominal_camera
from projector.known_scene import KnownPoseOptions, map_known_scene, reference_cameras
from projector.database import camera_of_image, drop_matches
from projector.mapping import MappingOptions, SceneModel, map_scene, remove_model_folder
from projector.matching import MatchOptions, MatchReport, match_pairs
from projector.merge import Alignment, MergeOptions, merge_scenes
from projector.observations import Observations
from projector.refine import RefineOptions, RefineReport, refine_observations
from projector.pairs import (Pair, PairOptions, UnknownStrategy, expand_pairs_from_matches, pairs_for_unknown,
                             pairs_from_prior)

logger = logging.getLogger(__name__)


@dataclass(kw_only=True)
class SfmOptions:
    features: FeatureOptions = field(default_factory=FeatureOptions)
    pairs: PairOptions = field(default_factory=PairOptions)
    matching: MatchOptions = field(default_factory=MatchOptions)
    mapping: MappingOptions = field(default_factory=MappingOptions)
    known_poses: KnownPoseOptions = field(default_factory=KnownPoseOptions)  # later scenes at the reference's poses
    merge: MergeOptions = field(default_factory=MergeOptions)
    refine: RefineOptions = field(default_factory=RefineOptions)  # keypoints aligned across each track's views
    scenes: list[str] | None = None  # default: every folder in CAPTURE/scenes
    num_workers: int | None = None  # default: all available cores
    # the likely reference scene is mapped (GLOMAP, in a thread) while the other scenes' features are extracted;
    # False: one after the other (the same result, a few seconds slower)
    map_reference_early: bool = True
    # the cameras' images are on the capture nodes, not under CAPTURE/scenes/ here (capture.json's "nodes"):
    # features of these names are asked for, scenes are taken as given (default: found under scenes/)
    cameras: list[str] | None = None
    show_progress: bool = True


@dataclass(kw_only=True)
class CameraFailure:
    camera: str
    scene: str  # "" for the whole capture
    stage: str  # features | mapping | merge
    reason: str


@dataclass(kw_only=True)
class SceneStats:
    scene: str
    features: FeatureReport
    pairs: int
    matches: MatchReport
    model: SceneModel
    mapping: str = "glomap"  # or "known poses (from <reference scene>)"
    fallback: str | None = None  # why the known-pose path was not used, when it was tried


@dataclass(kw_only=True)
class SfmResult:
    """What the front end hands to the bundle adjustment, plus what went wrong where.

    observations: the initial cameras by name, per-scene points in cm in the prior's frame and their
    observations in OpenCV pixels (:class:`Observations`). cameras: the initial cameras (as in ``observations``).
    failures: per camera and scene, with the stage and the reason. unregistered: cameras registered in no scene.
    """

    observations: Observations | None
    cameras: dict[str, Camera]
    scenes: dict[str, SceneStats]
    failures: list[CameraFailure]
    unregistered: dict[str, str]
    scene_alignment: dict[str, Alignment]
    prior_alignment: Alignment | None
    seconds: dict[str, float]
    refine: RefineReport | None = None  # the keypoint refinement's report (None: not run)


def _prior_cameras(prior: Bundle | Mapping[str, Camera] | str | Path | None) -> dict[str, Camera]:
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


def select_pairs(names: list[str], prior: Mapping[str, Camera], options: PairOptions) -> list[Pair]:
    """Prior-based pairs for known cameras plus the first-round fallback pairs for unknown ones."""
    return sorted(set(pairs_from_prior(prior, names, options)) | set(pairs_for_unknown(prior, names, options)))


def write_pairs(path: Path, pairs: list[Pair]) -> None:
    atomic_write_text(path, "".join(f"{a}.png {b}.png\n" for a, b in pairs))


def read_pairs(path: Path) -> list[Pair]:
    """The pairs :func:`write_pairs` wrote (camera names); none if the file is missing."""
    if not path.exists():
        return []
    return [(camera_of_image(a), camera_of_image(b))
            for a, b in (line.split() for line in path.read_text().splitlines() if line.strip())]


def scene_features(capture_dir: Path, work_dir: Path, scene: str, prior: Mapping[str, Camera], options: SfmOptions,
                   executor: Executor) -> FeatureReport:
    """Features of one scene into ``work_dir/<scene>/database.db`` (resumable)."""
    return extract_features(capture_dir / "scenes" / scene, work_dir / scene / "database.db", prior=prior,
                            options=options.features, executor=executor, scene=scene, cameras=options.cameras)


def match_scene(
    capture_dir: Path, work_dir: Path, scene: str, prior: Mapping[str, Camera], options: SfmOptions,
    executor: Executor, feats: FeatureReport | None = None, pairs: list[Pair] | None = None,
) -> tuple[FeatureReport, list[Pair], MatchReport]:
    """Features (unless given), pairs (unless given: :func:`select_pairs` from the prior) and matching of one scene
    into ``work_dir/<scene>/database.db`` (resumable)."""
    db_path = work_dir / scene / "database.db"
    if feats is None:
        feats = scene_features(capture_dir, work_dir, scene, prior, options, executor)
    names = sorted(feats.num_features)
    if pairs is None:
        pairs = select_pairs(names, prior, options.pairs)
    write_pairs(work_dir / scene / "pairs.txt", pairs)
    matches = match_pairs(db_path, pairs, options=options.matching, executor=executor, scene=scene)
    if options.pairs.unknown_strategy == UnknownStrategy.SUBSET and any(n not in prior for n in names):
        extra = expand_pairs_from_matches(prior, names, matches.inliers, pairs, options.pairs)
        if extra:
            pairs = sorted(set(pairs) | set(extra))
            write_pairs(work_dir / scene / "pairs.txt", pairs)
            matches = match_pairs(db_path, pairs, options=options.matching, executor=executor, scene=scene)
    return feats, pairs, matches


def known_scene_pairs(names: list[str], prior: Mapping[str, Camera], reference: SceneModel,
                      options: SfmOptions) -> list[Pair]:
    """Pairs of a scene to be triangulated at the reference's poses, chosen by the reference's geometry.

    The cameras the reference registered are placed as it found them (its poses moved into the prior's frame by
    a similarity on their centres, and its intrinsics: the focal lengths it refined), the others as the prior has
    them; then :func:`select_pairs` with ``options.known_poses.pairs_per_camera`` partners per camera instead of
    ``options.pairs.max_pairs_per_camera``: with the poses known a point needs only two views to be triangulated,
    and tracks grow through the partners' partners. Falls back on the prior alone when the reference cannot be
    aligned to it.
    """
    geometry = dict(prior)
    held = reference_cameras(reference)
    try:
        sim = align_cameras(held, prior).tgt_from_src
    except AlignmentError as exc:
        logger.warning("%s: pairs from the prior (the reference does not align to it: %s)", reference.scene, exc)
    else:
        geometry.update(transform_cameras(held, sim))
    pair_options = replace(options.pairs, max_pairs_per_camera=options.known_poses.pairs_per_camera)
    return select_pairs(names, geometry, pair_options)


def mapper_image_dir(capture_dir: Path, work_dir: Path, scene: str, options: SfmOptions) -> Path:
    """The image folder the mappers are given: the scene's, or an empty one when the images are on the capture
    nodes (``options.cameras``): the mappers read only the database, but COLMAP wants the folder to exist."""
    if options.cameras is None:
        return capture_dir / "scenes" / scene
    empty = work_dir / scene / "images_on_nodes"
    empty.mkdir(parents=True, exist_ok=True)
    return empty


def reference_scene(feats: Mapping[str, FeatureReport]) -> str:
    """The scene mapped with GLOMAP first: the most images with features (ties: the first name)."""
    return min(feats, key=lambda s: (-len(feats[s].num_features), s))


def likely_reference(capture_dir: Path, scenes: list[str], options: SfmOptions) -> str:
    """The scene that will most likely be :func:`reference_scene` before any features exist: the most images
    (ties: the first name; every scene when the images are on the capture nodes)."""
    if options.cameras is not None:
        return scenes[0]
    return min(scenes, key=lambda s: (-sum(1 for _ in (capture_dir / "scenes" / s).glob("*.png")), s))


class _InThread:
    """``fn(*args, **kwargs)`` run in a daemon thread (pycolmap's mappers release the GIL, so the process pool's
    results keep being written meanwhile); :meth:`result` waits and re-raises its error. A daemon: an interrupted
    run exits at once instead of waiting for the mapper (whose output is staged, :mod:`projector.mapping`)."""

    def __init__(self, fn: Callable[..., object], /, *args: object, **kwargs: object) -> None:
        self._out: object = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(fn, args, kwargs), daemon=True)
        self._thread.start()

    def _run(self, fn: Callable[..., object], args: tuple, kwargs: dict) -> None:
        try:
            self._out = fn(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller by result()
            self._error = exc

    def wait(self) -> BaseException | None:
        """Wait for the call to end; its error, if it raised (not raised here)."""
        self._thread.join()
        return self._error

    def result(self) -> object:
        error = self.wait()
        if error is not None:
            raise error
        return self._out


@dataclass(kw_only=True)
class MatchedForModel:
    """A scene matched for its model (:func:`match_for_model`): what :func:`model_of_matched` maps."""

    scene: str
    features: FeatureReport
    pairs: list[Pair]
    matches: MatchReport
    reference: SceneModel | None  # the model its cameras are held at, or None: GLOMAP


def match_for_model(capture_dir: Path, work_dir: Path, scene: str, prior: Mapping[str, Camera], options: SfmOptions,
                    executor: Executor, feats: FeatureReport, reference: SceneModel | None = None) -> MatchedForModel:
    """Pairs and matching of a scene for :func:`model_of_matched`: the reference's geometry's pairs when the scene
    is to be triangulated at ``reference``'s poses, else the prior's."""
    if not (reference is not None and reference.reconstruction is not None and options.known_poses.enabled):
        reference = None
    pairs = known_scene_pairs(sorted(feats.num_features), prior, reference, options) if reference else None
    feats, pairs, matches = match_scene(capture_dir, work_dir, scene, prior, options, executor, feats, pairs)
    return MatchedForModel(scene=scene, features=feats, pairs=pairs, matches=matches, reference=reference)


def known_model(capture_dir: Path, work_dir: Path, options: SfmOptions, matched: MatchedForModel
                ) -> tuple[SceneModel, str | None]:
    """The scene triangulated with its cameras held at ``matched.reference``'s poses (:func:`map_known_scene`):
    the model and None, or the model and why to map the scene with GLOMAP instead. Uses no executor: it runs in a
    thread while the next scene is matched."""
    scene = matched.scene
    return map_known_scene(work_dir / scene / "database.db", mapper_image_dir(capture_dir, work_dir, scene, options),
                           work_dir / scene / "known", matched.reference, options.known_poses, scene=scene)


def model_of_matched(capture_dir: Path, work_dir: Path, prior: Mapping[str, Camera], options: SfmOptions,
                     executor: Executor | None, matched: MatchedForModel,
                     known: tuple[SceneModel, str | None] | None = None) -> SceneStats:
    """The scene's model: triangulated with the cameras held at the reference's poses when it has one and that
    works (``known``: :func:`known_model`'s result when already computed), else mapped with GLOMAP (after matching
    the prior's full pair set, when it fell back)."""
    scene, feats, pairs, matches, reference = (matched.scene, matched.features, matched.pairs, matched.matches,
                                               matched.reference)
    db_path, image_dir = work_dir / scene / "database.db", mapper_image_dir(capture_dir, work_dir, scene, options)
    fallback = None
    if reference is not None:
        model, fallback = known if known is not None else known_model(capture_dir, work_dir, options, matched)
        if fallback is None:
            return SceneStats(scene=scene, features=feats, pairs=len(pairs), matches=matches, model=model,
                              mapping=f"known poses (from {reference.scene})")
        logger.warning("%s: mapping with GLOMAP instead: %s", scene, fallback)
        known_seconds, known_matching = model.seconds, matches.seconds
        # GLOMAP registers the cameras too: the prior's full pair set (matched ones reused)
        feats, pairs, matches = match_scene(capture_dir, work_dir, scene, prior, options, executor, feats)
        matches.seconds += known_matching
    model = map_scene(db_path, image_dir, work_dir / scene / "sparse", options=options.mapping, scene=scene)
    if fallback is not None:
        model.seconds += known_seconds
    return SceneStats(scene=scene, features=feats, pairs=len(pairs), matches=matches, model=model, fallback=fallback)


def run_scene(
    capture_dir: Path, work_dir: Path, scene: str, prior: Mapping[str, Camera], options: SfmOptions,
    executor: Executor, feats: FeatureReport | None = None, reference: SceneModel | None = None,
) -> SceneStats:
    """Features (unless given), pairs, matching and the scene's model: triangulated with the cameras held at
    ``reference``'s poses when given and that works, else mapped with GLOMAP."""
    if feats is None:
        feats = scene_features(capture_dir, work_dir, scene, prior, options, executor)
    matched = match_for_model(capture_dir, work_dir, scene, prior, options, executor, feats, reference)
    return model_of_matched(capture_dir, work_dir, prior, options, executor, matched)


def _known_poses_apply(options: SfmOptions, n_scenes: int, n_reference_images: int) -> bool:
    return options.known_poses.enabled and n_scenes > 1 and n_reference_images >= options.known_poses.min_images


def _reference_options(options: SfmOptions) -> SfmOptions:
    """The reference scene's options: its focal lengths refined when later scenes are triangulated at its poses."""
    if options.known_poses.enabled and options.known_poses.refine_reference_focal:
        return replace(options, mapping=replace(options.mapping, refine_focal_length=True))
    return options


def _map_reference_early(capture_dir: Path, work_dir: Path, scene: str, prior: Mapping[str, Camera],
                         options: SfmOptions, executor: Executor, feats: FeatureReport) -> _InThread:
    """:func:`run_scene` of the (likely) reference scene: matched here, then mapped with GLOMAP in a thread (no
    executor used there), whose result is the scene's :class:`SceneStats`."""
    matched = match_for_model(capture_dir, work_dir, scene, prior, options, executor, feats)
    return _InThread(model_of_matched, capture_dir, work_dir, prior, options, None, matched)


def _log_thread_error(what: str, error: BaseException | None) -> None:
    if error is not None:
        logger.warning("%s: %s: %s", what, type(error).__name__, error)


def run_sfm(
    capture_dir: str | Path, work_dir: str | Path, options: SfmOptions | None = None,
    prior: Bundle | Mapping[str, Camera] | str | Path | None = None, executor: Executor | None = None,
) -> SfmResult:
    """Run the whole front end on a capture folder.

    Args:
        capture_dir: ``CAPTURE`` with ``scenes/<scene>/<camera>.png``.
        work_dir: where databases and models go (reruns reuse them).
        prior: a previous calibration (Bundle, cameras by name, or a bundle folder); default the nominal dome
            layout. It seeds intrinsics, pair selection and the output frame (cm, Panoptic world).
        executor: task executor for features and matching (default: local process pool).
    Returns:
        :class:`SfmResult`; ``observations`` is None only if no scene reconstructed (``failures`` says why).
    Example:
        >>> result = run_sfm("capture", "work", prior="previous_bundle")
        >>> result.observations.camera_names[:3], len(result.observations.uv_px)
    """
    options = options or SfmOptions()
    for sub in (options.features, options.matching):
        sub.show_progress = options.show_progress
    capture_dir, work_dir = Path(capture_dir), Path(work_dir)
    scenes = list(options.scenes) if options.cameras is not None and options.scenes else list_scenes(capture_dir, options.scenes)
    prior_cams = _prior_cameras(prior)
    t0 = time.perf_counter()
    stats: dict[str, SceneStats] = {}
    # our own pool is stopped at once (workers quiet) if a scene fails or the run is interrupted
    with make_executor(options.num_workers) if executor is None else contextlib.nullcontext(executor) as pool:
        # the likely reference first: once it is matched, GLOMAP maps it in a thread while the process pool
        # extracts the other scenes' features (GLOMAP leaves a core idle for a good part of its run)
        likely = likely_reference(capture_dir, scenes, options)
        feats = {likely: scene_features(capture_dir, work_dir, likely, prior_cams, options, pool)}
        # a rerun first finishes the features it had begun: once every scene has them, the reference is known
        feats.update({scene: scene_features(capture_dir, work_dir, scene, prior_cams, options, pool)
                      for scene in scenes if scene != likely and (work_dir / scene / "database.db").exists()})
        early = None
        if (options.map_reference_early and len(feats) < len(scenes)
                and _known_poses_apply(options, len(scenes), len(feats[likely].num_features))):
            early = _map_reference_early(capture_dir, work_dir, likely, prior_cams, _reference_options(options),
                                         pool, feats[likely])
        try:
            feats.update({scene: scene_features(capture_dir, work_dir, scene, prior_cams, options, pool)
                          for scene in scenes if scene not in feats})
        except Exception:
            if early is not None:  # no mapper left writing in the background of a process that goes on
                _log_thread_error(f"{likely}: early mapping", early.wait())
            raise
        feats = {scene: feats[scene] for scene in scenes}
        ref = reference_scene(feats)
        n_ref = len(feats[ref].num_features)
        if options.known_poses.enabled and len(scenes) > 1 and n_ref < options.known_poses.min_images:
            logger.info("known poses: %s has %d images with features (< %d): every scene mapped with GLOMAP", ref,
                        n_ref, options.known_poses.min_images)
            options = replace(options, known_poses=replace(options.known_poses, enabled=False))
        ref_options = _reference_options(options) if len(scenes) > 1 else options
        if early is not None and ref == likely:
            stats[likely] = early.result()
        elif early is not None:  # another scene has more images with features: as if the likely one was never mapped
            _log_thread_error(f"{likely}: early mapping (dropped)", early.wait())
            logger.info("reference %s, not %s: %s's matches and model dropped", ref, likely, likely)
            drop_matches(work_dir / likely / "database.db")
            remove_model_folder(work_dir / likely / "sparse")
        if ref not in stats:
            stats[ref] = run_scene(capture_dir, work_dir, ref, prior_cams, ref_options, pool, feats[ref])
        # each later scene is triangulated at the reference's poses (single-threaded COLMAP, mostly) in a thread
        # while the next one is matched, one at a time; a fallback to GLOMAP runs here, after all are matched
        later: list[tuple[MatchedForModel, _InThread | None]] = []
        try:
            for scene in scenes:
                if scene != ref:
                    matched = match_for_model(capture_dir, work_dir, scene, prior_cams, options, pool, feats[scene],
                                              stats[ref].model)
                    if later and later[-1][1] is not None:
                        later[-1][1].wait()
                    later.append((matched, _InThread(known_model, capture_dir, work_dir, options, matched)
                                  if matched.reference is not None else None))
        except Exception:  # no mapper left running in a process that goes on (an interrupt does not wait)
            for matched, job in later:
                if job is not None:
                    _log_thread_error(f"{matched.scene}: triangulation at known poses", job.wait())
            raise
        if later and later[-1][1] is not None:  # none still running when an error is raised below
            later[-1][1].wait()
        for matched, job in later:
            stats[matched.scene] = model_of_matched(capture_dir, work_dir, prior_cams, options, pool, matched,
                                                    job.result() if job is not None else None)
    stats = {scene: stats[scene] for scene in scenes}
    t_scenes = time.perf_counter() - t0
    failures: list[CameraFailure] = []
    for s in stats.values():
        failures += [CameraFailure(camera=c, scene=s.scene, stage="features", reason=r)
                     for c, r in sorted(s.features.failures.items())]
        failures += [CameraFailure(camera=c, scene=s.scene, stage="mapping", reason=r)
                     for c, r in sorted(s.model.unregistered.items())]
        if s.model.failure:
            failures.append(CameraFailure(camera="", scene=s.scene, stage="mapping", reason=s.model.failure))
    # cameras seen in the images but unknown to the prior get nominal intrinsics (pose from the scenes)
    all_cams = sorted({c for s in stats.values() for c in (*s.features.num_features, *s.features.failures)})
    known = set(prior_cams)
    for s in stats.values():
        for c in s.model.registered:
            if c not in prior_cams:
                rec_cam = s.model.reconstruction.camera(s.model.reconstruction.find_image_with_name(f"{c}.png").camera_id)
                prior_cams[c] = nominal_camera(c, (rec_cam.width, rec_cam.height))
    t1 = time.perf_counter()
    observations, cameras, scene_alignment, prior_alignment, refined = None, {}, {}, None, None
    try:
        merge_options = replace(options.merge, use_colmap_intrinsics=options.merge.use_colmap_intrinsics
                                or ref_options.mapping.refine_focal_length or options.mapping.refine_principal_point)
        merged = merge_scenes([s.model for s in stats.values()], prior_cams, merge_options, align_to=known)
    except ValueError as exc:
        failures.append(CameraFailure(camera="", scene="", stage="merge", reason=str(exc)))
    else:
        observations, cameras = merged.observations, merged.observations.cameras
        # issue 36: every track's keypoints aligned across its views (projector.refine); images local only
        if options.refine.enabled and options.cameras is None:
            observations, refined = refine_observations(observations, lambda s: capture_dir / "scenes" / s,
                                                        options.refine)
        scene_alignment, prior_alignment = merged.scene_alignment, merged.prior_alignment
        failures += [CameraFailure(camera="", scene=sc, stage="merge", reason=r) for sc, r in merged.unaligned_scenes.items()]
        failures += [CameraFailure(camera=c, scene=sc, stage="merge", reason=r) for (sc, c), r in merged.excluded.items()]
    reasons: dict[str, list[str]] = {}
    for f in failures:
        if f.camera:
            reasons.setdefault(f.camera, []).append(f"{f.scene}: {f.reason}")
    unregistered = {c: "; ".join(reasons.get(c, ["not registered"])) for c in all_cams if c not in cameras}
    for c, r in unregistered.items():
        logger.warning("camera %s not registered in any scene: %s", c, r)
    seconds = {"features": sum(s.features.seconds for s in stats.values()),
               "matching": sum(s.matches.seconds for s in stats.values()),
               "mapping": sum(s.model.seconds for s in stats.values()),
               "scenes": t_scenes, "merge": time.perf_counter() - t1 - (refined.seconds if refined else 0.0),
               "refine": refined.seconds if refined else 0.0, "total": time.perf_counter() - t0}
    result = SfmResult(observations=observations, cameras=cameras, scenes=stats, failures=failures, unregistered=unregistered,
                       scene_alignment=scene_alignment, prior_alignment=prior_alignment, seconds=seconds, refine=refined)
    atomic_write_text(work_dir / "sfm_report.json", json.dumps(report_dict(result), indent=1))
    return result


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
