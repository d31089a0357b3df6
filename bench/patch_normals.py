"""The patches' normals against the truth, per visibility verdict: what tells the back-facing false positives (views of
the true surface's back that the MAP labels visible) from the true views.

Run: .venv/bin/python bench/patch_normals.py STREAM.npz [--people 2] [--scenario conversation] [--seed 0]
         [--vga 24] [--hd 4] [--kinect 2] [--preset panel]
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
``concentration``: how few patches hold half and four fifths of the back-facing false positives. ``oracle_grazing``:
a bound on any grazing-angle rule: told which patches' seed normals are at least ``seed_error_deg`` off (which no
rule knows), their labelled views with ``cos_est`` below ``cut`` dropped: the precision and recall then. Prints one
JSON object per line.
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
    bound = [{"seed_error_deg": e, "cut": c,
              "precision": round(float((tp_n - d[0]) / max(tp_n - d[0] + fp_n - d[1], 1)), 4),
              "recall": round(float((tp_n - d[0]) / max(tp_n + fn_n, 1)), 4)} for (e, c), d in oracle.items()]
    print(json.dumps({"stream": args.stream, "people": args.people, "seed": args.seed, "scenario": args.scenario,
                      "precision": round(len(tp) / max(len(tp) + fp_all, 1), 4), "classes": out,
                      "separations": seps, "by_seed_normal_error": bins, "concentration": concentration,
                      "oracle_grazing": bound, "load": [round(x, 2) for x in os.getloadavg()]}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stream")
    ap.add_argument("--preset", default="panel")
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--scenario", default="conversation")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--vga", type=int, default=24)
    ap.add_argument("--hd", type=int, default=4)
    ap.add_argument("--kinect", type=int, default=2)
    run(ap.parse_args())


if __name__ == "__main__":
    main()
