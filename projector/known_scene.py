"""Later scenes of a capture without mapping: the tent triangulated with the cameras held at the first scene's poses.

The scenes of a capture see the same cameras. Once the reference scene is mapped (GLOMAP, :mod:`projector.mapping`,
with its focal lengths refined: ``KnownPoseOptions.refine_reference_focal``), every camera it registered has a pose
good to about a centimetre and a tenth of a degree, in the reference's frame. A later scene then needs no mapping
of its own, and fewer pairs (:func:`projector.scene.known_scene_pairs`: chosen by the reference's geometry,
``pairs_per_camera`` partners per camera):

1. its points are triangulated from its verified matches with those cameras held at the reference's poses and
   intrinsics, by COLMAP's point triangulator (:func:`projector.known_poses.triangulate_known`), with the
   thresholds below (chosen by the end-to-end accuracy, not by generosity);
2. each camera with features in the scene that the reference did not register is registered against those points
   by absolute pose (:func:`projector.known_poses.register_cameras`, LO-RANSAC then refinement) and its inlier
   observations join the points' tracks.

The result is an ordinary :class:`projector.mapping.SceneModel` in the reference's frame and unit, so
:func:`projector.merge.merge_scenes` aligns it (about the identity) and runs its consistency checks as for a
mapped scene. When too few cameras register or too few points triangulate (the reference is poor, or the scene
shares too little with it), :func:`map_known_scene` says so and the caller maps the scene with GLOMAP instead.

Work folder: ``WORK/<scene>/known/model/`` (the model) and ``known/reference.json`` (which reference model it was
made from, by a digest of its poses and intrinsics). A rerun reuses the model only if the digest matches.
"""
from __future__ import annotations

import hashlib
import json
import logging
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pycolmap

from dome_calib.bundle import Camera, camera_type_from_name
from dome_calib.colmap_options import colmap_options
from dome_calib.io_utils import atomic_folder, atomic_write_text
from projector.database import DatabaseSummary, camera_of_image, intrinsics_from_colmap, read_summary
from projector.known_poses import add_posed_image, register_cameras, triangulate_known
from projector.mapping import SceneModel, describe_model
from dome_calib.options import AtLeast, options
from dome_calib.schema import NonNegFinite, PosFinite

logger = logging.getLogger(__name__)

#: Reprojection error (px) for merging tracks and completing them with more observations (COLMAP's default). The
#: held poses are GLOMAP's (~1 cm / 0.1 deg off) with the design's intrinsics (HD focal lengths up to 23 % off as
#: built), so a point reprojects ~1 px off (median; 95 % within 2.5 px on the panel bench) and a generous limit looked
#: right; measured, it is not: with GLOMAP's own 15 px the long tracks collect wrong observations (the observations'
#: noise 0.209 px against 0.202 from GLOMAP's scenes) and the bundle adjustment lands further from the oracle on the
#: panel bench (centres x1.06-1.09, focal x1.22-1.33 of the oracle's error, against x0.99 / x1.06 before); with 4 px
#: it lands as close as before (README, "Structure from motion").
KNOWN_MAX_REPROJ_ERROR_PX = 4.0
#: Reprojection error (px) above which an observation is dropped after the points are refined (COLMAP's default).
#: Per scene this keeps 98-99 % of the observations GLOMAP's own run of the scene gives on the panel bench (HD
#: cameras 83 %, VGA 101 %); 8 px would keep the HD cameras' all, but only measured with 15 px above (see there).
KNOWN_FILTER_MAX_REPROJ_ERROR_PX = 4.0
#: Smallest triangulation angle (deg) of a point (GLOMAP's; COLMAP's default 1.5 drops far-apart views' points).
KNOWN_MIN_TRI_ANGLE_DEG = 1.0
#: The scene falls back to GLOMAP when fewer than this fraction of its cameras with a verified pair register ...
KNOWN_MIN_REGISTERED_FRACTION = 0.9
#: ... or fewer than this many points triangulate (a poor reference, or a scene sharing little with it).
KNOWN_MIN_POINTS = 100


@options
class KnownPoseOptions:
    enabled: bool = True  # False: every scene is mapped with GLOMAP (README, SfM: measured both ways)
    # only when the reference scene has at least this many images with features: known poses save time, and a
    # small capture's GLOMAP runs take about a second each; on the 16-camera demo, known poses gave focal lengths
    # 0.23 % off (median) instead of 0.09 % and a person triangulated 1.12 x the truth bundle's error instead of
    # 1.005 (README, SfM)
    min_images: AtLeast(0) = 40
    # the reference scene's GLOMAP refines focal lengths, and the later scenes are triangulated with them: with the
    # design's (HD up to 23 % off as built) the full dome's later scenes lost HD observations at 4 px and the
    # ground-truth oracle's centres went 1.51 -> 2.18 mm median; refined, the bundle adjustment's ratios to the
    # oracle are as good as with every scene mapped (README)
    refine_reference_focal: bool = True
    # partners per camera of a later scene, by the reference's geometry (GLOMAP's scenes: PairOptions'
    # max_pairs_per_camera, 25): a point needs two views to be triangulated at known poses. Full dome, per later
    # scene: 3,209 pairs, 19 s of matching (15: 4,577, 28 s; 25: 7,511, 43 s); ratios to the oracle as good with
    # each (README, SfM)
    pairs_per_camera: AtLeast(1) = 10
    max_reproj_error_px: PosFinite = KNOWN_MAX_REPROJ_ERROR_PX
    filter_max_reproj_error_px: PosFinite = KNOWN_FILTER_MAX_REPROJ_ERROR_PX
    min_tri_angle_deg: NonNegFinite = KNOWN_MIN_TRI_ANGLE_DEG
    min_registered_fraction: NonNegFinite = KNOWN_MIN_REGISTERED_FRACTION  # above 1: never enough (forces GLOMAP)
    min_points: AtLeast(0) = KNOWN_MIN_POINTS
    min_points_per_image: AtLeast(0) = 30  # as the mapper's (MappingOptions.min_points_per_image)
    reuse: bool = True


def triangulator_options(options: KnownPoseOptions) -> pycolmap.IncrementalPipelineOptions:
    o = colmap_options(pycolmap.IncrementalPipelineOptions)
    o.triangulation.merge_max_reproj_error = options.max_reproj_error_px
    o.triangulation.complete_max_reproj_error = options.max_reproj_error_px
    o.triangulation.min_angle = options.min_tri_angle_deg
    o.mapper.filter_max_reproj_error = options.filter_max_reproj_error_px
    o.mapper.filter_min_tri_angle = options.min_tri_angle_deg
    return o


def reference_cameras(reference: SceneModel) -> dict[str, Camera]:
    """The reference scene's registered cameras: pose in ITS frame and unit (not cm), intrinsics as mapped."""
    rec = reference.reconstruction
    out = {}
    for name in reference.registered:
        image = rec.find_image_with_name(f"{name}.png")
        colmap_cam = rec.camera(image.camera_id)
        K, dist = intrinsics_from_colmap(colmap_cam)
        pose = image.cam_from_world()
        out[name] = Camera(name=name, type=camera_type_from_name(name), resolution=(colmap_cam.width, colmap_cam.height),
                           K=K, dist=dist, R=np.asarray(pose.rotation.matrix()), t_cm=np.asarray(pose.translation, float),
                           panel=0, node=0)
    return out


def reference_digest(reference: SceneModel) -> str:
    """Digest of the reference's registered cameras (names, poses, intrinsics: exact doubles, as stored)."""
    h = hashlib.sha256(reference.scene.encode())
    for name, cam in sorted(reference_cameras(reference).items()):
        h.update(name.encode())
        for a in (cam.R, cam.t_cm, cam.K, cam.dist):
            h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
    return h.hexdigest()


def _database_cameras(database_path: Path) -> tuple[dict[str, Camera], dict[str, int]]:
    """Cameras of the scene's database (the prior's intrinsics, identity pose) and their image ids, by name."""
    cams, ids = {}, {}
    with pycolmap.Database.open(str(database_path)) as db:
        for im in db.read_all_images():
            name = camera_of_image(im.name)
            colmap_cam = db.read_camera(im.camera_id)
            K, dist = intrinsics_from_colmap(colmap_cam)
            cams[name] = Camera(name=name, type=camera_type_from_name(name),
                                resolution=(colmap_cam.width, colmap_cam.height), K=K, dist=dist, R=np.eye(3),
                                t_cm=np.zeros(3), panel=0, node=0)
            ids[name] = im.image_id
    return cams, ids


def _add_registered(rec: pycolmap.Reconstruction, db: pycolmap.Database, regs: dict, ids: dict[str, int]) -> None:
    """Put the cameras registered by absolute pose into ``rec``: image, pose, and their inlier observations."""
    for name, reg in sorted(regs.items()):
        add_posed_image(rec, db, db.read_image(ids[name]), reg.camera)
        for kp, pid in zip(reg.keypoint_idx, reg.point3D_ids):
            rec.add_observation(int(pid), pycolmap.TrackElement(ids[name], int(kp)))


def _load(folder: Path, digest: str) -> tuple[pycolmap.Reconstruction, dict[str, str]] | None:
    """The saved model and its absolute-pose failures, if they were made from the reference of ``digest``."""
    try:
        stamp = json.loads((folder / "reference.json").read_text())
        if stamp["digest"] != digest:
            return None
        return pycolmap.Reconstruction(str(folder / "model")), stamp.get("absolute_pose_failures", {})
    except (OSError, ValueError, KeyError):
        return None


def map_known_scene(database_path: str | Path, image_dir: str | Path, output_dir: str | Path,
                    reference: SceneModel, options: KnownPoseOptions | None = None,
                    scene: str = "") -> tuple[SceneModel, str | None]:
    """The scene's model with the reference's cameras held (module docstring), and None; or, when the result is
    too poor to use (``options``' limits), the model and the reason to map the scene with GLOMAP instead."""
    database_path = Path(database_path)
    job = KnownJob(scene=scene or database_path.parent.name, database=database_path, images=Path(image_dir),
                   output=Path(output_dir))
    return map_known_scenes([job], reference, options)[job.scene]


@dataclass(frozen=True)
class KnownJob:
    """One scene to triangulate at the reference's poses: its database, image folder and output folder."""

    scene: str
    database: Path
    images: Path
    output: Path


def map_known_scenes(jobs: list[KnownJob], reference: SceneModel, options: KnownPoseOptions | None = None
                     ) -> dict[str, tuple[SceneModel, str | None]]:
    """:func:`map_known_scene` of every job, by scene, each step over all the scenes before the next (the saved
    models and databases read, the summaries, the triangulations, the writes, the descriptions): the work folder
    goes through each module once. The same models as one scene after the other (each scene its own database)."""
    options = options or KnownPoseOptions()
    digest = reference_digest(reference)
    held = reference_cameras(reference)
    seconds = {job.scene: 0.0 for job in jobs}
    saved, db = {}, {}
    for job in jobs:  # what the work folder holds: a model made from this reference, else the database's cameras
        t0 = time.perf_counter()
        saved[job.scene] = _load(job.output, digest) if options.reuse else None
        if saved[job.scene] is not None:
            logger.info("%s: reusing the known-pose model in %s", job.scene, job.output)
        else:
            db[job.scene] = _database_cameras(job.database)
        seconds[job.scene] += time.perf_counter() - t0
    # the databases are only read below: each summary, read once, describes the model made from it
    summaries = {}
    for job in jobs:
        t0 = time.perf_counter()
        summaries[job.scene] = read_summary(job.database)
        seconds[job.scene] += time.perf_counter() - t0
    made = {}
    for job in (j for j in jobs if saved[j.scene] is None):
        t0 = time.perf_counter()
        db_cams, ids = db[job.scene]
        in_scene = sorted(n for n in held if n in ids)
        rec = triangulate_known(job.database, job.images, job.output / "triangulated", held, in_scene,
                                triangulator_options(options))
        regs, pnp_failed = register_cameras(job.database, rec, db_cams, sorted(set(ids) - set(held)))
        with pycolmap.Database.open(str(job.database)) as database:
            _add_registered(rec, database, regs, ids)
        shutil.rmtree(job.output / "triangulated", ignore_errors=True)
        made[job.scene] = rec, pnp_failed
        seconds[job.scene] += time.perf_counter() - t0
    for scene, (rec, pnp_failed) in made.items():  # the writes, together
        t0 = time.perf_counter()
        output = next(j.output for j in jobs if j.scene == scene)
        with atomic_folder(output / "model") as staging:
            rec.write(str(staging))
        atomic_write_text(output / "reference.json", json.dumps({"reference": reference.scene, "digest": digest,
                                                                 "absolute_pose_failures": pnp_failed}, indent=1))
        seconds[scene] += time.perf_counter() - t0
    out = {}
    for job in jobs:
        t0 = time.perf_counter()
        rec, pnp_failed = saved[job.scene] or made[job.scene]
        out[job.scene] = _judged(rec, pnp_failed, summaries[job.scene], job.scene, reference, options)
        out[job.scene][0].seconds = seconds[job.scene] + time.perf_counter() - t0
        logger.info("%s: known poses from %s: %d cameras registered, %d points, %.1f s%s", job.scene,
                    reference.scene, len(out[job.scene][0].registered), rec.num_points3D(),
                    out[job.scene][0].seconds, f" ({out[job.scene][1]})" if out[job.scene][1] else "")
    return out


def _judged(rec: pycolmap.Reconstruction, pnp_failed: dict[str, str], database: DatabaseSummary, scene: str,
            reference: SceneModel, options: KnownPoseOptions) -> tuple[SceneModel, str | None]:
    """The model described, and why to map the scene with GLOMAP instead (None: it will do)."""
    model = describe_model(rec, database, scene, options.min_points_per_image,
                           reasons={n: f"absolute pose against the points of {reference.scene}'s cameras: {why}"
                                    for n, why in pnp_failed.items()})
    model.num_models = 1
    n_verified = len(database.verified)  # cameras with a verified pair
    need = options.min_registered_fraction * n_verified
    why = None
    if len(model.registered) < need:
        why = (f"known poses registered only {len(model.registered)} of the {n_verified} cameras with a verified pair "
               f"(need {options.min_registered_fraction:.0%})")
    elif rec.num_points3D() < options.min_points:
        why = f"known poses triangulated only {rec.num_points3D()} points (need {options.min_points})"
    return model, why
