"""The SfM front end's options and results (:func:`projector.sfm.run_sfm`, the per-scene steps of
:mod:`projector.scene`)."""
from __future__ import annotations

from dataclasses import dataclass, field

from dome_calib.bundle import Camera
from dome_calib.progress import ProgressTasks
from projector.features import FeatureOptions, FeatureReport
from projector.known_scene import KnownPoseOptions
from projector.mapping import MappingOptions, SceneModel
from projector.matching import MatchOptions, MatchReport
from projector.merge import Alignment, MergeOptions
from projector.observations import Observations
from projector.pairs import PairOptions
from projector.refine import RefineOptions, RefineReport
from dome_calib.options import AtLeast, options


@options
class SfmOptions:
    features: FeatureOptions = field(default_factory=FeatureOptions)
    pairs: PairOptions = field(default_factory=PairOptions)
    matching: MatchOptions = field(default_factory=MatchOptions)
    mapping: MappingOptions = field(default_factory=MappingOptions)
    known_poses: KnownPoseOptions = field(default_factory=KnownPoseOptions)  # later scenes at the reference's poses
    merge: MergeOptions = field(default_factory=MergeOptions)
    refine: RefineOptions = field(default_factory=RefineOptions)  # keypoints aligned across each track's views
    scenes: list[str] | None = None  # default: every folder in CAPTURE/scenes
    num_workers: AtLeast(1) | None = None  # default: all available cores
    # the likely reference scene is mapped (GLOMAP, in a thread) while the other scenes' features are extracted;
    # False: one after the other (the same result, a few seconds slower)
    map_reference_early: bool = True
    # the cameras' images are on the capture nodes, not under CAPTURE/scenes/ here (capture.json's "nodes"):
    # features of these names are asked for, scenes are taken as given (default: found under scenes/)
    cameras: list[str] | None = None
    progress: ProgressTasks | None = None  # a bar per scene's features and matching (dome_calib.progress)


@dataclass(kw_only=True)
class CameraFailure:
    camera: str
    scene: str  # "" for the whole capture
    stage: str  # features | mapping | merge | refine
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
