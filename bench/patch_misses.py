"""Which true views the patch stream's visibility misses, and why: the recall's losses of a saved stream split by
cause, camera distance, view angle, the surface point's speed and the frames since the seed.

Run: .venv/bin/python bench/patch_misses.py STREAM.npz [--people 2] [--scenario walk_past] [--seed 0]
         [--vga 24] [--hd 4] [--kinect 2] [--preset panel]
STREAM.npz: a ``bench/patches.py --save`` run with the same scene options. Every true view (the renderer's truth:
in the image, facing, not occluded) of a patch alive at a time is a hit (labelled visible) or a miss; a miss is
given the first cause that applies: ``drifted`` (the patch more than 1 cm from its true point), ``grazing`` (true
cosine below the stage's ``min_cos_view`` 0.2: never a candidate), ``wrong_normal`` (true cosine above it, the
patch's own not: never a candidate), ``near_border`` (the patch's square leaves the image), ``labelled_not_visible``
(a candidate, or a camera the people hide from it, that the cut labelled not visible). Beside them, ``dead``: the
true views of patches seeded (alive at the seed) and no longer alive, which the recall (over live patch-times) does
not count. Every class is then split by camera type, camera distance (m), true view cosine, the point's speed (cm per
reference-stream frame, over the step away from the seed) and frames from the seed. Prints one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os

import numpy as np

from dome_calib.recon.patches.frames import patch_grid_cm
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.project import project_points, view_set
from dome_calib.synth.dome import as_built_dome
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.textured import surface_points_cm, surface_visibility
from patches import add_scene_arguments, bench_cameras, cameras_by_type

CAUSES = ("drifted", "grazing", "wrong_normal", "near_border", "labelled_not_visible")
BINS = {"distance_m": (0.0, 1.0, 1.5, 2.0, 2.5, 10.0), "cos_true": (0.0, 0.2, 0.4, 0.6, 0.8, 1.01),
        "speed_cm_per_frame": (0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 100.0), "frames_from_seed": (0, 1, 3, 6, 11, 100)}


def binned(values: np.ndarray, edges: tuple) -> list[int]:
    """How many of ``values`` fall in each bin of ``edges``."""
    return np.histogram(values, bins=np.asarray(edges, float))[0].astype(int).tolist()


def run(args: argparse.Namespace) -> None:
    Z = np.load(args.stream)
    bundle = as_built_dome(args.preset, seed=args.seed)
    cams = bench_cameras(bundle, args.vga, args.hd, args.kinect)
    kind_of = {c: k for k, names in cameras_by_type(bundle).items() for c in names}
    kinds = np.array([kind_of[c] for c in cams])
    truth = make_group(GroupOptions(n_people=args.people, scenario=args.scenario, start_ms=500.0,
                                    duration_ms=5000.0, seed=args.seed))
    o = PatchOptions()
    times, alive, visible, X = Z["times_ms"], Z["alive"], Z["visible"], Z["X_cm"]
    P, n_true = surface_points_cm(truth, times, Z["person"], Z["part"], Z["local_cm"])  # (T, N, 3)
    T = len(times)
    s = T // 2  # the bench tracks --frames each way from the seed
    seeded = alive[:, s]
    vs = view_set(bundle, cams)
    C = vs.center_cm
    rows: dict[str, list[np.ndarray]] = {c: [] for c in ("hit",) + CAUSES + ("dead",)}
    for k in range(T):
        k2 = min(k + 1, T - 1) if k >= s else max(k - 1, 0)  # the point's step away from the seed
        speed = np.linalg.norm(P[k2] - P[k], axis=-1) / max(abs(k2 - k), 1)  # (N,) cm per frame
        a = np.flatnonzero(alive[:, k] | seeded)
        if not len(a):
            continue
        true = surface_visibility(bundle, cams, truth, float(times[k]), P[k][a], n_true[k][a])
        to_t = C[None] - P[k][a][:, None]
        dist = np.linalg.norm(to_t, axis=-1)
        cos_t = np.einsum("nvi,ni->nv", to_t, n_true[k][a]) / dist
        live = alive[a, k]
        Xa = np.where(live[:, None, None], X[a, k], 0.0)
        n_e = np.cross(Xa[:, 1] - Xa[:, 0], Xa[:, 2] - Xa[:, 0])
        n_e /= np.maximum(np.linalg.norm(n_e, axis=-1, keepdims=True), 1e-12)
        to_e = C[None] - Xa[:, None, 0]
        cos_e = np.einsum("nvi,ni->nv", to_e, n_e) / np.linalg.norm(to_e, axis=-1)
        grid = patch_grid_cm(Xa[:, 0], Xa[:, 1], Xa[:, 2], o.ncc_size_cm)
        square_in = project_points(vs, grid.reshape(-1, 3)).visible.reshape(len(C), len(a), -1).all(-1).T
        drift = (10.0 * np.linalg.norm(Xa[:, 0] - P[k][a], axis=-1) > 10.0)[:, None]
        est = visible[a, k]
        left = true & live[:, None] & ~est
        masks = {"hit": true & live[:, None] & est}
        for name, rule in zip(CAUSES, (drift, cos_t < o.min_cos_view, cos_e <= o.min_cos_view, ~square_in,
                                       np.ones_like(true))):
            masks[name] = left & rule
            left &= ~rule
        masks["dead"] = true & ~live[:, None]
        for name, m in masks.items():
            pi, vi = np.nonzero(m)
            rows[name].append(np.stack([dist[pi, vi] / 100.0, cos_t[pi, vi], speed[a][pi],
                                        np.full(len(pi), abs(k - s)), vi], 1))
    out = {}
    live_true = sum(len(np.concatenate(rows[c])) for c in ("hit",) + CAUSES)
    for name, got in rows.items():
        g = np.concatenate(got) if got else np.zeros((0, 5))
        out[name] = {"views": int(len(g)), "share_of_live_true": round(len(g) / max(live_true, 1), 4),
                     "by_camera_type": {t: int(np.sum(kinds[g[:, 4].astype(int)] == t)) for t in sorted(set(kinds))},
                     **{b: binned(g[:, i], e) for i, (b, e) in enumerate(BINS.items())}}
    hits = out["hit"]["views"]
    print(json.dumps({"stream": args.stream, "scenario": args.scenario, "people": args.people, "seed": args.seed,
                      "recall": round(hits / max(live_true, 1), 4), "bins": BINS, "classes": out,
                      "load": [round(x, 2) for x in os.getloadavg()]}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stream")
    add_scene_arguments(ap, "walk_past")
    run(ap.parse_args())


if __name__ == "__main__":
    main()
