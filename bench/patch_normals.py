"""The patches' normals against the truth, per visibility verdict: what tells the back-facing false positives (views of
the true surface's back that the MAP labels visible) from the true views.

Run: .venv/bin/python bench/patch_normals.py STREAM.npz [--people 2] [--scenario conversation] [--seed 0]
         [--vga 24] [--hd 4] [--kinect 2] [--preset panel]
     .venv/bin/python bench/patch_normals.py --seeds [--render-cache FOLDER] [the same scene options]
STREAM.npz: a ``bench/patches.py --save`` run with the same scene options. Every live patch-time and camera of the
stream's cameras is put in one class: ``true_positive`` (labelled visible, truly seen), ``back_facing_fp`` (labelled
visible, the true surface faces away: true cosine <= 0, the patch within 1 cm of its point), ``other_fp`` (the other
false positives of patches within 1 cm), ``drifted`` (false positives of patches more than 1 cm from their point),
``false_negative`` (truly seen, not labelled, within 1 cm). Per class (percentiles 10, 50, 90):

- ``normal_error_deg``: the angle between the patch's normal and the true surface normal at that time;
- ``seed_normal_error_deg``: the same at the patch's seed time (the error it started with);
- ``cos_true``: cosine between the view ray (point to camera) and the true normal; ``cos_est``: between the ray from
  the patch centre and the patch's normal (what the MAP's geometric term sees);
- ``cos_gain``: ``cos_est - cos_true``;
- ``visible_spread_deg``: the angle between the patch normal and the mean direction of the cameras labelled visible
  at that time (a patch whose labelled cameras sit off to one side of its normal).

``separations``: for rules that could drop a labelled view, how many back-facing false positives and how many true
positives each drops (and the precision the labels would then have, before any recall change). ``by_seed_normal_error``:
the patches alive at the seed binned by their seed normal error, with their views over the whole track per class;
``by_neighbour_gap``: the same by the seed's widest empty angle among the live seeds round it
(:func:`~dome_calib.recon.patches.seed.neighbour_gap_deg`, within 4 cm, in the plane of its normal: 180 deg and more
where the cloud ends on one side; branch prec61), with the precision of their views.
``concentration``: how few patches hold half and four fifths of the back-facing false positives. ``oracle_grazing``:
a bound on any grazing-angle rule: told which patches' seed normals are at least ``seed_error_deg`` off (which no
rule knows), their labelled views with ``cos_est`` below ``cut`` dropped: the precision and recall then. Prints one
JSON object per line.

``--seeds`` (no STREAM; branch normals50): why a seed's normal is wrong, before any tracking. The scene's VGA seeds
(the reference stream's, seeded as the stage seeds them, thinned, frames read from ``--render-cache``) against the
true surface; a seed within 1 cm of it is an ``outline`` seed when every camera that triangulated it is within 15 deg
of edge-on by the true normal, else ``rest``. Per class, the normal error (percentiles 10 / 50 / 90, share above 30
deg) of each way of getting it: ``svd_R`` (today's at R = 4 cm: the least principal axis of the seeds within R cm),
``svd_R_true_points`` (the same neighbours' TRUE surface points: the error the neighbourhood's shape alone gives,
without the seeds' noise), ``quadric_R_true_points`` (a quadric fitted to them, its normal at the seed),
``svd_4_same_part_on_surface`` (only neighbours on the seed's own part and within 3 mm of the surface: an oracle),
``svd_4_with_hd_seeds`` (the HD stream's seeds at its nearest frame added to the neighbours), ``stage_quadric_R``
(the stage's ``normal_fit="quadric"`` at ``normal_radius_cm`` R: :func:`~dome_calib.recon.patches.seed._normals`), ``refined_REACH``
(today's photometric refinement after the seed's MAP visibility, first step REACH deg; ``_all_streams``: in every
stream's cameras). ``seen_behind``: of the cameras that triangulated a seed, the share the true surface faces away
from (cosine <= 0); ``facing_elsewhere``: outline seeds that a camera of another stream faces (cosine > 0.5);
``boundary_offset``: the seed's in-plane distance from its neighbours' centroid over R (a one-sided neighbourhood).
"""
from __future__ import annotations

import argparse
import json
import os

import numpy as np

from dome_calib.synth.dome import as_built_dome
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.textured import surface_points_cm, surface_visibility
from dome_calib.recon.project import view_set
from patches import bench_cameras

ORACLE_ERROR_DEG = (15.0, 20.0, 30.0)
ORACLE_CUTS = (0.3, 0.4, 0.5)
CLASSES = ("true_positive", "back_facing_fp", "other_fp", "drifted", "false_negative")


def _pcts(x: np.ndarray) -> list[float] | None:
    return [round(float(v), 3) for v in np.percentile(x, [10, 50, 90])] if len(x) else None


def _deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1.0, 1.0)))


def run(args: argparse.Namespace) -> None:
    Z = np.load(args.stream)
    bundle = as_built_dome(args.preset, seed=args.seed)
    cams = bench_cameras(bundle, args.vga, args.hd, args.kinect)
    truth = make_group(GroupOptions(n_people=args.people, scenario=args.scenario, start_ms=500.0,
                                    duration_ms=5000.0, seed=args.seed))
    times, alive, visible, X, n_est = Z["times_ms"], Z["alive"], Z["visible"], Z["X_cm"], Z["normal"]
    P, n_true = surface_points_cm(truth, times, Z["person"], Z["part"], Z["local_cm"])  # (T, N, 3)
    s = len(times) // 2  # the bench tracks --frames each way from the seed
    seed_err = _deg(n_est[:, s], n_true[s])  # (N,) NaN where not alive at the seed
    C = view_set(bundle, cams).center_cm
    rows = {c: {k: [] for k in ("normal_error_deg", "seed_normal_error_deg", "cos_true", "cos_est", "cos_gain",
                                "visible_spread_deg")} for c in CLASSES}
    keep = {c: [] for c in CLASSES}  # (cos_est, normal error, spread) per view, for the separations
    per_patch = np.zeros((len(alive), len(CLASSES)))  # views of each class per patch, over the track
    totals = np.zeros(3)  # true positives, false positives, false negatives (all patches)
    oracle = {(e, c): np.zeros(2) for e in ORACLE_ERROR_DEG for c in ORACLE_CUTS}  # (TP, FP) dropped
    for k in range(len(times)):
        a = np.flatnonzero(alive[:, k])
        if not len(a):
            continue
        true = surface_visibility(bundle, cams, truth, float(times[k]), P[k][a], n_true[k][a])
        est = visible[a, k]
        near = 10.0 * np.linalg.norm(X[a, k, 0] - P[k][a], axis=-1) <= 10.0
        to_t = C[None] - P[k][a][:, None]
        cos_t = np.einsum("nvi,ni->nv", to_t, n_true[k][a]) / np.linalg.norm(to_t, axis=-1)
        to_e = C[None] - X[a, k, 0][:, None]
        to_e /= np.linalg.norm(to_e, axis=-1, keepdims=True)
        cos_e = np.einsum("nvi,ni->nv", to_e, n_est[a, k])
        err = _deg(n_est[a, k], n_true[k][a])
        mean_dir = np.where(est[..., None], to_e, 0.0).sum(1)
        mean_dir /= np.maximum(np.linalg.norm(mean_dir, axis=-1, keepdims=True), 1e-9)
        spread = _deg(mean_dir, n_est[a, k])
        masks = {"true_positive": est & true, "back_facing_fp": est & ~true & (cos_t <= 0) & near[:, None],
                 "other_fp": est & ~true & (cos_t > 0) & near[:, None], "drifted": est & ~true & ~near[:, None],
                 "false_negative": ~est & true & near[:, None]}
        totals += [np.sum(est & true), np.sum(est & ~true), np.sum(true & ~est)]
        for (e_deg, cut), got in oracle.items():
            drop = est & (seed_err[a] >= e_deg)[:, None] & (cos_e < cut)
            got += [np.sum(drop & true), np.sum(drop & ~true)]
        for c, m in masks.items():
            pi, vi = np.nonzero(m)
            r = rows[c]
            r["normal_error_deg"].append(err[pi])
            r["seed_normal_error_deg"].append(seed_err[a][pi])
            r["cos_true"].append(cos_t[pi, vi])
            r["cos_est"].append(cos_e[pi, vi])
            r["cos_gain"].append(cos_e[pi, vi] - cos_t[pi, vi])
            r["visible_spread_deg"].append(spread[pi])
            keep[c].append(np.stack([cos_e[pi, vi], err[pi], spread[pi]], 1))
            np.add.at(per_patch[:, CLASSES.index(c)], a[pi], 1)
    out = {}
    for c in CLASSES:
        got = {k: np.concatenate(v) if v else np.zeros(0) for k, v in rows[c].items()}
        out[c] = {"views": int(len(got["cos_true"])),
                  **{k: _pcts(v[np.isfinite(v)]) for k, v in got.items()}}
    tp = np.concatenate(keep["true_positive"])
    bf = np.concatenate(keep["back_facing_fp"])
    fp_all = sum(len(np.concatenate(keep[c])) for c in ("back_facing_fp", "other_fp", "drifted"))
    seps = []
    for name, col, cut in ([("cos_est_below", 0, x) for x in (0.3, 0.4, 0.5)]
                           + [("visible_spread_deg_above", 2, x) for x in (20.0, 30.0, 40.0)]):
        drop_tp = tp[:, col] < cut if col == 0 else tp[:, col] > cut
        drop_bf = bf[:, col] < cut if col == 0 else bf[:, col] > cut
        kept_tp = len(tp) - int(drop_tp.sum())
        kept_fp = fp_all - int(drop_bf.sum())
        seps.append({"rule": name, "cut": cut, "back_facing_fp_dropped": int(drop_bf.sum()),
                     "true_positive_dropped": int(drop_tp.sum()),
                     "precision_after": round(kept_tp / max(kept_tp + kept_fp, 1), 4)})
    at_seed = alive[:, s]
    bins = {}
    for lo, hi in ((0, 10), (10, 20), (20, 30), (30, 45), (45, 180)):
        m = at_seed & (seed_err >= lo) & (seed_err < hi)
        bins[f"{lo}-{hi}"] = {"patches": int(m.sum()), **{c: int(per_patch[m, i].sum()) for i, c in enumerate(CLASSES)}}
    back = np.sort(per_patch[:, CLASSES.index("back_facing_fp")])[::-1]
    share = np.cumsum(back) / max(back.sum(), 1)
    concentration = {"patches_alive_at_seed": int(at_seed.sum()),
                     "patches_with_half": int(np.searchsorted(share, 0.5) + 1) if back.sum() else 0,
                     "patches_with_four_fifths": int(np.searchsorted(share, 0.8) + 1) if back.sum() else 0}
    tp_n, fp_n, fn_n = totals
    gaps = _seed_gaps(X[:, s, 0], n_est[:, s], at_seed)
    by_gap = {}
    for lo, hi in GAP_BINS_DEG:
        m = at_seed & (gaps >= lo) & (gaps < hi)
        got = {c: int(per_patch[m, i].sum()) for i, c in enumerate(CLASSES)}
        fp = got["back_facing_fp"] + got["other_fp"] + got["drifted"]
        by_gap[f"{lo:g}-{hi:g}"] = {"patches": int(m.sum()), **got,
                                    "precision": round(got["true_positive"] / max(got["true_positive"] + fp, 1), 4),
                                    "seed_normal_error_deg": _pcts(seed_err[m & np.isfinite(seed_err)])}
    bound = [{"seed_error_deg": e, "cut": c,
              "precision": round(float((tp_n - d[0]) / max(tp_n - d[0] + fp_n - d[1], 1)), 4),
              "recall": round(float((tp_n - d[0]) / max(tp_n + fn_n, 1)), 4)} for (e, c), d in oracle.items()]
    print(json.dumps({"stream": args.stream, "people": args.people, "seed": args.seed, "scenario": args.scenario,
                      "precision": round(len(tp) / max(len(tp) + fp_all, 1), 4), "classes": out,
                      "separations": seps, "by_seed_normal_error": bins, "by_neighbour_gap": by_gap,
                      "concentration": concentration,
                      "oracle_grazing": bound, "load": [round(x, 2) for x in os.getloadavg()]}), flush=True)


#: ``by_neighbour_gap``'s bins (deg) of the seeds' :func:`~dome_calib.recon.patches.seed.neighbour_gap_deg`.
GAP_BINS_DEG = ((0.0, 90.0), (90.0, 150.0), (150.0, 180.0), (180.0, 210.0), (210.0, 240.0), (240.0, 361.0))


def _seed_gaps(X: np.ndarray, normal: np.ndarray, alive: np.ndarray, radius_cm: float = 4.0) -> np.ndarray:
    """(N,) each seed's :func:`~dome_calib.recon.patches.seed.neighbour_gap_deg` among the live seeds (``alive``)
    within ``radius_cm``, in the plane of its normal (NaN where not alive): the stream's merged cloud at the seed
    time, near what each stream's merge saw."""
    from scipy.spatial import cKDTree

    from dome_calib.recon.patches.seed import neighbour_gap_deg

    out = np.full(len(X), np.nan)
    idx = np.flatnonzero(alive)
    for i, nb in zip(idx, cKDTree(X[idx]).query_ball_point(X[idx], radius_cm)):
        n = normal[i]
        u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        out[i] = neighbour_gap_deg(X[i], X[idx[nb]], u, np.cross(n, u))
    return out


SEED_RADII_CM = (3.0, 4.0, 6.0)
OUTLINE_EDGE_ON_DEG = 15.0


def _fit_normals(X: np.ndarray, pts: np.ndarray, towards: np.ndarray, radius_cm: float, quadric: bool = False,
                 keep=None, tree_pts: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) normals of seeds X from the points ``pts`` (same rows as ``tree_pts``, default X) within ``radius_cm``
    of each: the least principal axis, or the normal at the seed of a quadric fitted in that axis' frame; the sign
    towards ``towards`` (N, 3). NaN with fewer than 5 (quadric: 8) neighbours."""
    from scipy.spatial import cKDTree

    out = np.full(X.shape, np.nan)
    for i, nb in enumerate(cKDTree(pts if tree_pts is None else tree_pts).query_ball_point(X, radius_cm)):
        nb = np.array(sorted(nb), dtype=np.int64)
        if keep is not None:
            nb = nb[keep(i, nb)]
        if len(nb) < (8 if quadric else 5):
            continue
        Q = pts[nb]
        _, _, Vt = np.linalg.svd(Q - Q.mean(0), full_matrices=False)
        n = Vt[2]
        if quadric:
            x, y, z = ((Q - pts[i]) @ Vt.T).T
            c, *_ = np.linalg.lstsq(np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], 1), z, rcond=None)
            n = np.array([-c[1], -c[2], 1.0]) @ Vt
            n /= np.linalg.norm(n)
        out[i] = n if n @ towards[i] > 0 else -n
    return out


def run_seeds(args: argparse.Namespace) -> None:
    """``--seeds``: the seeds' normals against the truth (module docstring)."""
    import dataclasses
    import time
    from pathlib import Path

    from patches import GrayCache, TexturedScene, bench_scene, cameras_by_type, render_cache_key
    from dome_calib.recon.patches import seed as S
    from dome_calib.recon.patches.frames import patch_axes
    from dome_calib.recon.patches.model import PatchOptions
    from dome_calib.recon.patches.refine import refine_normals
    from dome_calib.recon.patches.run import clocks_of, imaged_views, stream_seed_frame
    from dome_calib.recon.patches.track import judged_frames, quantise_cm
    from dome_calib.recon.patches.visibility import camera_neighbours, estimate_visibility
    from dome_calib.synth.textured import nearest_surface_points

    bundle, group, truth, texture = bench_scene(args)
    disk = (Path(args.render_cache) / render_cache_key(bundle, group, texture, args.preset, args.seed)
            if args.render_cache else None)
    source = GrayCache(TexturedScene(bundle, truth, texture, cache_frames=3), disk if disk and disk.exists() else None)
    cams = bench_cameras(bundle, args.vga, args.hd, args.kinect)
    table = bundle.sync.streams["vga"]
    f = int(table.index[int(np.searchsorted(table.univ_time_ms, 2500.0))])
    f -= f % 20  # bench/patches.py's seed frame
    t_seed = float(table.time_of(f))
    o = PatchOptions(track_frames=10)
    by_type = cameras_by_type(bundle)
    vga = [c for c in cams if c in by_type["vga"]]
    views_v = imaged_views(source, vga)
    c0 = time.process_time()
    per = [S.seed_camera(source, views_v, {n: f for n in vga}, r, o) for r in range(len(vga))]
    parts = [c for c in per if len(c.X_cm)]
    X = np.concatenate([c.X_cm for c in parts])
    seen = np.concatenate([c.seen for c in parts])
    pick = S.thin_to_cells(X, [np.concatenate([np.full(len(c.X_cm), c.camera) for c in parts]),
                               -np.concatenate([c.n_inliers for c in parts])], o.seed_spacing_cm)
    X, seen = X[pick], seen[pick]
    seed_cpu = time.process_time() - c0
    sp = nearest_surface_points(truth, t_seed, X)
    P, n_true = (a[0] for a in surface_points_cm(truth, np.array([t_seed]), sp.person, sp.part, sp.local_cm))
    near = np.linalg.norm(P - X, axis=1) < 1.0
    C = views_v.center_cm
    to = C[None] - X[:, None]
    to /= np.linalg.norm(to, axis=-1, keepdims=True)
    cos_t = np.einsum("nvi,ni->nv", to, n_true)
    edge = np.sin(np.radians(OUTLINE_EDGE_ON_DEG))
    outline = near & np.all(np.where(seen, np.abs(cos_t) <= edge, True), 1)
    classes = {"outline": outline, "rest": near & ~outline}
    towards = np.stack([(C[seen[i]] - X[i]).sum(0) for i in range(len(X))])
    est = {}
    for r in SEED_RADII_CM:
        est[f"svd_{r:g}"] = _fit_normals(X, X, towards, r)
        est[f"svd_{r:g}_true_points"] = _fit_normals(X, P, towards, r, tree_pts=X)
    for r in (6.0, 8.0):
        est[f"quadric_{r:g}_true_points"] = _fit_normals(X, P, towards, r, quadric=True, tree_pts=X)
    on_surface = np.linalg.norm(P - X, axis=1) < 0.3
    est["svd_4_same_part_on_surface"] = _fit_normals(
        X, X, towards, 4.0, keep=lambda i, nb: (sp.part[nb] == sp.part[i]) & (sp.person[nb] == sp.person[i])
        & on_surface[nb])
    hd = [c for c in cams if c in by_type["hd"]]
    views_h = imaged_views(source, hd)
    g = stream_seed_frame(clocks_of(bundle, source, hd), t_seed)
    hs = S.merge_camera_seeds([S.seed_camera(source, views_h, {n: g for n in hd}, r, o) for r in range(len(hd))],
                              views_h, o) if g is not None else None
    U = X if hs is None else np.concatenate([X, hs.X_cm[:, 0]])
    est["svd_4_with_hd_seeds"] = _fit_normals(X, U, towards, 4.0)
    for r in (4.0, 6.0):  # the stage's own rule (seed._normals, normal_fit="quadric": the plane below 8 points)
        est[f"stage_quadric_{r:g}"] = S._normals(X, X, seen, C, r, o.normal_min_points, "quadric")[0]
    # today's refinement, as run_cloud does it: the seed's MAP visibility in all the bench's cameras, then tilts
    normal, axis, ok = S._normals(X, X, seen, C, o.normal_radius_cm, o.normal_min_points)
    views = imaged_views(source, cams)
    frames = judged_frames(clocks_of(bundle, source, cams), t_seed)
    Xp = quantise_cm(S.patch_triplets(X[ok], normal[ok], axis[ok], o.axis_cm))
    seen_all = np.zeros((len(Xp), len(cams)), bool)
    seen_all[:, [cams.index(n) for n in vga]] = seen[ok]
    vis = estimate_visibility(source, views, frames, Xp, np.zeros_like(Xp), seen_all, None,
                              camera_neighbours(views, o.prior_neighbours), o, None).visible
    for name, oo in (("refined_8", o), ("refined_16", dataclasses.replace(o, normal_refine_reach_deg=16.0)),
                     ("refined_8_all_streams", dataclasses.replace(o, normal_refine_all_streams=True))):
        Xr = refine_normals(source, views, frames, Xp, vis, oo)
        est[name] = np.full(X.shape, np.nan)
        est[name][ok] = patch_axes(Xr[:, 0], Xr[:, 1], Xr[:, 2])[2]
    out = {}
    for name, n in est.items():
        err = _deg(n, n_true)
        out[name] = {}
        for c, m in classes.items():
            e = err[m & np.isfinite(err)]
            out[name][c] = {"n": int(len(e)), "pcts_deg": _pcts(e),
                            "share_above_30": round(float(np.mean(e > 30.0)), 3) if len(e) else None}
    n4 = est["svd_4"]
    mean_dir = towards / np.linalg.norm(towards, axis=1, keepdims=True)
    lean = {c: {"cos_true_normal": _pcts(np.sum(n_true[m] * mean_dir[m], 1)),
                "cos_svd_4": _pcts(np.sum(n4[m & np.isfinite(n4[:, 0])] * mean_dir[m & np.isfinite(n4[:, 0])], 1))}
            for c, m in classes.items()}
    behind = {c: {"seen_behind": round(float(np.mean(cos_t[m][seen[m]] <= 0)), 3),
                  "not_seen_behind": round(float(np.mean(cos_t[m][~seen[m]] <= 0)), 3),
                  "seen_cos_true": _pcts(cos_t[m][seen[m]])} for c, m in classes.items()}
    Ca = views.center_cm
    ta = Ca[None] - X[:, None]
    ta /= np.linalg.norm(ta, axis=-1, keepdims=True)
    other = [k for k, n in enumerate(cams) if n not in vga]
    facing = np.any(np.einsum("nvi,ni->nv", ta[:, other], n_true) > 0.5, axis=1)
    from scipy.spatial import cKDTree

    offset = np.full(len(X), np.nan)
    for i, nb in enumerate(cKDTree(X).query_ball_point(X, 4.0)):
        if len(nb) >= 5 and np.isfinite(n4[i, 0]):
            d = X[i] - X[sorted(nb)].mean(0)
            offset[i] = np.linalg.norm(d - (d @ n4[i]) * n4[i]) / 4.0
    print(json.dumps({"what": "seed_normals", "people": args.people, "seed": args.seed, "scenario": args.scenario,
                      "seeds": int(len(X)), "within_1cm": int(near.sum()), "outline": int(outline.sum()),
                      "hd_seeds": 0 if hs is None else int(len(hs.X_cm)), "seed_cpu_s": round(seed_cpu, 1),
                      "normal_error": out, "lean_towards_seeing_cameras": lean, "behind": behind,
                      "facing_elsewhere": int(np.sum(outline & facing)),
                      "boundary_offset": {c: _pcts(offset[m & np.isfinite(offset)]) for c, m in classes.items()},
                      "load": [round(x, 2) for x in os.getloadavg()]}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stream", nargs="?", default="")
    ap.add_argument("--seeds", action="store_true", help="the seeds' normals against the truth (no STREAM)")
    ap.add_argument("--render-cache", default="", help="bench/patches.py --render-cache folder (read if there)")
    ap.add_argument("--preset", default="panel")
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--scenario", default="conversation")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--vga", type=int, default=24)
    ap.add_argument("--hd", type=int, default=4)
    ap.add_argument("--kinect", type=int, default=2)
    args = ap.parse_args()
    if args.seeds:
        return run_seeds(args)
    if not args.stream:
        ap.error("STREAM.npz is needed without --seeds")
    run(args)


if __name__ == "__main__":
    main()
