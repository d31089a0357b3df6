"""Judge reconstructed people against a synthetic group's truth (bench/multiperson.py and `dome-calib demo`).

- Matching: at each time, bodies to true people by Hungarian on the mean distance of their common joints (>= 3),
  a pair kept below ``MATCH_CM`` (20 cm).
- MPJPE (cm) of the matched bodies, beside an oracle (:func:`oracle`): the same triangulation of perfectly
  associated detections; both over the joints both reconstructed.
- Found: share of (time, true person) with a matched body where >= 8 views see the person (>= 5 detected joints,
  by the oracle's labels), the issue's aim >= 99 %; the oracle's own share beside it (a body so wrong that even
  perfect association leaves it over ``MATCH_CM`` from the truth is the triangulation's, not the association's).
- False bodies: ids whose bodies match no true person; the aim allows none for more than 3 consecutive times.
- Identity switches: changes of the id matched to a true person between matches at most the tracker's
  ``max_missed_ms`` apart (a person unseen for longer gets a new id by design: counted apart as
  ``new_id_after_long_gap``), per 1,000 matched body-frames.

:func:`judge_group_session` judges a ``dome-calib reconstruct`` output folder against a group session on disk
(:mod:`dome_calib.synth.group_session`), with a bundle whose world may differ from the truth's (the demo's produced
bundle): bodies are matched in the bundle's world (a few cm off at most, far below ``MATCH_CM``), then one rigid
motion for the whole session, fitted on the matched joints, takes the world's placement out (as
:mod:`dome_calib.synth.product_eval` judges the single person).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from dome_calib.body3d_scene import read_scene, scene_files
from dome_calib.bundle import Bundle
from dome_calib.recon.body_models import JOINTS19
from dome_calib.recon.openpose_io import read_openpose_folder
from dome_calib.recon.people.resample import interpolate_people
from dome_calib.recon.people.run import PeopleOptions
from dome_calib.recon.people.sources import PeopleStream, people_streams
from dome_calib.recon.project import ViewSet, project_points, view_set
from dome_calib.recon.triangulate import triangulate
from dome_calib.synth.group_session import DETECTIONS, TRUTH_FILE
from dome_calib.synth.product_eval import session_rigid_fit

#: A body is the true person's if their mean joint distance is below this (cm).
MATCH_CM = 20.0
#: A true person counts in the "found" figure where this many views detect >= 5 of its joints.
FOUND_VIEWS = 8


@dataclass(frozen=True)
class GroupTruthFrames:
    """The truth at the reference stream's frames: times_ms (T,), frames (T,), ids (P,) people, X_cm (T, P, 19, 3)
    world cm (NaN where absent), present (T, P); the scenario and the body model the detections were written in."""

    scenario: str
    body_model: str
    times_ms: np.ndarray
    frames: np.ndarray
    ids: np.ndarray
    X_cm: np.ndarray
    present: np.ndarray


def load_group_truth(path: str | Path) -> GroupTruthFrames:
    """``group_truth.json`` -> :class:`GroupTruthFrames` (people in id order)."""
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    ids = np.array(sorted(int(i) for i in doc["roles"]), dtype=np.int64)
    col = {int(i): k for k, i in enumerate(ids)}
    frames = doc["frames"]
    X = np.full((len(frames), len(ids), 19, 3), np.nan)
    for t, f in enumerate(frames):
        for b in f["bodies"]:
            X[t, col[int(b["id"])]] = np.asarray(b["joints19"], dtype=float)
    return GroupTruthFrames(scenario=doc["scenario"], body_model=doc["options"]["body_model"],
                            times_ms=np.array([f["univ_time_ms"] for f in frames], dtype=float),
                            frames=np.array([f["frame"] for f in frames], dtype=np.int64), ids=ids, X_cm=X,
                            present=np.isfinite(X).all(-1).all(-1))


def read_bodies(folder: str | Path) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """A reconstruct output folder -> (frames (T,), univ times_ms (T,), ids[t] (N_t,), X_cm[t] (N_t, 19, 3) with
    NaN for joints not reconstructed), in frame order."""
    frames, times, ids, X = [], [], [], []
    for frame, path in scene_files(folder):
        t_ms, bodies = read_scene(path)
        order = sorted(bodies)
        frames.append(frame)
        times.append(t_ms)
        ids.append(np.array(order, dtype=np.int64))
        X.append(np.array([np.where(bodies[i][:, 3:4] >= 0, bodies[i][:, :3], np.nan) for i in order]
                          ).reshape(len(order), 19, 3))
    return np.array(frames, dtype=np.int64), np.array(times, dtype=float), ids, X


def mean_joint_cm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(P, 19, 3) and (Q, 19, 3) skeletons -> (P, Q) mean distance over their common joints (cm; inf below 3)."""
    d = np.linalg.norm(A[:, None] - B[None], axis=-1)
    n = np.isfinite(d).sum(-1)
    return np.where(n >= 3, np.nansum(d, -1) / np.maximum(n, 1), np.inf)


def oracle(views: ViewSet, streams: list[PeopleStream], times_ms: np.ndarray, truth_X: np.ndarray,
           present: np.ndarray, options: PeopleOptions) -> tuple[np.ndarray, np.ndarray]:
    """Perfect association: each interpolated detection labelled with the true person whose projection it matches
    (2D Hungarian on mean joint distance, gated at 30 % of the person's size), then the same triangulation.

    truth_X (T, P, 19, 3) cm at times_ms (T,), present (T, P). Returns X (T, P, 19, 3) cm and the number of views
    detecting >= 5 joints of each true person (T, P).
    """
    T, P = present.shape
    V = sum(len(s.cameras) for s in streams)
    parts = [interpolate_people(s, times_ms, max_gap_frames=options.max_gap_frames) for s in streams]
    N = max(p.shape[2] for p in parts)
    kp = np.concatenate([np.pad(p, ((0, 0), (0, 0), (0, N - p.shape[2]), (0, 0), (0, 0))) for p in parts], axis=1)
    proj = project_points(views, truth_X.reshape(-1, 3)).uv_px.reshape(V, T, P, 19, 2)
    uv = np.full((T, P, 19, V, 2), np.nan)
    conf = np.zeros((T, P, 19, V))
    seen = np.zeros((T, P), dtype=np.int64)
    for t in range(T):
        for v in range(V):
            det = kp[t, v]
            have = det[..., 2] > 0
            live = np.flatnonzero(have.sum(1) >= 3)
            if not len(live):
                continue
            d = np.linalg.norm(det[live][:, None, :, :2] - proj[v, t][None], axis=-1)
            ok = have[live][:, None] & np.isfinite(d)
            cost = np.where(ok.sum(-1) >= 3, np.where(ok, d, 0).sum(-1) / np.maximum(ok.sum(-1), 1), 1e9)
            cost[:, ~present[t]] = 1e9
            xy = np.where(have[live][..., None], det[live][..., :2], np.nan)
            size = np.hypot(*(np.nanmax(xy, axis=1) - np.nanmin(xy, axis=1)).T)
            r, c = linear_sum_assignment(cost)
            for i, p in zip(r, c):
                if cost[i, p] < max(0.3 * size[i], 15.0):
                    row = det[live[i]]
                    uv[t, p, :, v] = np.where(row[:, 2:3] > 0, row[:, :2], np.nan)
                    conf[t, p, :, v] = row[:, 2]
                    seen[t, p] += int((row[:, 2] > 0).sum() >= 5)
    tri = triangulate(views, uv.reshape(-1, V, 2), np.clip(conf.reshape(-1, V), 0, 1), options.triangulation)
    return tri.X_cm.reshape(T, P, 19, 3), seen


def match_bodies(body_ids: list[np.ndarray], body_X: list[np.ndarray], truth_X: np.ndarray, present: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, dict[int, list[int]]]:
    """Bodies to true people per time (Hungarian on :func:`mean_joint_cm`, kept below ``MATCH_CM``).

    body_ids[t] (N_t,), body_X[t] (N_t, 19, 3) cm; truth_X (T, P, 19, 3), present (T, P). Returns the matched id
    (T, P) (-1: none), the matched bodies' joints (T, P, 19, 3) (NaN: none) and id -> the times its body matched
    nobody.
    """
    T, P = present.shape
    match_id = np.full((T, P), -1)
    ours = np.full((T, P, 19, 3), np.nan)
    unmatched: dict[int, list[int]] = {}
    for t, (ids, X) in enumerate(zip(body_ids, body_X)):
        matched = set()
        if len(X):
            cost = mean_joint_cm(X, np.where(present[t][:, None, None], truth_X[t], np.nan))
            r, c = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
            for i, p in zip(r, c):
                if cost[i, p] < MATCH_CM:
                    match_id[t, p] = ids[i]
                    ours[t, p] = X[i]
                    matched.add(i)
        for i, bid in enumerate(ids):
            if i not in matched:
                unmatched.setdefault(int(bid), []).append(t)
    return match_id, ours, unmatched


def _longest_run(ts: list[int]) -> int:
    run = best = 1
    for a, c in zip(ts, ts[1:]):
        run = run + 1 if c == a + 1 else 1
        best = max(best, run)
    return best


def judge_group(times_ms: np.ndarray, body_ids: list[np.ndarray], body_X: list[np.ndarray], truth_X: np.ndarray,
                present: np.ndarray, oracle_X: np.ndarray, seen: np.ndarray, max_missed_ms: float) -> dict:
    """Every figure of the module docstring (plain data, one JSON object of bench/multiperson.py).

    times_ms (T,); bodies as :func:`match_bodies`; truth_X, oracle_X (T, P, 19, 3) cm in one world frame;
    present, seen (T, P) as :func:`oracle` returns them.
    """
    T, P = present.shape
    match_id, ours, unmatched = match_bodies(body_ids, body_X, truth_X, present)
    longest = {bid: _longest_run(ts) for bid, ts in unmatched.items()}
    both = np.isfinite(ours).all(-1) & np.isfinite(oracle_X).all(-1)
    err_ours = np.linalg.norm(ours - truth_X, axis=-1)[both]
    err_oracle = np.linalg.norm(oracle_X - truth_X, axis=-1)[both]
    eight = present & (seen >= FOUND_VIEWS)
    d_oracle = np.linalg.norm(oracle_X - truth_X, axis=-1)  # (T, P, 19)
    n_oracle = np.isfinite(d_oracle).sum(-1)
    oracle_found = (n_oracle >= 3) & (np.nansum(d_oracle, -1) < MATCH_CM * np.maximum(n_oracle, 1))
    switches = renamed = 0
    for p in range(P):
        k = np.flatnonzero(match_id[:, p] >= 0)
        for a, c in zip(k, k[1:]):
            if match_id[a, p] != match_id[c, p]:
                if times_ms[c] - times_ms[a] <= max_missed_ms:
                    switches += 1
                else:
                    renamed += 1  # unseen longer than the tracker keeps a track: a new id by design
    matched = int((match_id >= 0).sum())
    found = match_id >= 0
    return {"mpjpe_cm": round(float(err_ours.mean()), 3), "oracle_mpjpe_cm": round(float(err_oracle.mean()), 3),
            "ratio": round(float(err_ours.mean() / err_oracle.mean()), 3),
            "found_8views": round(float(found[eight].mean()), 4) if eight.any() else None,
            "oracle_found_8views": round(float(oracle_found[eight].mean()), 4) if eight.any() else None,
            "true_body_frames_8views": int(eight.sum()), "matched_body_frames": matched,
            "true_body_frames": int(present.sum()), "body_frames": int(sum(len(i) for i in body_ids)),
            "times": int(T), "times_all_found": int(np.all(found | ~present, axis=1).sum()),
            "false_bodies_gt3": int(sum(v > 3 for v in longest.values())),
            "false_body_frames": int(sum(len(v) for v in unmatched.values())),
            "id_switches": int(switches), "new_id_after_long_gap": int(renamed),
            "id_switches_per_1000": round(1000.0 * switches / max(matched, 1), 3)}


def judge_group_session(group_folder: str | Path, bundle: Bundle, people_folder: str | Path,
                        options: PeopleOptions) -> dict:
    """A reconstruct output folder (``people_folder``, made with ``bundle`` and ``options``) against the group
    session in ``group_folder`` (its ``detections/`` and ``group_truth.json``), at the reference frames both have.

    Returns :func:`judge_group`'s figures after the session alignment, plus ``mpjpe_world_cm`` and
    ``oracle_mpjpe_world_cm`` in the bundle's own world, ``people`` (true), ``ids`` (reconstructed), ``views``,
    ``truth_times`` (the truth's frames), the scenario and the tracker's ``max_missed_ms``.
    """
    group_folder = Path(group_folder)
    truth = load_group_truth(group_folder / TRUTH_FILE)
    frames, times_ms, body_ids, body_X = read_bodies(people_folder)
    common, i_ours, i_truth = np.intersect1d(frames, truth.frames, return_indices=True)
    times_ms = times_ms[i_ours]
    body_ids, body_X = [body_ids[i] for i in i_ours], [body_X[i] for i in i_ours]
    truth_X, present = truth.X_cm[i_truth], truth.present[i_truth]
    det = read_openpose_folder(group_folder / DETECTIONS, body_model=truth.body_model,
                               cameras=set(bundle.cameras))
    streams = people_streams(bundle, det.people, det.files, shared_fps=options.shared_fps)
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    oracle_X, seen = oracle(views, streams, times_ms, truth_X, present, options)
    world = judge_group(times_ms, body_ids, body_X, truth_X, present, oracle_X, seen, options.tracking.max_missed_ms)
    _, ours, _ = match_bodies(body_ids, body_X, truth_X, present)
    align = session_rigid_fit(ours.reshape(-1, 19, 3), truth_X.reshape(-1, 19, 3))
    aligned = judge_group(times_ms, body_ids, [align(X) for X in body_X], truth_X, present, align(oracle_X), seen,
                          options.tracking.max_missed_ms)
    return {**aligned, "mpjpe_world_cm": world["mpjpe_cm"], "oracle_mpjpe_world_cm": world["oracle_mpjpe_cm"],
            "people": int(present.any(0).sum()), "ids": len({int(i) for ids in body_ids for i in ids}),
            "views": len(views.names), "truth_times": int(len(truth.frames)), "scenario": truth.scenario,
            "max_missed_ms": float(options.tracking.max_missed_ms)}


#: The limbs of the PCP score (Shelf / Campus style, joints19): torso, head, upper and lower arms and legs.
PCP_LIMBS = {"torso": ("neck", "body_center"), "head": ("neck", "nose"),
             "l_upper_arm": ("l_shoulder", "l_elbow"), "r_upper_arm": ("r_shoulder", "r_elbow"),
             "l_lower_arm": ("l_elbow", "l_wrist"), "r_lower_arm": ("r_elbow", "r_wrist"),
             "l_upper_leg": ("l_hip", "l_knee"), "r_upper_leg": ("r_hip", "r_knee"),
             "l_lower_leg": ("l_knee", "l_ankle"), "r_lower_leg": ("r_knee", "r_ankle")}


def pcp(ours: np.ndarray, truth: np.ndarray, mask: np.ndarray, alpha: float = 0.5) -> dict:
    """Percentage of correct parts: a limb is correct where the mean distance of its two joints to the truth is at
    most ``alpha`` x its true length; ours (T, P, 19, 3) matched to truth (T, P, 19, 3) (NaN: missing, so wrong);
    over the (time, person) of ``mask`` (T, P). Returns per limb and their mean, in percent."""
    out = {}
    for name, (a, b) in PCP_LIMBS.items():
        ia, ib = JOINTS19.index(a), JOINTS19.index(b)
        err = 0.5 * (np.linalg.norm(ours[..., ia, :] - truth[..., ia, :], axis=-1)
                     + np.linalg.norm(ours[..., ib, :] - truth[..., ib, :], axis=-1))
        length = np.linalg.norm(truth[..., ia, :] - truth[..., ib, :], axis=-1)
        ok = np.nan_to_num(err, nan=np.inf) <= alpha * length
        out[name] = round(100.0 * float(ok[mask].mean()), 2) if mask.any() else None
    out["mean"] = round(float(np.mean([v for v in out.values() if v is not None])), 2) if mask.any() else None
    return out
