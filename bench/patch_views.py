"""How many cameras see a point of the people's surface, the figure that scales the patch stream's tracking cost from
a measured rig to another: per dome preset and group, the mean number of cameras (by type) that see a surface point
(in the image, facing it, not occluded: :func:`dome_calib.synth.textured.surface_visibility`) and of those within
78 deg of its normal (the stage's ``min_cos_view`` 0.2: the views it can use).

Run: .venv/bin/python bench/patch_views.py [--presets panel,full] [--people 2,8] [--points 300] [--seed 0]
Surface points: the nearest surface point of random points within 15 cm of each person's joints at 2.5 s (the
same number per person). Prints one JSON object per line.
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from dome_calib.synth.dome import as_built_dome
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.textured import nearest_surface_points, surface_points_cm, surface_visibility


def run(args: argparse.Namespace) -> None:
    for people in [int(x) for x in args.people.split(",")]:
        truth = make_group(GroupOptions(n_people=people, scenario=args.scenario, start_ms=500.0, duration_ms=5000.0,
                                        seed=args.seed))
        t = 2500.0
        Xj, present = truth.joints_cm(np.array([t]))
        rng = np.random.default_rng(args.seed)
        per = max(1, args.points // people)
        q = []
        for p in np.flatnonzero(present[0]):
            J = Xj[0, p][np.all(np.isfinite(Xj[0, p]), axis=1)]
            q.append(J[rng.integers(0, len(J), per)] + rng.uniform(-15.0, 15.0, (per, 3)))
        sp = nearest_surface_points(truth, t, np.concatenate(q))
        P, normal = surface_points_cm(truth, np.array([t]), sp.person, sp.part, sp.local_cm)
        for preset in args.presets.split(","):
            bundle = as_built_dome(preset, seed=args.seed)
            cams = sorted(bundle.cameras)
            c0 = time.process_time()
            seen = surface_visibility(bundle, cams, truth, t, P[0], normal[0])
            C = np.array([bundle.cameras[n].center_cm for n in cams])
            to_cam = C[None] - P[0][:, None]
            cos = np.sum(to_cam * normal[0][:, None], -1) / np.linalg.norm(to_cam, axis=-1)
            usable = seen & (cos > 0.2)
            kinds = np.array([str(bundle.cameras[n].type) for n in cams])
            out = {k: {"seen": round(float(seen[:, kinds == k].sum(1).mean()), 2),
                       "within_78deg": round(float(usable[:, kinds == k].sum(1).mean()), 2),
                       "cameras": int((kinds == k).sum())} for k in sorted(set(kinds))}
            print(json.dumps({"preset": preset, "people": people, "points": int(len(P[0])), "views_per_point": out,
                              "cpu_s": round(time.process_time() - c0, 1),
                              "load": [round(x, 2) for x in os.getloadavg()]}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--presets", default="panel,full")
    ap.add_argument("--people", default="2,8")
    ap.add_argument("--scenario", default="conversation")
    ap.add_argument("--points", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    run(ap.parse_args())


if __name__ == "__main__":
    main()
