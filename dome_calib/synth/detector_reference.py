"""The 3D reference a detector is judged against on a capture without ground truth: a robust body per frame.

For a capture of one person seen by a few synchronised cameras (the real one: Pose2Sim's demo, 4 phones, 60 fps):

1. per camera and frame, the person: first the tallest detection, then the one nearest the first fit's
   projection (a second, partial person in some views is not the one measured);
2. a robust triangulation per joint and frame (:func:`dome_calib.recon.triangulate.triangulate`);
3. the cameras' poses refined by the bundle adjustment (:mod:`dome_calib.ba`, Huber, intrinsics and distortion
   held) on those points: a calibration a few pixels off would otherwise pass for detector bias (the real one is
   30-40 px off in two of its four cameras; 1-2 deg, a few cm);
4. the triangulation again with the refined cameras, inliers within the adjustment's own outlier threshold
   (5 x its robust noise); neck and body centre as the midpoints of the shoulders and hips (BODY_25B derives them);
5. per observation, its leverage in its point's weighted fit (``w J (sum w J^T J)^-1 J^T``, the mean of the two
   coordinates'), the person's height in each view and which joints its body hides.

What the refinement cannot tell apart: an offset common to all of a person's joints in one view is a camera turned
by a hair; with one person, that part of a detector's per-person bias is calibration and is not measured.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.ba import BAOptions, BAProblem, ParamGroup, bundle_adjust
from dome_calib.bundle import Bundle
from dome_calib.recon.project import ViewSet, project_points, view_set
from dome_calib.recon.triangulate import TriangulationOptions, point_jacobian, triangulate
from dome_calib.rotation import rotation_angle_deg
from dome_calib.synth.body_volume import occluded_joints
from dome_calib.synth.detector_stats import Track
from dome_calib.synth.group import NOMINAL_BONE_CM, PARENT19, GroupTruth

NOMINAL_HEIGHT_CM = 170.0
_LIMB_BONES = [4, 5, 7, 8, 10, 11, 13, 14]  # upper and lower arms and legs (joint -> its parent)
_DERIVED = {0: (3, 9), 2: (6, 12)}  # neck, body centre: midpoints


@dataclass(frozen=True)
class Reference:
    """The fit: track (the statistics' input), X_cm (F, 19, 3), the refined bundle, per camera what the
    refinement changed, the adjustment's noise and threshold (px), the person's bone scale (x nominal)."""

    track: Track
    X_cm: np.ndarray
    bundle: Bundle
    cameras: dict[str, dict]
    ba_sigma_px: float
    ba_threshold_px: float
    scale: float


def _pick(people: dict[str, dict[int, np.ndarray]], cams: list[str], frames: np.ndarray,
          ref_uv: np.ndarray | None) -> np.ndarray:
    """(F, V, 19, 3): per view and frame the tallest detection, or the one nearest ``ref_uv`` (F, V, 19, 2)."""
    kp = np.zeros((len(frames), len(cams), 19, 3))
    for v, cam in enumerate(cams):
        for k, f in enumerate(frames):
            p = people.get(cam, {}).get(int(f))
            if p is None or len(p) == 0:
                continue
            seen = p[..., 2] > 0
            if ref_uv is None:
                y = np.where(seen, p[..., 1], np.nan)
                score = -(np.nanmax(y, 1) - np.nanmin(y, 1))
            else:
                d = np.linalg.norm(p[..., :2] - ref_uv[k, v][None], axis=-1)
                score = np.nanmedian(np.where(seen, d, np.nan), axis=1)
            kp[k, v] = p[int(np.nanargmin(np.where(np.isfinite(score), score, np.inf)))]
    return kp


def _triangulate(views: ViewSet, kp: np.ndarray, threshold_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, V, 19, 3) -> ((F, 19, 3) cm, (F, V, 19) inliers)."""
    F, V = kp.shape[:2]
    c = kp[..., 2].transpose(0, 2, 1).reshape(-1, V)
    uv = np.where(c[..., None] > 0, kp[..., :2].transpose(0, 2, 1, 3).reshape(-1, V, 2), np.nan)
    tri = triangulate(views, uv, np.where(c > 0, np.minimum(c, 1.0), np.nan),
                      TriangulationOptions(inlier_threshold_px=threshold_px))
    X = tri.X_cm.reshape(F, 19, 3)
    for j, (a, b) in _DERIVED.items():
        X[:, j] = 0.5 * (X[:, a] + X[:, b])
    return X, tri.inliers.reshape(F, 19, V).transpose(0, 2, 1)


def _leverage(views: ViewSet, X: np.ndarray, kp: np.ndarray, inliers: np.ndarray) -> np.ndarray:
    """(F, V, 19) leverage of each inlier observation in its point's confidence-weighted fit (0 elsewhere)."""
    F, V = kp.shape[:2]
    Xf = X.reshape(-1, 3)
    ok = np.all(np.isfinite(Xf), axis=1)
    _, Jac = point_jacobian(views, np.where(ok[:, None], Xf, 0.0))  # (P, V, 2, 3)
    w = np.where(inliers.transpose(0, 2, 1).reshape(-1, V),
                 np.minimum(kp[..., 2].transpose(0, 2, 1).reshape(-1, V), 1.0), 0.0) * ok[:, None]
    A = np.einsum("pv,pvij,pvik->pjk", w, Jac, Jac) + 1e-9 * np.eye(3)
    H = np.einsum("pv,pvij,pjk,pvlk->pvil", w, Jac, np.linalg.inv(A), Jac)
    lev = 0.5 * np.einsum("pvii->pv", H)
    return np.clip(lev, 0.0, 0.95).reshape(F, 19, V).transpose(0, 2, 1)


def _refine_poses(bundle: Bundle, cams: list[str], kp: np.ndarray, X: np.ndarray, joints: np.ndarray):
    """The bundle adjustment of the cameras' poses on the fitted points (Huber 5 px; intrinsics held)."""
    V = len(cams)
    Xn = X[:, joints].reshape(-1, 3)
    obs = kp[:, :, joints].transpose(0, 2, 1, 3).reshape(-1, V, 3)
    ok = np.all(np.isfinite(Xn), axis=1)
    pid = np.cumsum(ok) - 1
    pi, ci = np.nonzero((obs[..., 2] > 0) & ok[:, None])
    problem = BAProblem.from_cameras({c: bundle.cameras[c] for c in cams}, {"frames": Xn[ok]}, camera_index=ci,
                                     point_index=pid[pi], uv_px=obs[pi, ci, :2], camera_names=cams)
    problem.fix([ParamGroup.DISTORTION, ParamGroup.INTRINSICS])
    return bundle_adjust(problem, BAOptions(loss="huber", loss_scale_px=5.0, compute_uncertainty=False))


def fit_reference(bundle: Bundle, people: dict[str, dict[int, np.ndarray]], frames: np.ndarray, frame_ms: float,
                  *, cameras: list[str] | None = None, first_threshold_px: float = 40.0) -> Reference:
    """The robust 3D reference of the one person of ``people`` (camera -> {frame -> (N, 19, 3)}), see the module
    docstring. ``frames``: the frame indices shared by every camera, ``frame_ms`` apart.

    Example:
        >>> ref = fit_reference(bundle, read_openpose_folder(folder, body_model="BODY_25B").people,
        ...                     np.arange(100), 1000 / 60)
        >>> measure(ref.track)["noise"]["sigma_rel_median"]
    """
    cams = sorted(cameras if cameras is not None else people)
    frames = np.asarray(frames, dtype=np.int64)
    track_joints = np.array(Track.__dataclass_fields__["joints"].default)
    views = view_set(bundle, cams)
    kp = _pick(people, cams, frames, None)
    X, _ = _triangulate(views, kp, first_threshold_px)
    F, V = len(frames), len(cams)
    uv = project_points(views, X.reshape(-1, 3)).uv_px.reshape(V, F, 19, 2).transpose(1, 0, 2, 3)
    kp = _pick(people, cams, frames, uv)
    X, _ = _triangulate(views, kp, first_threshold_px)
    ba = _refine_poses(bundle, cams, kp, X, track_joints)
    refined = ba.problem.to_bundle(seq=f"{bundle.seq}-refined")
    refined.sync = bundle.sync
    changes = {}
    for c in cams:
        a, b = bundle.cameras[c], refined.cameras[c]
        changes[c] = {"rotation_deg": round(float(rotation_angle_deg(a.R, b.R)), 3),
                      "centre_cm": round(float(np.linalg.norm(b.center_cm - a.center_cm)), 2)}
    views = view_set(refined, cams)
    X, inliers = _triangulate(views, kp, float(ba.outlier_threshold_px))
    proj = project_points(views, np.where(np.isfinite(X), X, 0.0).reshape(-1, 3))
    uv = proj.uv_px.reshape(V, F, 19, 2).transpose(1, 0, 2, 3)
    bones = np.linalg.norm(X - X[:, np.maximum(PARENT19, 0)], axis=-1)[:, _LIMB_BONES]
    scale = float(np.nanmedian(bones / NOMINAL_BONE_CM[_LIMB_BONES]))
    depth = proj.depth_cm.reshape(V, F, 19)[..., 2].T  # body centre
    h_px = views.intr[None, :, 1] * NOMINAL_HEIGHT_CM * scale / np.maximum(depth, 1.0)
    have = np.all(np.isfinite(X), axis=(1, 2))
    hidden = np.zeros((F, V, 19), dtype=bool)
    for k in np.flatnonzero(have):
        hidden[k] = occluded_joints(views.center_cm, X[k][None])[:, 0]
    keep = have & np.isfinite(uv).all(axis=(1, 2, 3))
    track = Track(kp=kp[keep], uv_ref_px=uv[keep], h_px=h_px[keep], hidden=hidden[keep],
                  leverage=_leverage(views, X, kp, inliers)[keep], frame_ms=float(frame_ms))
    return Reference(track=track, X_cm=X, bundle=refined, cameras=changes, ba_sigma_px=float(ba.sigma_px),
                     ba_threshold_px=float(ba.outlier_threshold_px), scale=scale)


def truth_track(bundle: Bundle, truth: GroupTruth, detections: dict[str, dict[int, np.ndarray]],
                ids: dict[str, dict[int, np.ndarray]], frames: np.ndarray, times_ms: np.ndarray, frame_ms: float,
                *, person: int = 0) -> Track:
    """Synthetic detections of one person (by the true ids, as :func:`~dome_calib.synth.detector.synth_detections`
    gives them with ``with_ids``) judged against the truth itself (no fit: leverage 0), every camera of
    ``detections`` at the shared ``frames`` (universal ``times_ms``)."""
    cams = sorted(detections)
    views = view_set(bundle, cams)
    X, present = truth.joints_cm(np.asarray(times_ms, dtype=float))
    p = truth.ids.index(person)
    F, V = len(frames), len(cams)
    proj = project_points(views, X[:, p].reshape(-1, 3))
    uv = proj.uv_px.reshape(V, F, 19, 2).transpose(1, 0, 2, 3)
    depth = proj.depth_cm.reshape(V, F, 19)[..., 2].T
    h_px = views.intr[None, :, 1] * NOMINAL_HEIGHT_CM * truth.plans[p].scale / np.maximum(depth, 1.0)
    kp = np.zeros((F, V, 19, 3))
    for v, cam in enumerate(cams):
        for k, f in enumerate(frames):
            mine = detections[cam][int(f)][ids[cam][int(f)] == person]
            if len(mine):
                kp[k, v] = mine[0]
    hidden = np.stack([occluded_joints(views.center_cm, X[k], present[k])[:, p] for k in range(F)])
    return Track(kp=kp, uv_ref_px=uv, h_px=h_px, hidden=hidden, leverage=np.zeros((F, V, 19)), frame_ms=float(frame_ms))
