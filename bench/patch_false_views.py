"""Where the patch stream's visibility says "visible" and the renderer says not: the precision's losses of a saved
stream split by cause, frames from the seed, the patch's views, its drift and whether the camera saw it truly the
step before (towards the seed).

Run: .venv/bin/python bench/patch_false_views.py STREAM.npz [--people 2] [--scenario conversation] [--seed 0]
         [--vga 24] [--hd 4] [--kinect 2] [--preset panel]
STREAM.npz: a ``bench/patches.py --save`` run with the same scene options. Every view labelled visible of a patch
alive at a time is a true or a false positive against the renderer's truth (in the image, facing, not occluded:
``bench/patches.py``'s judging); a false positive is given the first cause of ``bench/patches.py``'s
:data:`FALSE_POSITIVE_CAUSES` that applies (drifted more than 1 cm, the true surface back-facing, occluded by
another person, by another part of the same person, by its own part, out of the image, other). Each class is then
split by frames from the seed, the patch's views labelled visible then (MAP), its centre's distance from its true
point (mm), whether the camera truly saw the patch the step before (``onset``: no, the truth changed this step or
earlier) and camera type; beside them the precision per frames-from-the-seed bin. Prints one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os

import numpy as np

from dome_calib.recon.patches.model import PatchOptions
from dome_calib.synth.textured import TexturedScene, surface_points_cm, surface_visibility
from dome_calib.recon.patches.run import imaged_views
from patch_misses import binned
from patches import (FALSE_POSITIVE_CAUSES, add_scene_arguments, bench_cameras, bench_scene, cameras_by_type,
                     cause_rules, first_cause)

BINS = {"frames_from_seed": (0, 1, 4, 8, 12, 16, 21, 26, 31, 100), "map_views": (0, 3, 4, 6, 10, 100),
        "drift_mm": (0.0, 2.0, 4.0, 6.0, 10.0, 1e9), "truly_seen_before": (0, 1, 2)}


def run(args: argparse.Namespace) -> None:
    Z = np.load(args.stream)
    bundle, _, truth, texture = bench_scene(args)
    cams = bench_cameras(bundle, args.vga, args.hd, args.kinect)
    views = imaged_views(TexturedScene(bundle, truth, texture), cams)
    kind_of = {c: k for k, names in cameras_by_type(bundle).items() for c in names}
    kinds = np.array([kind_of[c] for c in cams])
    o = PatchOptions()
    times, alive, visible, X = Z["times_ms"], Z["alive"], Z["visible"], Z["X_cm"]
    person, part = Z["person"], Z["part"]
    P, n_true = surface_points_cm(truth, times, person, part, Z["local_cm"])  # (T, N, 3)
    T, N, V = len(times), len(alive), len(cams)
    s = T // 2  # the bench tracks --frames each way from the seed
    true_all = np.zeros((N, T, V), bool)
    rows: list[np.ndarray] = []  # (frames from seed, map views, drift mm, truly seen before, camera, cause, fp)
    order = [s] + [k for j in range(1, s + 1) for k in (s - j, s + j) if 0 <= k < T]  # the seed outwards
    for k in order:
        a = np.flatnonzero(alive[:, k])
        if not len(a):
            continue
        true = surface_visibility(bundle, cams, truth, float(times[k]), P[k][a], n_true[k][a])
        true_all[a, k] = true
        est = visible[a, k]
        before = true_all[a, k + 1] if k < s else true_all[a, k - 1] if k > s else true
        err_mm = 10.0 * np.linalg.norm(X[a, k, 0] - P[k][a], axis=-1)
        fp_rules, _ = cause_rules(truth, views, float(times[k]), X[a, k], P[k][a], n_true[k][a], person[a],
                                  part[a], err_mm, true, o)
        cause = first_cause(fp_rules)
        pi, vi = np.nonzero(est)
        rows.append(np.stack([np.full(len(pi), abs(k - s)), est.sum(1)[pi], err_mm[pi], before[pi, vi], vi,
                              cause[pi, vi], ~true[pi, vi]], 1).astype(float))
    g = np.concatenate(rows) if rows else np.zeros((0, 7))
    fp = g[:, 6] > 0
    out = {}
    for c, name in enumerate(FALSE_POSITIVE_CAUSES):
        m = fp & (g[:, 5] == c)
        out[name] = {"views": int(m.sum()), "share_of_false": round(float(m.sum() / max(fp.sum(), 1)), 4),
                     "by_camera_type": {t: int(np.sum(kinds[g[m, 4].astype(int)] == t)) for t in sorted(set(kinds))},
                     **{b: binned(g[m, i], e) for i, (b, e) in enumerate(BINS.items())}}
    every = {b: binned(g[:, i], e) for i, (b, e) in enumerate(BINS.items())}
    false = {b: binned(g[fp, i], e) for i, (b, e) in enumerate(BINS.items())}
    precision = {b: [round(1.0 - f / n, 4) if n else None for f, n in zip(false[b], every[b])] for b in BINS}
    print(json.dumps({"stream": args.stream, "scenario": args.scenario, "people": args.people, "seed": args.seed,
                      "precision": round(float(1.0 - fp.sum() / max(len(g), 1)), 4), "labelled_visible": int(len(g)),
                      "false": int(fp.sum()), "bins": BINS, "labelled_by_bin": every, "false_by_bin": false,
                      "precision_by_bin": precision, "causes": out,
                      "load": [round(x, 2) for x in os.getloadavg()]}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stream")
    add_scene_arguments(ap)
    run(ap.parse_args())


if __name__ == "__main__":
    main()
