"""TEMPORARY stand-in for the SfM front end (issue 6, ``projector``) so that `dome-calib calibrate` and the demo
run end to end before it lands: pycolmap SIFT, exhaustive matching and GLOMAP global mapping per scene, scenes
merged by a robust similarity on shared camera centres. No prior-based pair selection, no executor, small
captures only. :func:`dome_calib.pipeline_stages.run_sfm_stage` uses ``projector.run_sfm`` whenever it exists.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pycolmap

from dome_calib.align import AlignOptions, align_cameras, sim3_apply, transform_cameras
from dome_calib.ba.problem import BAProblem
from dome_calib.bundle import Camera, CameraType
from dome_calib.camera import colmap_to_opencv_px, intr_to_K
from dome_calib.errors import CaptureError

logger = logging.getLogger(__name__)


def _type_of(name: str) -> CameraType:
    prefix = name.split("_", 1)[0]
    return CameraType.HD if prefix == "00" else CameraType.KINECT_COLOR if prefix == "50" else CameraType.VGA


def _int_part(name: str, k: int) -> int:
    parts = name.split("_")
    return int(parts[k]) if len(parts) == 2 and parts[k].isdigit() else 0


def _scene_reconstruction(image_dir: Path, work: Path) -> pycolmap.Reconstruction | None:
    work.mkdir(parents=True, exist_ok=True)
    db = work / "database.db"
    done = work / "matched.ok"
    if not done.exists():
        db.unlink(missing_ok=True)
        extraction = pycolmap.FeatureExtractionOptions(num_threads=2)
        extraction.sift.max_num_features = 8192
        pycolmap.extract_features(db, image_dir, camera_mode=pycolmap.CameraMode.PER_IMAGE,
                                  reader_options=pycolmap.ImageReaderOptions(camera_model="OPENCV"),
                                  extraction_options=extraction, device=pycolmap.Device.cpu)
        matching = pycolmap.FeatureMatchingOptions(num_threads=2)
        pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
        done.write_text("ok\n")
    options = pycolmap.GlobalPipelineOptions(num_threads=2, random_seed=0)
    recs = pycolmap.global_mapping(db, image_dir, work / "sparse", options)
    if not recs:
        return None
    return max(recs.values(), key=lambda r: r.num_reg_images())


def _cameras_of(rec: pycolmap.Reconstruction) -> dict[str, Camera]:
    out = {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        name = Path(image.name).stem
        cam = image.camera
        fx, fy, cx, cy, k1, k2, p1, p2 = cam.params
        pose = image.cam_from_world()
        res = (int(cam.width), int(cam.height))
        cam_type = _type_of(name)
        out[name] = Camera(name=name, type=cam_type, resolution=res,
                           K=intr_to_K(np.array([fx, fy, cx - 0.5, cy - 0.5])), dist=np.array([k1, k2, p1, p2, 0.0]),
                           R=np.asarray(pose.rotation.matrix()), t_cm=np.asarray(pose.translation, dtype=float),
                           panel=_int_part(name, 0), node=_int_part(name, 1))
    return out


def _observations(rec: pycolmap.Reconstruction) -> tuple[np.ndarray, list[str], list[np.ndarray]]:
    """Points (P, 3) and, per point, (camera names, (k, 2) OpenCV px)."""
    pts, names, uvs = [], [], []
    for p in rec.points3D.values():
        cams, uv = [], []
        for el in p.track.elements:
            image = rec.images[el.image_id]
            cams.append(Path(image.name).stem)
            uv.append(image.points2D[el.point2D_idx].xy)
        pts.append(p.xyz)
        names.append(cams)
        uvs.append(colmap_to_opencv_px(np.asarray(uv)))
    return np.asarray(pts, dtype=float).reshape(-1, 3), names, uvs


def fallback_sfm(capture: Path, work_dir: Path, scenes: list[str]) -> tuple[BAProblem, dict[str, str], dict]:
    """Per-scene pycolmap reconstruction, merged into one frame as a :class:`BAProblem`."""
    pycolmap.logging.minloglevel = 1  # COLMAP's per-image INFO lines would drown the progress display
    recs = {}
    for scene in scenes:
        rec = _scene_reconstruction(capture / "scenes" / scene, Path(work_dir) / scene)
        if rec is not None and rec.num_reg_images() >= 3:
            recs[scene] = rec
        logger.info("sfm %s: %d images registered", scene, 0 if rec is None else rec.num_reg_images())
    if not recs:
        raise CaptureError(f"{capture}: no scene could be reconstructed")
    ref = max(recs, key=lambda s: recs[s].num_reg_images())
    ref_cams = _cameras_of(recs[ref])
    extent = np.median(np.linalg.norm([c.center_cm for c in ref_cams.values()] - np.mean(
        [c.center_cm for c in ref_cams.values()], axis=0), axis=1))
    cameras: dict[str, Camera] = dict(ref_cams)
    scene_points, cam_idx, pt_idx, uv_all = {}, [], [], []
    per_scene_obs = []
    for scene, rec in recs.items():
        cams = _cameras_of(rec)
        if scene == ref:
            sim = pycolmap.Sim3d()
        else:
            sim = align_cameras(cams, ref_cams, AlignOptions(max_error_cm=0.02 * extent)).tgt_from_src
            for n, c in transform_cameras(cams, sim).items():
                cameras.setdefault(n, c)
        pts, names, uvs = _observations(rec)
        scene_points[scene] = sim3_apply(sim, pts)
        per_scene_obs.append((names, uvs))
    order = sorted(cameras)
    index = {n: i for i, n in enumerate(order)}
    offset = 0
    for (names, uvs), pts in zip(per_scene_obs, scene_points.values()):
        for k, (cams, uv) in enumerate(zip(names, uvs)):
            cam_idx.extend(index[n] for n in cams)
            pt_idx.extend([offset + k] * len(cams))
            uv_all.append(uv)
        offset += len(pts)
    problem = BAProblem.from_cameras(cameras, scene_points, camera_index=np.asarray(cam_idx),
                                     point_index=np.asarray(pt_idx), uv_px=np.concatenate(uv_all),
                                     camera_names=order)
    registered = set(cameras)
    images = {p.stem for s in scenes for p in (capture / "scenes" / s).glob("*.png")}
    failures = {n: "not registered in any scene" for n in sorted(images - registered)}
    stats = {"front_end": "pycolmap fallback (exhaustive matching, GLOMAP)",
             "registered": {s: r.num_reg_images() for s, r in recs.items()},
             "points": int(problem.n_points), "observations": int(problem.n_observations)}
    return problem, failures, stats
