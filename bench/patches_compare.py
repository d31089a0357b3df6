"""Two variants of ``bench/patches.py --save`` (one invocation: the same seeds, the same order) judged on the same
patch-times: the centre error against the true surface point where both are alive, so a variant that keeps more
patches alive is not judged on a different population.

Run: .venv/bin/python bench/patches_compare.py A.npz B.npz [--people 2] [--scenario conversation] [--seed 0]
         [--lags 1,10,30]
(the group's options as given to bench/patches.py). Prints one JSON object: per lag (frames from the seed, both
directions pooled) the patch-times alive in A, in B and in both, and over those in both the median and 90th
percentile error of each (mm), and how many are better by more than 1 mm in each.
"""
from __future__ import annotations

import argparse
import json

import numpy as np

from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.textured import surface_points_cm


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--scenario", default="conversation")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--lags", default="1,10,30")
    args = ap.parse_args()
    A, B = np.load(args.a), np.load(args.b)
    for key in ("times_ms", "person", "part", "local_cm"):
        if not np.array_equal(A[key], B[key]):
            raise SystemExit(f"{args.b}: {key} differs from {args.a}'s (not the same seeds)")
    truth = make_group(GroupOptions(n_people=args.people, scenario=args.scenario, start_ms=500.0,
                                    duration_ms=5000.0, seed=args.seed))
    P, _ = surface_points_cm(truth, A["times_ms"], A["person"], A["part"], A["local_cm"])  # (T, N, 3)
    err = {name: 10.0 * np.linalg.norm(Z["X_cm"][:, :, 0] - P.transpose(1, 0, 2), axis=-1) for name, Z in
           (("a", A), ("b", B))}
    T = len(A["times_ms"])
    s = T // 2  # the seed time: the bench tracks --frames each way
    out = {"a": args.a, "b": args.b, "lags": {}}
    for lag in [int(x) for x in args.lags.split(",")]:
        cols = [c for c in (s - lag, s + lag) if 0 <= c < T and lag <= s]
        if not cols:
            continue
        a_alive = np.concatenate([A["alive"][:, c] for c in cols])
        b_alive = np.concatenate([B["alive"][:, c] for c in cols])
        ea = np.concatenate([err["a"][:, c] for c in cols])
        eb = np.concatenate([err["b"][:, c] for c in cols])
        both = a_alive & b_alive
        out["lags"][str(lag)] = {
            "alive_a": int(a_alive.sum()), "alive_b": int(b_alive.sum()), "both": int(both.sum()),
            "a_median_mm": round(float(np.median(ea[both])), 3) if both.any() else None,
            "b_median_mm": round(float(np.median(eb[both])), 3) if both.any() else None,
            "a_p90_mm": round(float(np.percentile(ea[both], 90)), 3) if both.any() else None,
            "b_p90_mm": round(float(np.percentile(eb[both], 90)), 3) if both.any() else None,
            "a_better_by_1mm": int(np.sum(ea[both] < eb[both] - 1.0)),
            "b_better_by_1mm": int(np.sum(eb[both] < ea[both] - 1.0))}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
