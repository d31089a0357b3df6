"""Projection throughput: our vectorised camera model vs cv2.projectPoints looped over cameras, same points.

Prints one JSON object per line. Run: .venv/bin/python bench/camera.py [--points 2000] [--repeats 7]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

from dome_calib.camera import K_to_intr, project
from dome_calib.panoptic_io import read_calibration

REAL = Path(__file__).resolve().parents[1] / "tests" / "data" / "panoptic" / "calibration_160906_band1.json"


def best_of(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    cameras, _ = read_calibration(REAL)
    cams = [cameras[n] for n in sorted(cameras)]
    cams.append(cams[0])  # 521 views, as in the dome (520 in the real file + 1)
    rotvec = np.array([cv2.Rodrigues(c.R)[0][:, 0] for c in cams])
    R = np.array([cv2.Rodrigues(r)[0] for r in rotvec])
    t = np.array([c.t_cm for c in cams])
    K = np.array([c.K for c in cams])
    dist = np.array([c.dist for c in cams])
    intr = K_to_intr(K)
    rng = np.random.default_rng(0)
    X = rng.normal([0.0, -120.0, 0.0], [60.0, 50.0, 60.0], (args.points, 3))  # a person-sized cloud at the centre
    C, N = len(cams), args.points

    def ours():
        return project(X, R, t, intr, dist).uv_px

    def opencv():
        return [cv2.projectPoints(X, rotvec[i], t[i], K[i], dist[i])[0] for i in range(C)]

    a, b = ours(), np.stack([u[:, 0] for u in opencv()])
    max_diff = float(np.abs(a - b).max())
    t_ours = best_of(ours, args.repeats)
    t_cv = best_of(opencv, args.repeats)
    n = C * N
    print(json.dumps({"bench": "camera.project", "cameras": C, "points": N, "projections": n,
                      "ours_s": round(t_ours, 5), "ours_points_per_s": round(n / t_ours),
                      "opencv_s": round(t_cv, 5), "opencv_points_per_s": round(n / t_cv),
                      "speed_ratio_ours_over_opencv": round(t_cv / t_ours, 3),
                      "max_abs_diff_px": max_diff}))


if __name__ == "__main__":
    main()
