"""Stage 5: bring the per-scene reconstructions into one frame and gather the observations for the bundle adjustment.

The cameras are the same physical cameras in every scene, so scenes are related by similarity transforms
estimated on their shared cameras:

1. The scene with the most registered cameras is the reference. Every other scene is aligned to the frame
   built so far (reference plus scenes already aligned) by a robust similarity on shared camera centres
   (pycolmap's LO-RANSAC ``estimate_sim3d_robust``, threshold relative to the camera spread), whose inliers
   must also agree in orientation (``max_rotation_error_deg``); the final similarity is the least-squares fit
   on those inliers.
2. Each scene is pre-scaled by its similarity's scale; a gtsam pose graph (:mod:`projector.pose_graph`) then
   jointly optimises the rigid scene alignments and one pose per camera from every (scene, camera)
   registration under a robust (Cauchy) kernel, starting from step 1's alignments and, per camera, the medoid
   of its registrations. Registrations that still disagree with the optimised pose (beyond the step-1
   thresholds) are dropped from that scene and the graph is solved again without them (at most 3 solves). ``PoseAveraging.CHORDAL_MEAN`` keeps step 1's alignments and
   averages instead (centres: mean of inliers; rotations: chordal L2 mean).
3. The merged frame is mapped onto the prior (previous calibration or nominal layout) by the same robust
   similarity on camera centres, so the result is in centimetres in the Panoptic world frame.
4. Every 3D point of every scene, with its observations (COLMAP pixels converted to OpenCV's convention),
   goes into the :class:`projector.observations.Observations` handed to the bundle adjustment.
"""
from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Annotated

import numpy as np
import pycolmap

from dome_calib.align import Alignment, sim3_apply
from dome_calib.bundle import Camera
from dome_calib.camera import colmap_to_opencv_px
from dome_calib.colmap_options import colmap_options
from dome_calib.rotation import rotation_angle_deg
from dome_calib.ties import UNIT_QUANTUM, quantize
from projector.database import camera_of_image, intrinsics_from_colmap
from projector.mapping import SceneModel
from projector.observations import Observations
from projector.pose_graph import optimise_pose_graph
from dome_calib.options import AtLeast, Lax, options
from dome_calib.schema import PosFinite

logger = logging.getLogger(__name__)


class PoseAveraging(StrEnum):
    POSE_GRAPH = "pose_graph"  # joint robust gtsam optimisation of scene alignments and camera poses
    CHORDAL_MEAN = "chordal_mean"  # sequential alignments only; mean centres, chordal mean rotations


@options
class MergeOptions:
    inlier_threshold_rel: PosFinite = 0.02  # RANSAC threshold on centres, fraction of the camera spread
    max_rotation_error_deg: PosFinite = 5.0
    min_shared_cameras: AtLeast(3) = 3
    pose_averaging: Annotated[PoseAveraging, Lax] = PoseAveraging.POSE_GRAPH
    robust_k: PosFinite = 2.0  # Cauchy kernel width of the pose graph, in sigmas (sigma = a third of the thresholds)
    prior_inlier_threshold_cm: PosFinite = 15.0
    # True: K from the scenes (median; set by run_sfm when mapping refines focal lengths), else from the prior
    use_colmap_intrinsics: bool = False


@dataclass(kw_only=True)
class ScenePoses:
    """Cameras of one scene: name -> (R cam_from_world (3, 3), centre (3,)), in the scene's own frame."""

    scene: str
    R: dict[str, np.ndarray]
    center: dict[str, np.ndarray]


def scene_poses(model: SceneModel) -> ScenePoses:
    rec = model.reconstruction
    R, C = {}, {}
    keep = set(model.registered)
    for image_id in rec.reg_image_ids():
        im = rec.image(image_id)
        name = camera_of_image(im.name)
        if name not in keep:
            continue
        R[name] = np.asarray(im.cam_from_world().rotation.matrix())
        C[name] = np.asarray(im.projection_center())
    return ScenePoses(scene=model.scene, R=R, center=C)


def robust_similarity(src: Mapping[str, np.ndarray], tgt: Mapping[str, np.ndarray], threshold: float,
                      src_R: Mapping[str, np.ndarray] | None = None, tgt_R: Mapping[str, np.ndarray] | None = None,
                      max_rotation_error_deg: float = 5.0, min_shared: int = 3, unit: str = "cm") -> Alignment | None:
    """Similarity ``tgt_from_src`` from shared names' centres (LO-RANSAC, then least squares on inliers).

    ``threshold`` is in the target frame's unit, which ``unit`` names (the result's residuals are in it too).
    With rotations given, an inlier must also agree in orientation within ``max_rotation_error_deg``.
    Returns None with fewer than ``min_shared`` shared names or inliers.
    """
    names = sorted(set(src) & set(tgt))
    if len(names) < max(min_shared, 3):
        return None
    A = np.stack([src[n] for n in names])
    B = np.stack([tgt[n] for n in names])
    ransac = colmap_options(pycolmap.RANSACOptions, max_error=threshold)
    sim = pycolmap.estimate_sim3d_robust(A, B, ransac)
    if sim is None:
        return None
    sim = sim["tgt_from_src"] if isinstance(sim, dict) else sim
    M = np.asarray(sim.matrix())
    s = float(np.cbrt(np.linalg.det(M[:, :3])))
    Ra = M[:, :3] / s
    res = np.linalg.norm(A @ M[:, :3].T + M[:, 3] - B, axis=1)
    ok = res < threshold
    if src_R is not None and tgt_R is not None:
        for k, n in enumerate(names):
            # cam_from_tgt = cam_from_src @ Ra^T must match the target's rotation
            ok[k] &= rotation_angle_deg(tgt_R[n], src_R[n] @ Ra.T) < max_rotation_error_deg
    if ok.sum() < max(min_shared, 3):
        return None
    ls = pycolmap.estimate_sim3d(A[ok], B[ok])
    final = ls if ls is not None else sim
    res = np.linalg.norm(sim3_apply(final, A) - B, axis=1)
    return Alignment(tgt_from_src=final, names=names, inliers=[n for n, k in zip(names, ok) if k],
                     residual={n: float(r) for n, r in zip(names, res)}, unit=unit)


def transform_poses(p: ScenePoses, a: Alignment) -> ScenePoses:
    """Poses of ``p`` expressed in the alignment's target frame."""
    Ra = a.rotation
    return ScenePoses(scene=p.scene, R={n: R @ Ra.T for n, R in p.R.items()},
                      center={n: a.apply(C) for n, C in p.center.items()})


def chordal_mean(Rs: list[np.ndarray]) -> np.ndarray:
    """Rotation closest (Frobenius) to the mean of the rotation matrices."""
    U, _, Vt = np.linalg.svd(np.mean(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _spread(centers: Mapping[str, np.ndarray]) -> float:
    C = np.stack(list(centers.values()))
    return float(np.sqrt(np.mean(np.sum((C - C.mean(0)) ** 2, axis=1)))) or 1.0


@dataclass(kw_only=True)
class AlignedPoses:
    """Scenes brought into the common frame (the reference scene's, at its scale)."""

    reference: str
    alignment: dict[str, Alignment]  # scene -> common frame
    R: dict[str, np.ndarray]  # camera -> R cam_from_common
    center: dict[str, np.ndarray]  # camera -> centre in the common frame
    kept: dict[str, list[str]]  # scene -> cameras whose pose in that scene is used
    unaligned: dict[str, str] = field(default_factory=dict)
    excluded: dict[tuple[str, str], str] = field(default_factory=dict)  # (scene, camera) -> reason


def _disagreement(dist: float, angle_deg: float, spread: float) -> str:
    return f"pose disagrees with the other scenes by {dist / spread:.1%} of the dome size ({angle_deg:.1f} deg)"


def _sequential(poses: Mapping[str, ScenePoses], options: MergeOptions) -> AlignedPoses:
    """Steps 1-2 of the chordal-mean path: sequential robust similarities, then pose averaging."""
    order = sorted(poses, key=lambda s: (-len(poses[s].R), s))
    ref = order[0]
    merged: dict[str, ScenePoses] = {ref: poses[ref]}
    unit = f"{ref} units"  # the common frame is the reference scene's (no metric scale yet)
    result_align = {ref: Alignment.identity(sorted(poses[ref].R), unit)}
    unaligned: dict[str, str] = {}
    excluded: dict[tuple[str, str], str] = {}
    pending = order[1:]
    while pending:  # align scenes in rounds, so a scene may link through one aligned before it
        progressed = False
        for scene in list(pending):
            tgt_C = {n: C for p in merged.values() for n, C in p.center.items()}
            tgt_R = {n: R for p in merged.values() for n, R in p.R.items()}
            thr = options.inlier_threshold_rel * _spread(tgt_C)
            a = robust_similarity(poses[scene].center, tgt_C, thr, poses[scene].R, tgt_R,
                                  options.max_rotation_error_deg, options.min_shared_cameras, unit)
            if a is None:
                continue
            outliers = (set(poses[scene].R) & set(tgt_C)) - set(a.inliers)
            for n in sorted(outliers):
                C = a.apply(poses[scene].center[n])
                angle = float(rotation_angle_deg(tgt_R[n], poses[scene].R[n] @ a.rotation.T))
                excluded[(scene, n)] = _disagreement(float(np.linalg.norm(C - tgt_C[n])), angle,
                                                     _spread(tgt_C))
            kept = ScenePoses(scene=scene, R={n: R for n, R in poses[scene].R.items() if n not in outliers},
                              center={n: C for n, C in poses[scene].center.items() if n not in outliers})
            merged[scene] = transform_poses(kept, a)
            result_align[scene] = a
            pending.remove(scene)
            progressed = True
        if not progressed:
            break
    for scene in pending:
        unaligned[scene] = f"shares fewer than {options.min_shared_cameras} consistent cameras with the other scenes"
        logger.warning("%s: %s", scene, unaligned[scene])
    names = sorted({n for p in merged.values() for n in p.R})
    avg_R = {n: chordal_mean([p.R[n] for p in merged.values() if n in p.R]) for n in names}
    avg_C = {n: np.mean([p.center[n] for p in merged.values() if n in p.center], axis=0) for n in names}
    return AlignedPoses(reference=ref, alignment=result_align, R=avg_R, center=avg_C,
                        kept={s: sorted(p.R) for s, p in merged.items()}, unaligned=unaligned, excluded=excluded)


def _pose_graph(poses: Mapping[str, ScenePoses], seq: AlignedPoses, options: MergeOptions) -> AlignedPoses:
    """Step 2 with gtsam: joint robust optimisation of rigid scene alignments and camera poses (pre-scaled)."""
    ref = seq.reference
    scenes = sorted(seq.alignment)
    spread = _spread(seq.center)
    thr = options.inlier_threshold_rel * spread
    # every registration of an aligned scene takes part; the robust kernel and the check below judge it
    measured = {s: {n: (R.T, seq.alignment[s].scale * poses[s].center[n]) for n, R in poses[s].R.items()}
                for s in scenes}
    init_scene = {s: (seq.alignment[s].rotation, seq.alignment[s].translation) for s in scenes}
    init_camera = {}  # medoid of the camera's registrations (the averages of step 1 trust the reference scene)
    for n in seq.R:
        cand = [(init_scene[s][0] @ m[n][0], init_scene[s][0] @ m[n][1] + init_scene[s][1])
                for s, m in measured.items() if n in m]
        total = np.array([sum(np.linalg.norm(p[1] - q[1]) for q in cand) for p in cand])  # in scene order
        init_camera[n] = cand[int(np.argmin(quantize(total / max(total.max(), 1e-300), UNIT_QUANTUM)))]
    dropped: set[tuple[str, str]] = set()
    errors: dict[tuple[str, str], tuple[float, float]] = {}
    for rnd in range(3):  # optimise, drop disagreeing registrations, optimise again without them
        use = {s: {n: p for n, p in m.items() if (s, n) not in dropped} for s, m in measured.items()}
        out = optimise_pose_graph(use, init_scene, init_camera, ref,
                                  sigma_rotation_rad=np.radians(options.max_rotation_error_deg) / 3,
                                  sigma_translation=thr / 3, robust_k=options.robust_k)
        logger.info("pose graph: %d scenes, %d cameras, error %.4g -> %.4g in %d iterations", len(scenes),
                    len(out.common_from_camera), out.error_before, out.error_after, out.iterations)
        errors = {}
        for s, m in measured.items():
            Xr, Xt = out.common_from_scene[s]
            for n, (R_wc, C) in m.items():
                Yr, Yc = out.common_from_camera[n]
                errors[(s, n)] = (float(np.linalg.norm(Xr @ C + Xt - Yc)), float(rotation_angle_deg(Xr @ R_wc, Yr)))
        bad = {k for k, (d, ang) in errors.items() if d >= thr or ang >= options.max_rotation_error_deg}
        for n in {n for _, n in bad}:  # a camera keeps at least its best registration
            own = [k for k in errors if k[1] == n]
            if all(k in bad for k in own):
                bad.discard(min(own, key=lambda k: errors[k][0] / thr + errors[k][1] / options.max_rotation_error_deg))
        if bad == dropped or rnd == 2:
            break
        dropped = bad
        init_scene, init_camera = out.common_from_scene, out.common_from_camera
    kept = {s: sorted(n for n in measured[s] if (s, n) not in dropped) for s in scenes}
    alignment = {}
    for s in scenes:
        others = {n for o in scenes if o != s for n in kept[o]}
        inl = kept[s] if s == ref else [n for n in kept[s] if n in others]
        Xr, Xt = out.common_from_scene[s]
        alignment[s] = Alignment(tgt_from_src=pycolmap.Sim3d(seq.alignment[s].scale, pycolmap.Rotation3d(Xr), Xt),
                                 names=seq.alignment[s].names, inliers=inl,
                                 residual={n: errors[(s, n)][0] for n in kept[s]}, unit=seq.alignment[s].unit)
    names = sorted({n for k in kept.values() for n in k})
    return AlignedPoses(reference=ref, alignment=alignment, R={n: out.common_from_camera[n][0].T for n in names},
                        center={n: out.common_from_camera[n][1] for n in names}, kept=kept, unaligned=seq.unaligned,
                        excluded={k: _disagreement(*errors[k], spread) for k in sorted(dropped)})


def align_scenes(poses: Mapping[str, ScenePoses], options: MergeOptions | None = None) -> AlignedPoses:
    """Steps 1-2: scenes into the common frame and one pose per camera (see the module docstring)."""
    options = options or MergeOptions()
    seq = _sequential(poses, options)
    if options.pose_averaging == PoseAveraging.CHORDAL_MEAN:
        return seq
    return _pose_graph(poses, seq, options)


@dataclass(kw_only=True)
class MergeResult:
    observations: Observations
    scene_alignment: dict[str, Alignment] = field(default_factory=dict)  # scene -> merged frame
    prior_alignment: Alignment | None = None  # merged frame -> prior (cm)
    unaligned_scenes: dict[str, str] = field(default_factory=dict)
    excluded: dict[tuple[str, str], str] = field(default_factory=dict)  # (scene, camera) -> reason


def merge_scenes(models: list[SceneModel], prior: Mapping[str, Camera], options: MergeOptions | None = None,
                 *, align_to: set[str] | None = None) -> MergeResult:
    """Align the scenes' reconstructions, average the camera poses and gather the :class:`Observations`.

    ``prior`` gives the target frame (cm, Panoptic world) and the cameras' type, resolution and intrinsics;
    only the cameras in ``align_to`` (default: all of the prior) are used to align to it (cameras unknown to
    the real prior carry placeholder poses).
    Raises ValueError if no scene reconstructed or the merged frame cannot be aligned to the prior.
    """
    options = options or MergeOptions()
    poses = {m.scene: scene_poses(m) for m in models if m.reconstruction is not None}
    if not poses:
        raise ValueError("no scene reconstructed")
    aligned = align_scenes(poses, options)
    result_align, unaligned, excluded = aligned.alignment, aligned.unaligned, aligned.excluded
    kept = {s: set(cams) for s, cams in aligned.kept.items()}  # scene -> cameras whose pose it contributes
    names = sorted(aligned.R)
    avg_R, avg_C = aligned.R, aligned.center
    # merged frame -> prior
    prior_C = {n: c.center_cm for n, c in prior.items() if align_to is None or n in align_to}
    prior_R = {n: c.R for n, c in prior.items() if align_to is None or n in align_to}
    # the RANSAC threshold applies to target-frame (cm) residuals, so it is given in cm directly
    pa = robust_similarity(avg_C, prior_C, options.prior_inlier_threshold_cm, avg_R, prior_R, 30.0, 3, "cm")
    if pa is None:
        raise ValueError("the reconstruction cannot be aligned to the prior (fewer than 3 consistent cameras)")
    cameras: dict[str, Camera] = {}
    pa_R = pa.rotation
    for n in names:
        R = avg_R[n] @ pa_R.T
        C = pa.apply(avg_C[n])
        base = prior[n]
        cam = replace(base, R=R, t_cm=-R @ C, K=base.K.copy(), dist=base.dist.copy())
        if options.use_colmap_intrinsics:
            Ks = [intrinsics_from_colmap(m.reconstruction.camera(m.reconstruction.find_image_with_name(
                f"{n}.png").camera_id))[0] for m in models if n in kept.get(m.scene, ())]
            cam.K = np.median(np.stack(Ks), axis=0)
        cameras[n] = cam
    # points and observations
    cam_index = {n: i for i, n in enumerate(names)}
    scene_points: dict[str, np.ndarray] = {}
    ci, pi, uv = [], [], []
    offset = 0
    for m in models:
        if m.scene not in kept:
            continue
        a = result_align[m.scene]
        rec = m.reconstruction
        image_cam = {im_id: cam_index[camera_of_image(rec.image(im_id).name)] for im_id in rec.reg_image_ids()
                     if camera_of_image(rec.image(im_id).name) in kept[m.scene]}
        kept_xyz = []
        for pid in rec.point3D_ids():
            point = rec.point3D(pid)
            els = [el for el in point.track.elements if el.image_id in image_cam]
            if len(els) < 2:  # a point needs two kept views to be constrained
                continue
            for el in els:
                ci.append(image_cam[el.image_id])
                pi.append(offset + len(kept_xyz))
                uv.append(rec.image(el.image_id).points2D[el.point2D_idx].xy)
            kept_xyz.append(point.xyz)
        X = np.array(kept_xyz, dtype=float).reshape(-1, 3)
        scene_points[m.scene] = pa.apply(a.apply(X))
        offset += len(kept_xyz)
    uv_px = colmap_to_opencv_px(np.array(uv).reshape(-1, 2))
    observations = Observations(camera_names=names, cameras=cameras, scene_points_cm=scene_points,
                                camera_index=np.array(ci, np.int64), point_index=np.array(pi, np.int64), uv_px=uv_px)
    return MergeResult(observations=observations, scene_alignment=result_align, prior_alignment=pa,
                       unaligned_scenes=unaligned, excluded=excluded)
