"""The SfM front end's per-scene steps over every scene of a capture, in ``WORK/<scene>/`` (resumable).
:func:`projector.sfm.run_sfm` calls :func:`scene_models` once; the quick recalibration
(:mod:`dome_calib.pipeline.quick`) calls :func:`match_scene` on one scene.

    scene_models        every scene's model: features, the reference (GLOMAP), the later scenes at its poses,
                        the reference's GLOMAP in a thread while the pool extracts the other features
    ScenesRun           the places, prior, options and executor held once; one method per step, each handing the
                        scene's places to one stage module (features, matching, mapping, known_scene)
    scene_features      features of one scene into its database
    select_pairs        prior-based pairs (plus first-round pairs for cameras the prior does not know)
    known_scene_pairs   pairs chosen by the reference model's geometry (a scene mapped at known poses)
    match_scene         features (unless given), pairs, verified matches of one scene
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from dome_calib.align import AlignmentError, align_cameras, transform_cameras
from dome_calib.bundle import Camera
from dome_calib.executor import Executor
from dome_calib.io_utils import atomic_write_text
from dome_calib.progress import task_progress
from projector.database import camera_of_image, drop_matches, read_summary
from projector.features import FeatureReport, extract_features
from projector.known_scene import KnownJob, map_known_scenes, reference_cameras
from projector.mapping import SceneModel, map_scene, remove_model_folder
from projector.matching import MatchReport, match_pairs
from projector.pairs import (Pair, PairOptions, UnknownStrategy, expand_pairs_from_matches, pairs_for_unknown,
                             pairs_from_prior)
from projector.sfm_types import SceneStats, SfmOptions

logger = logging.getLogger(__name__)


def select_pairs(names: list[str], prior: Mapping[str, Camera], options: PairOptions) -> list[Pair]:
    """Prior-based pairs for known cameras plus the first-round fallback pairs for unknown ones."""
    return sorted(set(pairs_from_prior(prior, names, options)) | set(pairs_for_unknown(prior, names, options)))


def pairs_text(pairs: list[Pair]) -> str:
    """The pairs file's text: one "a.png b.png" line per pair."""
    return "".join(f"{a}.png {b}.png\n" for a, b in pairs)


def write_pairs(path: Path, pairs: list[Pair]) -> None:
    atomic_write_text(path, pairs_text(pairs))


def read_pairs(path: Path) -> list[Pair]:
    """The pairs :func:`write_pairs` wrote (camera names); none if the file is missing."""
    if not path.exists():
        return []
    return [(camera_of_image(a), camera_of_image(b))
            for a, b in (line.split() for line in path.read_text().splitlines() if line.strip())]


def scene_features(capture_dir: Path, work_dir: Path, scene: str, prior: Mapping[str, Camera], options: SfmOptions,
                   executor: Executor) -> FeatureReport:
    """Features of one scene into ``work_dir/<scene>/database.db`` (resumable)."""
    return ScenesRun(capture_dir, work_dir, prior, options, executor).features(scene)


def match_scene(
    capture_dir: Path, work_dir: Path, scene: str, prior: Mapping[str, Camera], options: SfmOptions,
    executor: Executor, feats: FeatureReport | None = None, pairs: list[Pair] | None = None,
) -> tuple[FeatureReport, list[Pair], MatchReport]:
    """Features (unless given), pairs (unless given: :func:`select_pairs` from the prior) and matching of one scene
    into ``work_dir/<scene>/database.db`` (resumable); the matched pairs in ``pairs.txt``."""
    run = ScenesRun(capture_dir, work_dir, prior, options, executor)
    matched = run.match_pairs(scene, options, feats, pairs)
    run.write_pairs()
    return matched


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
    return ScenesRun(capture_dir, work_dir, {}, options, None).mapper_images(scene, options)


def reference_scene(feats: Mapping[str, FeatureReport]) -> str:
    """The scene mapped with GLOMAP first: the most images with features (ties: the first name)."""
    return min(feats, key=lambda s: (-len(feats[s].num_features), s))


def likely_reference(capture_dir: Path, scenes: list[str], options: SfmOptions) -> str:
    """The scene that will most likely be :func:`reference_scene` before any features exist: the most images
    (ties: the first name; every scene when the images are on the capture nodes)."""
    if options.cameras is not None:
        return scenes[0]
    return min(scenes, key=lambda s: (-sum(1 for _ in (capture_dir / "scenes" / s).glob("*.png")), s))


def known_poses_apply(options: SfmOptions, n_scenes: int, n_reference_images: int) -> bool:
    """Whether the later scenes are triangulated at the reference's poses (else every scene is mapped)."""
    return options.known_poses.enabled and n_scenes > 1 and n_reference_images >= options.known_poses.min_images


def with_known_poses_decided(options: SfmOptions, reference: str, n_reference_images: int,
                             n_scenes: int) -> SfmOptions:
    """``options`` with the known-pose path turned off when the reference has too few images with features
    (``known_poses.min_images``: a small capture's GLOMAP runs take seconds)."""
    if options.known_poses.enabled and n_scenes > 1 and n_reference_images < options.known_poses.min_images:
        logger.info("known poses: %s has %d images with features (< %d): every scene mapped with GLOMAP", reference,
                    n_reference_images, options.known_poses.min_images)
        return replace(options, known_poses=replace(options.known_poses, enabled=False))
    return options


def reference_options(options: SfmOptions) -> SfmOptions:
    """The reference scene's options: its focal lengths refined when later scenes are triangulated at its poses."""
    if options.known_poses.enabled and options.known_poses.refine_reference_focal:
        return replace(options, mapping=replace(options.mapping, refine_focal_length=True))
    return options


class InThread:
    """``fn(*args, **kwargs)`` run in a daemon thread; :meth:`result` waits and re-raises its error. A daemon: an
    interrupted run exits at once instead of waiting for the mapper (whose output is staged,
    :mod:`projector.mapping`)."""

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


def _log_thread_error(what: str, error: BaseException | None) -> None:
    if error is not None:
        logger.warning("%s: %s: %s", what, type(error).__name__, error)


@dataclass(kw_only=True)
class Matched:
    """A scene matched for its model: its features, pairs and matches, and the reference model its cameras are to
    be held at (None: GLOMAP)."""

    scene: str
    features: FeatureReport
    pairs: list[Pair]
    matches: MatchReport
    reference: SceneModel | None


@dataclass(kw_only=True)
class SceneModels:
    """Every scene's model (:func:`scene_models`), and what the run decided on the way."""

    scenes: dict[str, SceneStats]  # in the capture's order
    reference: str
    options: SfmOptions  # the known-pose path decided (:func:`with_known_poses_decided`)
    reference_options: SfmOptions  # the reference scene's (:func:`reference_options`)


class ScenesRun:
    """One run of the per-scene steps over a capture: the places (``capture_dir``, ``work_dir``), the prior, the
    options and the executor held once; each step takes a scene's name and hands its places to one stage module
    (features, matching, mapping, known poses), so the work folder goes from here into each stage and its result
    comes back as a typed value. :func:`scene_models` is the straight run of the steps."""

    def __init__(self, capture_dir: Path, work_dir: Path, prior: Mapping[str, Camera], options: SfmOptions,
                 executor: Executor | None) -> None:
        self._capture_dir, self._work_dir = capture_dir, work_dir
        self._prior, self._options, self._executor = prior, options, executor
        self._pairs: dict[str, list[Pair]] = {}  # the pairs each scene was last matched on (:meth:`write_pairs`)

    def features(self, scene: str) -> FeatureReport:
        """Features of the scene's images into its database (:func:`projector.features.extract_features`)."""
        o = self._options
        return extract_features(self._capture_dir / "scenes" / scene, self._work_dir / scene / "database.db",
                                prior=self._prior, options=o.features, executor=self._executor, scene=scene,
                                cameras=o.cameras, progress=task_progress(o.progress, f"features {scene}"))

    def has_database(self, scene: str) -> bool:
        return (self._work_dir / scene / "database.db").exists()

    def mapper_images(self, scene: str, options: SfmOptions) -> Path:
        """The image folder the mappers are given (:func:`mapper_image_dir`)."""
        if options.cameras is None:
            return self._capture_dir / "scenes" / scene
        empty = self._work_dir / scene / "images_on_nodes"
        empty.mkdir(parents=True, exist_ok=True)
        return empty

    def match_pairs(self, scene: str, options: SfmOptions, feats: FeatureReport | None = None,
                    pairs: list[Pair] | None = None) -> tuple[FeatureReport, list[Pair], MatchReport]:
        """Features (unless given), pairs (unless given: :func:`select_pairs` from the prior) and matching of the
        scene into its database (:func:`projector.matching.match_pairs`); the pairs kept for :meth:`write_pairs`."""
        executor = self._executor
        db_path = self._work_dir / scene / "database.db"
        if feats is None:
            feats = self.features(scene)
        names = sorted(feats.num_features)
        if pairs is None:
            pairs = select_pairs(names, self._prior, options.pairs)
        matches = match_pairs(db_path, pairs, options=options.matching, executor=executor, scene=scene,
                              progress=task_progress(options.progress, f"matching {scene}"))
        if options.pairs.unknown_strategy == UnknownStrategy.SUBSET and any(n not in self._prior for n in names):
            extra = expand_pairs_from_matches(self._prior, names, matches.inliers, pairs, options.pairs)
            if extra:
                pairs = sorted(set(pairs) | set(extra))
                matches = match_pairs(db_path, pairs, options=options.matching, executor=executor, scene=scene,
                                      progress=task_progress(options.progress, f"matching {scene}"))
        self._pairs[scene] = pairs
        return feats, pairs, matches

    def write_pairs(self) -> None:
        """Each matched scene's pairs in its ``pairs.txt``, together once the run's matching is done (a record:
        reruns select them again)."""
        for scene, pairs in self._pairs.items():
            atomic_write_text(self._work_dir / scene / "pairs.txt", pairs_text(pairs))

    def match(self, scene: str, options: SfmOptions, feats: FeatureReport,
              reference: SceneModel | None = None) -> Matched:
        """Pairs and matching of a scene for its model: the reference's geometry's pairs when the scene is to be
        triangulated at ``reference``'s poses, else the prior's."""
        if not (reference is not None and reference.reconstruction is not None and options.known_poses.enabled):
            reference = None
        pairs = known_scene_pairs(sorted(feats.num_features), self._prior, reference, options) if reference else None
        feats, pairs, matches = self.match_pairs(scene, options, feats, pairs)
        return Matched(scene=scene, features=feats, pairs=pairs, matches=matches, reference=reference)

    def glomap(self, scene: str, options: SfmOptions) -> SceneModel:
        """The scene mapped with GLOMAP (:func:`projector.mapping.map_scene`). Uses no executor."""
        work = self._work_dir / scene
        database = read_summary(work / "database.db")  # read before the mapper (which only reads the database)
        return map_scene(work / "database.db", self.mapper_images(scene, options), work / "sparse",
                         options=options.mapping, scene=scene, database=database)

    def known(self, matched: list[Matched], options: SfmOptions) -> dict[str, tuple[SceneModel, str | None]]:
        """The scenes (all at one reference's poses) triangulated with their cameras held there
        (:func:`projector.known_scene.map_known_scenes`, each step over all of them): by scene, the model and None,
        or the model and why to map the scene with GLOMAP instead."""
        if not matched:
            return {}
        jobs = [KnownJob(scene=m.scene, database=self._work_dir / m.scene / "database.db",
                         images=self.mapper_images(m.scene, options), output=self._work_dir / m.scene / "known")
                for m in matched]
        return map_known_scenes(jobs, matched[0].reference, options.known_poses)

    def drop(self, scene: str) -> None:
        """A scene's matches and GLOMAP model dropped, as if they were never made (its features kept)."""
        drop_matches(self._work_dir / scene / "database.db")
        remove_model_folder(self._work_dir / scene / "sparse")

    def model(self, matched: Matched, options: SfmOptions, known: tuple[SceneModel, str | None] | None = None,
              glomap: SceneModel | None = None) -> SceneStats:
        """The scene's stats: triangulated at the reference's poses when it has one and that works (``known``:
        :meth:`known`'s result), else mapped with GLOMAP (``glomap`` when already mapped; after matching the
        prior's full pair set, when it fell back)."""
        scene, feats, pairs, matches, reference = (matched.scene, matched.features, matched.pairs, matched.matches,
                                                   matched.reference)
        fallback = None
        if reference is not None:
            model, fallback = known if known is not None else self.known([matched], options)[scene]
            if fallback is None:
                return SceneStats(scene=scene, features=feats, pairs=len(pairs), matches=matches, model=model,
                                  mapping=f"known poses (from {reference.scene})")
            logger.warning("%s: mapping with GLOMAP instead: %s", scene, fallback)
            known_seconds, known_matching = model.seconds, matches.seconds
            # GLOMAP registers the cameras too: the prior's full pair set (matched ones reused)
            feats, pairs, matches = self.match_pairs(scene, options, feats)
            matches.seconds += known_matching
        model = glomap if glomap is not None else self.glomap(scene, options)
        if fallback is not None:
            model.seconds += known_seconds
        return SceneStats(scene=scene, features=feats, pairs=len(pairs), matches=matches, model=model,
                          fallback=fallback)


def scene_models(capture_dir: Path, work_dir: Path, scenes: list[str], prior: Mapping[str, Camera],
                 options: SfmOptions, executor: Executor) -> SceneModels:
    """Every scene's model (the same result as one step after the other): the reference's GLOMAP runs in a thread
    (it uses no executor; pycolmap's mappers release the GIL) while the pool extracts the other scenes' features.

    1. Features of every scene. The likely reference (the most images, ties by name: :func:`likely_reference`)
       first; it is then matched and mapped with GLOMAP in a thread while the pool extracts the other scenes'
       features (``SfmOptions.map_reference_early``; not on a rerun that finds the other scenes' databases: their
       features are finished first, and the reference is then known).
    2. The reference (:func:`reference_scene`): the early mapping's model when it mapped this scene; else the
       likely one's matches and model are dropped (:func:`projector.database.drop_matches`), as if they never
       were, and the reference is matched and mapped now.
    3. Every later scene matched, then all of them triangulated at the reference's poses
       (:func:`projector.known_scene.map_known_scenes`: each step over all the scenes, so that the work folder goes
       through each stage module once); a fallback to GLOMAP runs after. Each scene's ``pairs.txt`` is written
       last (:meth:`ScenesRun.write_pairs`).
    """
    run = ScenesRun(capture_dir, work_dir, prior, options, executor)
    # 1. features: the likely reference first; a rerun first finishes the features it had begun (once every scene
    # has them, the reference is known)
    likely = likely_reference(capture_dir, scenes, options)
    feats = {likely: run.features(likely)}
    feats.update({scene: run.features(scene) for scene in scenes if scene != likely and run.has_database(scene)})
    early: InThread | None = None
    early_matched: Matched | None = None
    if (options.map_reference_early and len(feats) < len(scenes)
            and known_poses_apply(options, len(scenes), len(feats[likely].num_features))):
        # matched here, then mapped with GLOMAP in a thread (GLOMAP leaves a core idle for a good part of its run)
        likely_options = reference_options(options)
        early_matched = run.match(likely, likely_options, feats[likely])
        early = InThread(run.glomap, likely, likely_options)
    try:
        feats.update({scene: run.features(scene) for scene in scenes if scene not in feats})
    except Exception:
        if early is not None:  # no mapper left writing in the background of a process that goes on
            _log_thread_error(f"{likely}: early mapping", early.wait())
        raise
    feats = {scene: feats[scene] for scene in scenes}
    # 2. the reference scene: the most images with features; pairs, matching and mapping (GLOMAP)
    ref = reference_scene(feats)
    options = with_known_poses_decided(options, ref, len(feats[ref].num_features), len(scenes))
    ref_options = reference_options(options) if len(scenes) > 1 else options
    if early is not None and early_matched.scene == ref:
        stats = {ref: run.model(early_matched, ref_options, glomap=early.result())}
    else:
        if early is not None:
            _log_thread_error(f"{early_matched.scene}: early mapping (dropped)", early.wait())
            logger.info("reference %s, not %s: %s's matches and model dropped", ref, early_matched.scene,
                        early_matched.scene)
            run.drop(early_matched.scene)
        stats = {ref: run.model(run.match(ref, ref_options, feats[ref]), ref_options)}
    reference = stats[ref].model
    # 3. every other scene: pairs by the reference's geometry and matching, then all of them triangulated at its
    # poses (each step over all the scenes: the work folder goes through each stage once); a fallback to GLOMAP last
    later = [run.match(scene, options, feats[scene], reference) for scene in scenes if scene != ref]
    known = run.known([m for m in later if m.reference is not None], options)
    stats.update({m.scene: run.model(m, options, known=known.get(m.scene)) for m in later})
    run.write_pairs()
    return SceneModels(scenes={scene: stats[scene] for scene in scenes}, reference=ref, options=options,
                       reference_options=ref_options)
