"""Patch trajectories on real video, judged by a camera left out: Pose2Sim's demo "balancing trial" (four phone
cameras, 60 fps, 1088 x 1920; ../shared/data/multiview/pose2sim_balancing, see its PROVENANCE.md).

    .venv/bin/python bench/patches_real.py [--data ../shared/data/multiview/pose2sim_balancing] [--frames 60]
        [--seed-frame 40] [--clouds 1] [--crop-x 0] [--min-ncc 0.8] [--seed-method sweep|features|skeleton]
        [--match-px 3] [--depth-window 6] [--corners 400] [--lk-window 0] [--judge-occlusion]

For each camera L in turn, the other three track patches (``recon.patches.run.patch_stream``: ``--clouds`` clouds
seeded at ``--seed-frame`` + 20 k, each tracked ``--frames / 2`` frames each way; a seed needs 2 views, as only 3
cameras track; ``--seed-method skeleton``: seeded on the participant reconstructed from the same three cameras'
detections, the body over time, ``recon.patches.seed_skeleton``) and L
judges them with its own images: at every step k -> k+1 where a patch is alive at both times, faces L (the normal's
cosine towards L's centre above 0.2) and projects into L's image, L's own pyramidal Lucas-Kanade flow
(``seed.optical_flow``, forward-backward checked) carries the projection at k to frame k+1; the distance from there
to the projection at k+1 is the patch's error in L (px). Beside it, the skeleton: the participant reconstructed
from the same three cameras' OpenPose detections (the group stage, the body over time), projected into L, against
L's own detections (median px over frames and joints with confidence >= 0.5). ``--judge-occlusion``: L also
leaves out patches that the participant's own body hides from it (the ray from L meets one of the skeleton's
capsules more than ``seed_depth_window_cm`` before the patch): facing L is not seen by L when an arm or the torso
is in the way, or when a normal is wrong.

A patch that stands still scores L's own flow in that step (``flow_median_px``); the participant barely moves, so
the steps alone cannot tell a tracked patch from one that stands still. So L also judges each patch over its whole
track: L's flow carries the patch's seed-time projection frame by frame away from the seed (chained, both ways), and
per patch and time the error is the distance to the patch's projection, beside the do-nothing baseline, the
seed-time projection held still (``from_seed_*``, ``held_still_*``, ``beats_held_still_share``; ``farthest_*`` at
the largest distance from the seed judged; ``at_1``, ``at_10``, ``at_30``: at exactly that many frames from the
seed, either way).

What the rig allows L to judge (``rig_allows``, from the participant's capsules at each seed time): L's pixels on
the body put on the capsules; of the surface points facing L (``min_cos_view``) and not hidden from it by the body,
how many ``seed_min_views`` (2) of the three tracking cameras also see. Only such a patch can be seeded, tracked and
judged; on this rig that is 0-11 of 1,500-2,000 (docs/patches.md).

The flow's window (``--lk-window``, the tracking's and the judge's; 0, the default: sized to the patch) is the
patch's side ``ncc_size_cm`` at the participant's distance in the tracking cameras (median, made odd): 31-33 px
on these phones (focal length ~1,680 px, 3.2-3.8 m), where the dome's default is 15 px for VGA.

The videos of cam01 and cam02 are 1080 px wide against the calibration's 1088 (the PROVENANCE): they are read as a
crop of the calibrated image starting at column ``--crop-x`` (0: the calibrated image's left edge, what cam01's
H.264 stream itself says: coded 1088 wide, its last 8 columns cropped; cam02 is VP9 and keeps no record, see
docs/patches.md).

One JSON object per line: per left-out camera the clouds' seeds (and those facing L at their seed), the
patch-steps judged, the median and 90th percentile error (px), the median flow in L itself (the error a patch
standing still would have), the judgement from the seed beside the patch held still, the skeleton's median
reprojection in L (px), CPU seconds, load average.

``--synthetic conversation|mixed`` judges the judge: the same left-out test on a rendered, textured person (standing
and talking, or walking) in the tiny dome's first 8 VGA cameras (one cloud at VGA frame 120, 5 frames each way;
each of the first two cameras left out, seven tracking); with ``--seed-method skeleton`` the prior is the true
joints with ``--joint-noise`` cm of noise per coordinate, and the seeds are judged against the true surface
(centre distance, normal angle).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from fractions import Fraction  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.interop.common import ImportOptions  # noqa: E402
from dome_calib.interop.convert import read_foreign  # noqa: E402
from dome_calib.recon.openpose_io import read_openpose_folder  # noqa: E402
from dome_calib.recon.patches.images import open_images, with_shared_clock  # noqa: E402
from dome_calib.recon.patches.model import PatchOptions  # noqa: E402
from dome_calib.recon.patches.run import patch_stream  # noqa: E402
from dome_calib.recon.patches.seed_skeleton import (  # noqa: E402
    BodyPrior, _rays, body_capsules, person_mask, ray_capsules)
from dome_calib.recon.patches.seed import optical_flow  # noqa: E402
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people  # noqa: E402
from dome_calib.recon.people.sources import people_streams  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402
from dome_calib.recon.streams import stream_of_camera  # noqa: E402

CAMS = [f"00_{k:02d}" for k in range(1, 5)]
FPS = Fraction(60)
HORIZONS = (1, 10, 30)  # frames from the seed at which the whole-track judgement is also given on its own


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def _pct(x: np.ndarray, q: float) -> float | None:
    return round(float(np.percentile(x, q)), 2) if len(x) else None


def hidden_by_body(centre: np.ndarray, X: np.ndarray, body: BodyPrior | None, t_ms: float, margin_cm: float
                   ) -> np.ndarray:
    """(N,) patches (N, 3) that the participant's own body (its capsules at ``t_ms``) hides from a camera at
    ``centre``: the ray meets a capsule more than ``margin_cm`` before the patch (all False without a body)."""
    if body is None or not len(X):
        return np.zeros(len(X), bool)
    A, B, radius = body_capsules(body.at(t_ms))
    to = X - centre
    dist = np.linalg.norm(to, axis=1)
    s, _ = ray_capsules(centre, to / np.maximum(dist, 1e-9)[:, None], A, B, radius)
    return s < dist - margin_cm


def judgeable_share(views, left: str, tracking: list[str], joints_cm: np.ndarray, o: PatchOptions) -> dict:
    """What the rig allows ``left`` to judge, from the participant's capsules (``joints_cm`` (19, 3)): ``left``'s
    pixels on the body (a 8 px grid of its mask) put on the capsules; of the surface points that face ``left`` (the
    visibility's ``min_cos_view``) and that the body does not hide from it, how many at least ``seed_min_views`` of
    the tracking cameras also see (facing them, not hidden): only such a patch can be seeded, tracked and judged."""
    A, B, R = body_capsules(joints_cm[None])
    if not len(A):
        return {"facing_left_out": 0, "seen_by_enough_trackers": 0}
    v = views.names.index(left)
    mask = person_mask(views, v, tuple(int(x) for x in views.resolution[v]), A, B, R)
    rows, cols = np.nonzero(mask[::8, ::8])
    dirs = _rays(views, v, np.stack([cols * 8, rows * 8], 1).astype(float))
    s, n = ray_capsules(views.center_cm[v], dirs, A, B, R)
    hit = np.isfinite(s)
    P, n = views.center_cm[v] + s[hit, None] * dirs[hit], n[hit]

    def sees(c: int) -> np.ndarray:
        to = views.center_cm[c] - P
        dist = np.linalg.norm(to, axis=1)
        first, _ = ray_capsules(views.center_cm[c], -to / dist[:, None], A, B, R)
        return (np.sum(to * n, 1) / dist > o.min_cos_view) & (first > dist - o.seed_depth_window_cm)

    seen = sees(v)
    n_track = sum(sees(views.names.index(c)).astype(int) for c in tracking)
    return {"facing_left_out": int(seen.sum()),
            "seen_by_enough_trackers": int((seen & (n_track >= o.seed_min_views)).sum()),
            "seen_by_one_tracker": int((seen & (n_track == 1)).sum())}


def patch_window_px(views, joints_cm: np.ndarray, cams: list[str], size_cm: float) -> int:
    """The optical flow's window sized to the patch: ``size_cm`` at the participant's distance (the joints'
    centroid) in the cameras ``cams``, median px, made odd."""
    mid = np.nanmean(joints_cm, axis=0)
    idx = [views.names.index(c) for c in cams]
    px = views.intr[idx, 0] * size_cm / np.linalg.norm(views.center_cm[idx] - mid, axis=1)
    return int(2 * round(float(np.median(px)) / 2) + 1)


def judge_in(source, bundle, traj, cam: str, o: PatchOptions, body: BodyPrior | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Per patch-step seen by ``cam`` (facing it, in its image, not hidden by the participant's ``body``): (|cam's
    own LK flow of the projection - the next projection|, |that flow|: the error a patch that did not move would
    have) px."""
    views = view_set(bundle, [cam])
    centre = bundle.cameras[cam].center_cm
    frames, off_ms = stream_of_camera(bundle, cam)[1].nearest(traj.times_ms)  # L's own frames at the patch times
    assert np.all(np.abs(off_ms) < 1.0), "the left-out camera's frames must meet the reference times"
    errors, moves = [], []
    for k in range(len(traj.times_ms) - 1):
        both = traj.alive[:, k] & traj.alive[:, k + 1]
        X0, X1 = traj.X_cm[both, k, 0], traj.X_cm[both, k + 1, 0]
        to_cam = centre - X0
        cos = np.sum(traj.normal[both, k] * to_cam, 1) / np.linalg.norm(to_cam, axis=1)
        p0, p1 = project_points(views, X0), project_points(views, X1)
        ok = (cos > o.min_cos_view) & p0.visible[0] & p1.visible[0]
        ok &= ~hidden_by_body(centre, np.nan_to_num(X0), body, float(traj.times_ms[k]), o.seed_depth_window_cm)
        if not ok.any():
            continue
        q, tracked = optical_flow(source.gray(cam, int(frames[k])), source.gray(cam, int(frames[k + 1])),
                                  p0.uv_px[0][ok], o)
        errors.append(np.linalg.norm(q - p1.uv_px[0][ok], axis=1)[tracked])
        moves.append(np.linalg.norm(q - p0.uv_px[0][ok], axis=1)[tracked])
    return np.concatenate(errors + [np.zeros(0)]), np.concatenate(moves + [np.zeros(0)])


def judge_from_seed(source, bundle, traj, cam: str, o: PatchOptions, body: BodyPrior | None = None) -> dict:
    """Judged over the whole track, not step by step: ``cam``'s own flow carries each patch's seed-time projection
    (patches alive at their cloud's seed, facing ``cam``, in its image) frame by frame away from the seed, both
    ways (chained Lucas-Kanade, forward-backward checked; a point lost stays lost); per patch and time where the
    patch is alive and still faces ``cam``: the error |that track - the patch's projection| and the do-nothing
    baseline |that track - the seed-time projection| (a patch held still at its seed), px."""
    views = view_set(bundle, [cam])
    centre = bundle.cameras[cam].center_cm
    frames, off_ms = stream_of_camera(bundle, cam)[1].nearest(traj.times_ms)
    assert np.all(np.abs(off_ms) < 1.0), "the left-out camera's frames must meet the reference times"

    def facing(k: int) -> tuple[np.ndarray, np.ndarray]:
        X = np.nan_to_num(traj.X_cm[:, k, 0])
        to_cam = centre - X
        cos = np.sum(traj.normal[:, k] * to_cam, 1) / np.linalg.norm(to_cam, axis=1)
        p = project_points(views, X)
        seen = traj.alive[:, k] & (np.nan_to_num(cos) > o.min_cos_view) & p.visible[0]
        seen &= ~hidden_by_body(centre, X, body, float(traj.times_ms[k]), o.seed_depth_window_cm)
        return seen, p.uv_px[0]

    err, still, far, n_judged = [], [], {}, 0
    for t_seed in np.unique(traj.seed_time_ms):
        s = int(np.argmin(np.abs(traj.times_ms - t_seed)))
        ok0, p_seed = facing(s)
        idx = np.flatnonzero(ok0 & (traj.seed_time_ms == t_seed))
        n_judged += len(idx)
        for direction in (1, -1):
            _follow(source, cam, frames, traj, facing, idx, p_seed, s, direction, o, err, still, far)
    e, m = np.concatenate(err + [np.zeros(0)]), np.concatenate(still + [np.zeros(0)])
    last = max((d for d, v in far.items() if sum(len(x) for x, _ in v)), default=0)
    e_last = np.concatenate([x for x, _ in far.get(last, [])] + [np.zeros(0)])
    m_last = np.concatenate([y for _, y in far.get(last, [])] + [np.zeros(0)])
    return {"patch_times_judged": int(len(e)), "patches_judged": n_judged, "from_seed_median_px": _pct(e, 50),
            "from_seed_p90_px": _pct(e, 90), "held_still_median_px": _pct(m, 50),
            "held_still_p90_px": _pct(m, 90),
            "beats_held_still_share": round(float(np.mean(e < m)), 3) if len(e) else None,
            "farthest_frames": int(last), "farthest_judged": int(len(e_last)),
            "farthest_median_px": _pct(e_last, 50), "farthest_held_still_median_px": _pct(m_last, 50),
            **{f"at_{d}": _at(far.get(d, [])) for d in HORIZONS}}


def _at(judged: list) -> dict:
    """The judgement at one distance from the seed: patch-times, median and 90th percentile error, held still."""
    e = np.concatenate([x for x, _ in judged] + [np.zeros(0)])
    m = np.concatenate([y for _, y in judged] + [np.zeros(0)])
    return {"n": int(len(e)), "median_px": _pct(e, 50), "p90_px": _pct(e, 90), "held_still_median_px": _pct(m, 50)}


def _follow(source, cam, frames, traj, facing, idx, p_seed, s, direction, o, err, still, far) -> None:
    """One direction of :func:`judge_from_seed` for one cloud's patches ``idx``: appends to err, still, far."""
    q, live = p_seed[idx].copy(), np.ones(len(idx), bool)
    k = s
    while 0 <= k + direction < len(traj.times_ms) and live.any():
        a, b = int(frames[k]), int(frames[k + direction])
        q_new, tracked = optical_flow(source.gray(cam, a), source.gray(cam, b), q[live], o)
        at = np.flatnonzero(live)
        q[at] = q_new
        live[at[~tracked]] = False
        k += direction
        ok, p = facing(k)
        judged = live & ok[idx]
        e = np.linalg.norm(q[judged] - p[idx[judged]], axis=1)
        m = np.linalg.norm(q[judged] - p_seed[idx[judged]], axis=1)
        err.append(e), still.append(m)
        far.setdefault(abs(k - s), []).append((e, m))


def participant(bundle, det, tracking: list[str], frames: np.ndarray):
    """The participant from ``tracking``'s detections: (streams, times, the group stage's people over time)."""
    people = {n: {f: p for f, p in det.people[n].items() if f in set(frames.tolist())} for n in tracking}
    streams = people_streams(bundle, people, shared_fps=FPS)
    times = streams[0].table.times_of(streams[0].frame_index)
    return streams, times, reconstruct_people(view_set(bundle, tracking), streams, times, PeopleOptions(shared_fps=FPS))


def body_prior(times_ms: np.ndarray, seq, at_ms: np.ndarray) -> BodyPrior:
    """The participant (at each time the body seen by most views) as the seeds' depth prior at ``at_ms`` (each a
    time of the people's, within 0.5 ms)."""
    J = np.full((len(seq.bodies), 1, 19, 3), np.nan)
    for k, b in enumerate(seq.bodies):
        if len(b.ids):
            J[k, 0] = b.X_cm[int(np.argmax(b.n_views))]
    near = np.array([int(np.argmin(np.abs(times_ms - t))) for t in at_ms])
    assert np.all(np.abs(times_ms[near] - at_ms) < 0.5), "the people's times must be the patch stream's"
    return BodyPrior(times_ms=np.asarray(at_ms, float), joints_cm=J[near])


def skeleton_in(bundle, det, tracking: list[str], cam: str, frames: np.ndarray, found=None
                ) -> tuple[float | None, int]:
    """The participant from ``tracking``'s detections, projected into ``cam``, against its detections (``found``:
    :func:`participant`'s result, else made here)."""
    streams, _, seq = found or participant(bundle, det, tracking, frames)
    errs = []
    for k, f in enumerate(streams[0].frame_index):
        b = seq.bodies[k]
        if not len(b.ids) or int(f) not in det.people[cam]:
            continue
        X = b.X_cm[int(np.argmax(b.n_views))]  # the participant: the body seen by most views
        uv = project_points(view_set(bundle, [cam]), np.nan_to_num(X)).uv_px[0]
        d = det.people[cam][int(f)]  # (N, 19, 3)
        e = np.where((d[..., 2] >= 0.5) & np.isfinite(X[:, 0])[None], np.linalg.norm(d[..., :2] - uv[None], axis=-1),
                     np.nan)
        if np.isfinite(e).any():
            row = int(np.nanargmin(np.nanmean(np.where(np.isfinite(e), e, 1e9), axis=1)))
            errs.append(e[row][np.isfinite(e[row])])
    e = np.concatenate(errs + [np.zeros(0)])
    return (round(float(np.median(e)), 2) if len(e) else None), int(len(e))


def synthetic_check(frames: int, o: PatchOptions, scenario: str, joint_noise_cm: float) -> None:
    """The judge itself on known ground: the tiny dome's first 8 VGA cameras and one rendered, textured person
    (``synth.textured``); each of the first two cameras left out in turn, the other seven tracking. With skeleton
    seeds the prior is the true joints with ``joint_noise_cm`` of noise per coordinate (seeded), and the seeds are
    judged against the true surface at the seed time (centre distance, normal angle)."""
    from dome_calib.synth.dome import nominal_dome
    from dome_calib.synth.group import GroupOptions, make_group
    from dome_calib.synth.skeleton import synthetic_sync
    from dome_calib.synth.textured import TexturedScene, TextureOptions, nearest_surface_points, surface_points_cm

    bundle = nominal_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=1500.0, seed=0)
    truth = make_group(GroupOptions(n_people=1, scenario=scenario, start_ms=100.0, duration_ms=1300.0, seed=2))
    scene = TexturedScene(bundle, truth, TextureOptions())
    cams = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"][:8]
    table = bundle.sync.streams["vga"]
    half = frames // 2
    span = (table.time_of(120 - half), table.time_of(120 + half))
    body = None
    if o.seed_method == "skeleton":
        at = table.times_of(np.arange(120 - half, 120 + half + 1))
        J, present = truth.joints_cm(at)
        J = np.where(present[..., None, None], J, np.nan)
        J = J + np.random.default_rng(0).normal(0.0, joint_noise_cm, J.shape)
        body = BodyPrior(times_ms=at, joints_cm=J)
    t_seed = table.time_of(120)
    for left in cams[:2]:
        tracking = [c for c in cams if c != left]
        traj = patch_stream(bundle, scene, tracking, span, o, seed_frames=[120], body=body)
        err, move = judge_in(scene, bundle, traj, left, o)
        s = int(np.argmin(np.abs(traj.times_ms - t_seed)))
        X, n = traj.X_cm[traj.alive[:, s], s, 0], traj.normal[traj.alive[:, s], s]
        near = nearest_surface_points(truth, t_seed, X)
        on = np.isfinite(near.distance_cm)
        _, n_true = surface_points_cm(truth, np.array([t_seed]), near.person[on], near.part[on], near.local_cm[on])
        ang = np.degrees(np.arccos(np.clip(np.sum(n_true[0] * n[on], 1), -1.0, 1.0)))
        emit(synthetic=scenario, seed_method=o.seed_method, joint_noise_cm=joint_noise_cm if body else None,
             seed_centre_median_cm=_pct(near.distance_cm[on], 50), seed_centre_p90_cm=_pct(near.distance_cm[on], 90),
             seed_normal_median_deg=_pct(ang, 50), seed_normal_p90_deg=_pct(ang, 90))
        whole = judge_from_seed(scene, bundle, traj, left, o)
        whole["seeds_facing_left_out"] = whole.pop("patches_judged")
        emit(synthetic=scenario, left_out=left, tracking=len(tracking), seeds=int(traj.alive.any(1).sum()), **whole,
             patch_steps_judged=int(len(err)), patch_median_px=_pct(err, 50), patch_p90_px=_pct(err, 90),
             flow_median_px=_pct(move, 50), load=[round(x, 2) for x in os.getloadavg()])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "multiview" / "pose2sim_balancing"))
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--seed-frame", type=int, default=40)
    ap.add_argument("--clouds", type=int, default=1, help="clouds seeded at --seed-frame + 20 k, k = 0.. (a new "
                    "cloud every 20th frame, as the stage does)")
    ap.add_argument("--crop-x", type=int, default=0)
    ap.add_argument("--min-ncc", type=float, default=0.8)
    ap.add_argument("--seed-method", choices=["sweep", "features", "skeleton"], default="sweep")
    ap.add_argument("--depth-window", type=float, default=PatchOptions().seed_depth_window_cm,
                    help='"skeleton": cm searched either side of the body\'s capsules')
    ap.add_argument("--judge-occlusion", action="store_true",
                    help="L judges only patches its view of the participant's body (capsules) does not hide")
    ap.add_argument("--lk-window", type=int, default=0,
                    help="optical flow's window (px), the tracking's and the judge's; 0: sized to the patch "
                    "(ncc_size_cm at the participant's distance in the tracking cameras, made odd: 31 px here)")
    ap.add_argument("--corners", type=int, default=PatchOptions().seed_features, help="corners per camera")
    ap.add_argument("--joint-noise", type=float, default=3.0,
                    help="--synthetic with skeleton seeds: the prior is the true joints with this much noise (cm)")
    ap.add_argument("--match-px", type=float, default=3.0, help='"features": epipolar band and triangulation inliers')
    ap.add_argument("--synthetic", choices=["conversation", "mixed"], default=None,
                    help="judge the judge: a rendered person (standing, or walking) in 8 VGA cameras")
    args = ap.parse_args()
    data = Path(args.data)
    if args.synthetic:
        synthetic_check(min(args.frames, 10), PatchOptions(track_frames=min(args.frames, 10) // 2, seed_features=100,
                                                           seed_neighbours=3, seed_views=4,
                                                           seed_method=args.seed_method,
                                                           seed_depth_window_cm=args.depth_window),
                        args.synthetic, args.joint_noise)
        return
    names = {f"cam_{k:02d}": f"00_{k:02d}" for k in range(1, 5)}
    bundle, _ = read_foreign(data / "calibration" / "Calib_qualisys.toml", "pose2sim",
                             ImportOptions(names=names, seq="pose2sim"))  # z up turned to the Panoptic frame
    det = read_openpose_folder(data / "pose", body_model="BODY_25B",
                               camera_map={f"cam{k:02d}_json": f"00_{k:02d}" for k in range(1, 5)})
    half = args.frames // 2
    seed_frames = [args.seed_frame + 20 * k for k in range(args.clouds)]
    frames = np.arange(max(seed_frames[0] - half, 0), min(seed_frames[-1] + half, 99) + 1)
    o = PatchOptions(track_frames=half, seed_min_views=2, seed_min_ncc=args.min_ncc, seed_method=args.seed_method,
                     seed_match_px=args.match_px, seed_depth_window_cm=args.depth_window, seed_features=args.corners,
                     lk_window_px=args.lk_window or PatchOptions().lk_window_px)  # 0: set per left-out camera
    emit(bench="patches_real", frames=int(len(frames)), seed_frames=seed_frames, crop_x=args.crop_x,
         options={"track_frames": half, "seed_min_views": 2, "seed_min_ncc": args.min_ncc,
                  "seed_method": args.seed_method, "seed_match_px": args.match_px,
                  "seed_depth_window_cm": args.depth_window, "seed_features": args.corners,
                  "lk_window_px": args.lk_window, "judge_occlusion": args.judge_occlusion},
         load=[round(x, 2) for x in os.getloadavg()])
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for k in range(1, 5):
            (folder / f"cam{k:02d}.mp4").symlink_to((data / "videos" / f"cam{k:02d}.mp4").resolve())
        (folder / "images.json").write_text(json.dumps({
            "cameras": {f"00_{k:02d}": f"cam{k:02d}.mp4" for k in range(1, 5)},
            "crop_origin_px": {"00_01": [args.crop_x, 0], "00_02": [args.crop_x, 0]}}))
        source = open_images(folder, bundle)
        clocked = with_shared_clock(bundle, source, FPS)
        table = clocked.sync.streams["hd"]
        span = (table.time_of(int(frames[0])), table.time_of(int(frames[-1])))
        for left in CAMS:
            tracking = [c for c in CAMS if c != left]
            found = participant(bundle, det, tracking, frames)
            body = body_prior(found[1], found[2], table.times_of(frames)) if args.seed_method == "skeleton" else None
            at_seed = body_prior(found[1], found[2], table.times_of(np.array(seed_frames))).joints_cm[:, 0]
            views = view_set(bundle, CAMS)
            o = dataclasses.replace(o, lk_window_px=args.lk_window or patch_window_px(views, at_seed[0], tracking,
                                                                                    o.ncc_size_cm))
            allowed = [judgeable_share(views, left, tracking, J, o) for J in at_seed]
            cpu0 = time.process_time()
            traj = patch_stream(clocked, source, tracking, span, o, seed_frames=seed_frames, body=body)
            cpu = time.process_time() - cpu0
            who = body_prior(found[1], found[2], table.times_of(frames)) if args.judge_occlusion else None
            err, move = judge_in(source, clocked, traj, left, o, who)
            skel, n_joints = skeleton_in(bundle, det, tracking, left, frames, found)
            length = traj.alive.sum(1)
            whole = judge_from_seed(source, clocked, traj, left, o, who)
            emit(left_out=left, tracking=tracking, seeds=int(len(traj.ids)),
                 seeds_facing_left_out=whole.pop("patches_judged"),
                 median_frames_alive=(int(np.median(length)) if len(length) else None),
                 patch_steps_judged=int(len(err)), patch_median_px=_pct(err, 50), patch_p90_px=_pct(err, 90),
                 flow_median_px=_pct(move, 50), **whole, skeleton_median_px=skel, skeleton_joints=n_joints,
                 lk_window_px=o.lk_window_px, rig_allows={k: sum(a[k] for a in allowed) for k in allowed[0]},
                 stage_cpu_s=round(cpu, 1), load=[round(x, 2) for x in os.getloadavg()])
        source.close()


if __name__ == "__main__":
    main()
