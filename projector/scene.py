"""The SfM front end's per-scene steps, each callable on its own (hloc style): features, pairs, matching and the
scene's model, in ``WORK/<scene>/`` (resumable). :func:`projector.sfm.run_sfm` runs them for every scene;
the quick recalibration (:mod:`dome_calib.pipeline.quick`) calls :func:`match_scene` on one scene.

    scene_features      features of the scene's images into its database
    select_pairs        prior-based pairs (plus first-round pairs for cameras the prior does not know)
    known_scene_pairs   pairs chosen by the reference model's geometry (a scene mapped at known poses)
    match_scene         features (unless given), pairs, verified matches
    match_for_model     pairs and matching for the scene's model (reference's pairs, or the prior's)
    known_model         the scene triangulated at the reference's poses (or why not)
    model_of_matched    the scene's model: at known poses when that works, else GLOMAP
    run_scene           all of the above for one scene
"""
from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from dome_calib.align import AlignmentError, align_cameras, transform_cameras
from dome_calib.bundle import Camera
from dome_calib.executor import Executor
from dome_calib.io_utils import atomic_write_text
from dome_calib.progress import task_progress
from projector.database import camera_of_image
from projector.features import FeatureReport, extract_features
from projector.known_scene import map_known_scene, reference_cameras
from projector.mapping import SceneModel, map_scene
from projector.matching import MatchReport, match_pairs
from projector.pairs import (Pair, PairOptions, UnknownStrategy, expand_pairs_from_matches, pairs_for_unknown,
                             pairs_from_prior)
from projector.sfm_types import SceneStats, SfmOptions

logger = logging.getLogger(__name__)


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
                            options=options.features, executor=executor, scene=scene, cameras=options.cameras,
                            progress=task_progress(options.progress, f"features {scene}"))


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
    matches = match_pairs(db_path, pairs, options=options.matching, executor=executor, scene=scene,
                          progress=task_progress(options.progress, f"matching {scene}"))
    if options.pairs.unknown_strategy == UnknownStrategy.SUBSET and any(n not in prior for n in names):
        extra = expand_pairs_from_matches(prior, names, matches.inliers, pairs, options.pairs)
        if extra:
            pairs = sorted(set(pairs) | set(extra))
            write_pairs(work_dir / scene / "pairs.txt", pairs)
            matches = match_pairs(db_path, pairs, options=options.matching, executor=executor, scene=scene,
                                  progress=task_progress(options.progress, f"matching {scene}"))
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
    thread while the next scene is matched (:mod:`projector.overlap`)."""
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
