"""The SfM front end's two cores kept busy (the same result as one step after the other): the mappers run in
threads while the process pool extracts features or matches the next scene.

- :func:`features_of_scenes`: the likely reference (the most images, ties by name:
  :func:`projector.scene.likely_reference`) has its features extracted and is matched first, then GLOMAP maps it
  in a thread while the pool extracts the other scenes' features (``SfmOptions.map_reference_early``; not on a
  rerun that finds the other scenes' databases: their features are finished first, and the reference is then
  known).
- :func:`reference_model`: should another scene have more images with features, it is the reference and the
  likely one's matches and model are dropped (:func:`projector.database.drop_matches`) before it is matched as a
  later scene.
- :func:`later_scene_models`: each later scene is triangulated at the reference's poses in a thread while the next
  one is matched, one at a time (:func:`projector.scene.known_model`); a fallback to GLOMAP runs after all are
  matched.

The threads use no executor. pycolmap's mappers release the GIL, so the pool's results keep being written
meanwhile. Measured on the panel bench: 2-3 s of its minute.
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from dome_calib.bundle import Camera
from dome_calib.executor import Executor
from projector.database import drop_matches
from projector.features import FeatureReport
from projector.mapping import SceneModel, remove_model_folder
from projector.scene import (MatchedForModel, known_model, known_poses_apply, likely_reference, match_for_model,
                             model_of_matched, reference_options, run_scene, scene_features)
from projector.sfm_types import SceneStats, SfmOptions

logger = logging.getLogger(__name__)


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


@dataclass(kw_only=True)
class EarlyReference:
    """The likely reference scene, matched, being mapped with GLOMAP in a thread (its result: SceneStats)."""

    scene: str
    job: InThread


def _log_thread_error(what: str, error: BaseException | None) -> None:
    if error is not None:
        logger.warning("%s: %s: %s", what, type(error).__name__, error)


def features_of_scenes(capture_dir: Path, work_dir: Path, scenes: list[str], prior: Mapping[str, Camera],
                       options: SfmOptions, executor: Executor
                       ) -> tuple[dict[str, FeatureReport], EarlyReference | None]:
    """Features of every scene (in ``scenes``' order), and the likely reference mapped early when that applies."""
    likely = likely_reference(capture_dir, scenes, options)
    feats = {likely: scene_features(capture_dir, work_dir, likely, prior, options, executor)}
    # a rerun first finishes the features it had begun: once every scene has them, the reference is known
    feats.update({scene: scene_features(capture_dir, work_dir, scene, prior, options, executor)
                  for scene in scenes if scene != likely and (work_dir / scene / "database.db").exists()})
    early = None
    if (options.map_reference_early and len(feats) < len(scenes)
            and known_poses_apply(options, len(scenes), len(feats[likely].num_features))):
        # matched here, then mapped with GLOMAP in a thread (GLOMAP leaves a core idle for a good part of its run)
        ref_options = reference_options(options)
        matched = match_for_model(capture_dir, work_dir, likely, prior, ref_options, executor, feats[likely])
        early = EarlyReference(scene=likely, job=InThread(model_of_matched, capture_dir, work_dir, prior, ref_options,
                                                          None, matched))
    try:
        feats.update({scene: scene_features(capture_dir, work_dir, scene, prior, options, executor)
                      for scene in scenes if scene not in feats})
    except Exception:
        if early is not None:  # no mapper left writing in the background of a process that goes on
            _log_thread_error(f"{likely}: early mapping", early.job.wait())
        raise
    return {scene: feats[scene] for scene in scenes}, early


def reference_model(capture_dir: Path, work_dir: Path, reference: str, prior: Mapping[str, Camera],
                    options: SfmOptions, executor: Executor, feats: FeatureReport,
                    early: EarlyReference | None) -> SceneStats:
    """The reference scene's model: the early mapping's when it mapped this scene, else matched and mapped now
    (an early mapping of another scene is dropped, as if it never ran)."""
    if early is not None and early.scene == reference:
        return early.job.result()
    if early is not None:
        _log_thread_error(f"{early.scene}: early mapping (dropped)", early.job.wait())
        logger.info("reference %s, not %s: %s's matches and model dropped", reference, early.scene, early.scene)
        drop_matches(work_dir / early.scene / "database.db")
        remove_model_folder(work_dir / early.scene / "sparse")
    return run_scene(capture_dir, work_dir, reference, prior, options, executor, feats)


def later_scene_models(capture_dir: Path, work_dir: Path, scenes: list[str], prior: Mapping[str, Camera],
                       options: SfmOptions, executor: Executor, feats: Mapping[str, FeatureReport],
                       reference: SceneModel) -> dict[str, SceneStats]:
    """The models of the scenes other than the reference: each matched, then triangulated at the reference's poses
    in a thread while the next one is matched (one at a time); a fallback to GLOMAP runs after all are matched."""
    later: list[tuple[MatchedForModel, InThread | None]] = []
    try:
        for scene in scenes:
            matched = match_for_model(capture_dir, work_dir, scene, prior, options, executor, feats[scene], reference)
            if later and later[-1][1] is not None:
                later[-1][1].wait()
            later.append((matched, InThread(known_model, capture_dir, work_dir, options, matched)
                          if matched.reference is not None else None))
    except Exception:  # no mapper left running in a process that goes on (an interrupt does not wait)
        for matched, job in later:
            if job is not None:
                _log_thread_error(f"{matched.scene}: triangulation at known poses", job.wait())
        raise
    if later and later[-1][1] is not None:  # none still running when an error is raised below
        later[-1][1].wait()
    return {matched.scene: model_of_matched(capture_dir, work_dir, prior, options, executor, matched,
                                            job.result() if job is not None else None)
            for matched, job in later}
