"""Stage 4: per-scene mapping with pycolmap (GLOMAP global SfM by default, COLMAP incremental as an option).

Reads the scene database (features, verified two-view geometries, one FULL_OPENCV camera per physical camera
with the prior's intrinsics) and writes the models to ``output_dir/<k>/``. The largest model is the scene's
reconstruction. A rerun loads ``output_dir/0`` instead of mapping again.

Intrinsics: the prior's distortion is kept fixed (``refine_extra_params=False``): COLMAP's FULL_OPENCV has
three rational terms that must stay zero to remain the OpenCV 5-parameter model, and a scene's SfM is only
the initial value of the multi-scene bundle adjustment, which refines all five terms. Focal lengths and principal
points are held too by default (``MappingOptions``): the bundle adjustment's lens-model selection refines them.
:func:`projector.sfm.run_sfm` has the reference scene's focal lengths refined when the later scenes are
triangulated at its poses (``KnownPoseOptions.refine_reference_focal``).
"""
from __future__ import annotations

import logging
import shutil
import time
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import pycolmap

from dome_calib.colmap_options import colmap_options
from dome_calib.io_utils import atomic_folder
from projector.database import DatabaseSummary, camera_of_image, read_summary
from dome_calib.options import AtLeast, Lax, options

logger = logging.getLogger(__name__)


class Mapper(StrEnum):
    GLOBAL = "global"  # GLOMAP (pycolmap.global_mapping)
    INCREMENTAL = "incremental"  # COLMAP (pycolmap.incremental_mapping)


@options
class MappingOptions:
    mapper: Annotated[Mapper, Lax] = Mapper.GLOBAL
    refine_focal_length: bool = False
    refine_principal_point: bool = False
    refine_extra_params: bool = False
    # GLOMAP's stages after global positioning, trimmed: the scene model only starts our multi-scene bundle
    # adjustment, which does the fine work. Measured on one full-dome scene (521 cameras, 7,500 pairs): GLOMAP's
    # defaults (3 bundle-adjustment rounds with a fixed-rotation stage, then retriangulation) took 154 s;
    # one joint round without retriangulation 77 s, with the same camera centres (0.95 against 0.89 cm median
    # after a similarity to the truth, both before our bundle adjustment).
    ba_rounds: AtLeast(0) = 1
    skip_fixed_rotation_stage: bool = True
    skip_retriangulation: bool = True
    min_num_matches: AtLeast(1) = 15
    min_model_size: AtLeast(2) = 3
    min_points_per_image: AtLeast(0) = 30  # a registered image seeing fewer 3D points is reported, not used
    # 1: the same model, bit for bit, on every run (dome_calib.colmap_options). More (-1: all cores) lets Ceres and
    # GLOMAP sum in the order their threads finish: the model, and calibrate's bundle after it, then differ in the
    # last bits from run to run, for no gain in time measured on the tiny dome (docs/benchmarks.md)
    num_threads: AtLeast(-1) = 1
    random_seed: AtLeast(0) = 0
    reuse: bool = True  # load an existing model instead of mapping again
    fallback: bool = True  # try the other mapper when the first gives no model


@dataclass(kw_only=True)
class SceneModel:
    """The reconstruction of one scene (None if it did not reconstruct) and what happened to each camera."""

    scene: str
    reconstruction: pycolmap.Reconstruction | None
    registered: list[str] = field(default_factory=list)
    unregistered: dict[str, str] = field(default_factory=dict)  # camera -> reason
    num_models: int = 0
    seconds: float = 0.0
    failure: str | None = None


def _global_options(options: MappingOptions) -> pycolmap.GlobalPipelineOptions:
    o = colmap_options(pycolmap.GlobalPipelineOptions, seed=options.random_seed)
    o.min_num_matches = options.min_num_matches
    o.min_model_size = options.min_model_size
    o.num_threads = o.mapper.num_threads = options.num_threads
    o.mapper.ba_num_iterations = options.ba_rounds
    o.mapper.ba_skip_fixed_rotation_stage = options.skip_fixed_rotation_stage
    o.mapper.skip_retriangulation = options.skip_retriangulation
    ba = o.mapper.bundle_adjustment
    ba.refine_focal_length = options.refine_focal_length
    ba.refine_principal_point = options.refine_principal_point
    ba.refine_extra_params = options.refine_extra_params
    o.mapper.global_positioning.use_gpu = False
    ba.ceres.use_gpu = False
    return o


def _incremental_options(options: MappingOptions) -> pycolmap.IncrementalPipelineOptions:
    o = colmap_options(pycolmap.IncrementalPipelineOptions, seed=options.random_seed)
    o.min_num_matches = options.min_num_matches
    o.min_model_size = options.min_model_size
    o.num_threads = o.mapper.num_threads = options.num_threads
    o.ba_refine_focal_length = options.refine_focal_length
    o.ba_refine_principal_point = options.refine_principal_point
    o.ba_refine_extra_params = options.refine_extra_params
    return o


def remove_model_folder(output_dir: Path) -> None:
    """Remove a mapper's output folder and any staging or set-aside folder :func:`atomic_folder` left beside it
    (a run that stopped)."""
    shutil.rmtree(output_dir, ignore_errors=True)
    for kind in ("new", "old"):
        for stale in output_dir.parent.glob(f".{output_dir.name}.{kind}.*"):
            shutil.rmtree(stale, ignore_errors=True)


def _run_mapper(mapper: Mapper, database_path: Path, image_dir: str | Path, output_dir: Path,
                options: MappingOptions, scene: str) -> tuple[dict[int, pycolmap.Reconstruction], str | None]:
    """Map into a staging folder of its own beside ``output_dir`` (:func:`atomic_folder`), renamed to it once the
    mapper has written every model: a run stopped while mapping (or while the mapper runs in a thread of a process
    that stops) leaves no half-written model for a rerun to load."""
    remove_model_folder(output_dir)
    try:
        with atomic_folder(output_dir) as staging:
            if mapper == Mapper.GLOBAL:
                models = pycolmap.global_mapping(str(database_path), str(image_dir), str(staging),
                                                 _global_options(options))
            else:
                models = pycolmap.incremental_mapping(str(database_path), str(image_dir), str(staging),
                                                      _incremental_options(options))
    except Exception as exc:  # noqa: BLE001 - a scene that fails to map is reported, not fatal
        logger.warning("%s: %s mapping failed: %s", scene, mapper.value, exc)
        output_dir.mkdir(parents=True, exist_ok=True)
        return {}, f"{mapper.value} mapping failed: {exc}"
    return dict(models), (None if models else f"{mapper.value} mapping gave no model")


def _load_models(output_dir: Path) -> dict[int, pycolmap.Reconstruction]:
    models = {}
    for sub in sorted(output_dir.iterdir()) if output_dir.is_dir() else []:
        if sub.is_dir() and sub.name.isdigit() and (sub / "images.bin").exists():
            models[int(sub.name)] = pycolmap.Reconstruction(str(sub))
    return models


def best_model(models: dict[int, pycolmap.Reconstruction]) -> pycolmap.Reconstruction | None:
    """The model with the most registered images (ties: the lowest model number)."""
    return max(sorted(models.items()), key=lambda kv: kv[1].num_reg_images(), default=(None, None))[1]


def describe_model(best: pycolmap.Reconstruction | None, database: DatabaseSummary, scene: str,
                   min_points_per_image: int, failure: str | None = None,
                   reasons: dict[str, str] | None = None) -> SceneModel:
    """The :class:`SceneModel` of a scene's reconstruction ``best``: its registered cameras (those seeing at least
    ``min_points_per_image`` of its points) and, for every other camera of the database (``database``: its
    summary, :func:`projector.database.read_summary`), why not (``reasons`` first, given per camera by the caller)."""
    reasons = reasons or {}
    all_images, verified_ids = database.cameras, database.verified
    result = SceneModel(scene=scene, reconstruction=best, failure=failure)
    if best is None and failure is None:
        result.failure = "no model: too few verified pairs to reconstruct"
    weak: dict[str, str] = {}
    registered: set[str] = set()
    for image_id in best.reg_image_ids() if best is not None else []:
        image = best.image(image_id)
        if image.num_points3D < min_points_per_image:
            weak[camera_of_image(image.name)] = (f"registered with only {image.num_points3D} 3D points "
                                                 f"(< {min_points_per_image}): pose unreliable")
        else:
            registered.add(image.name)
    result.registered = sorted(camera_of_image(n) for n in registered)
    for image_id, cam in sorted(all_images.items(), key=lambda kv: kv[1]):
        if cam in result.registered:
            continue
        if cam in weak:
            result.unregistered[cam] = weak[cam]
        elif cam in reasons:
            result.unregistered[cam] = reasons[cam]
        elif image_id not in verified_ids:
            result.unregistered[cam] = "no verified image pair (overlap too small or no tent in view)"
        elif best is None:
            result.unregistered[cam] = result.failure or "scene did not reconstruct"
        else:
            result.unregistered[cam] = "not registered in the scene's largest model"
    return result


def map_scene(
    database_path: str | Path, image_dir: str | Path, output_dir: str | Path, *,
    options: MappingOptions | None = None, scene: str = "", database: DatabaseSummary | None = None,
) -> SceneModel:
    """Reconstruct one scene from its database; never raises for a scene that does not reconstruct.

    Returns a :class:`SceneModel`: the largest model, the registered cameras, and for every camera in the
    database that is not registered, the reason (no verified pair, or not in the largest model). ``database``: the
    database's summary when the caller has read it (:func:`projector.database.read_summary`), else read here.
    """
    options = options or MappingOptions()
    database_path, output_dir = Path(database_path), Path(output_dir)
    scene = scene or database_path.parent.name
    t0 = time.perf_counter()
    database = database or read_summary(database_path)
    models = _load_models(output_dir) if options.reuse else {}
    if not models:
        mappers = [options.mapper] + ([m for m in Mapper if m != options.mapper] if options.fallback else [])
        failure = None
        for mapper in mappers:
            models, failure = _run_mapper(mapper, database_path, image_dir, output_dir, options, scene)
            if models:
                break
            logger.warning("%s: %s mapping gave no model%s", scene, mapper.value,
                           ", trying the next mapper" if mapper != mappers[-1] else "")
    else:
        failure = None
        logger.info("%s: reusing %d model(s) in %s", scene, len(models), output_dir)
    result = describe_model(best_model(models), database, scene, options.min_points_per_image, failure)
    result.num_models = len(models)
    result.seconds = time.perf_counter() - t0
    logger.info("%s: %d models, %d/%d cameras registered, %.1f s", scene, len(models), len(result.registered),
                len(result.registered) + len(result.unregistered), result.seconds)
    return result
