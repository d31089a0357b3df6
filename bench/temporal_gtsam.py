"""Why the body over time does not use gtsam's factor graphs: one time step's reprojection factors built and solved
in gtsam from Python (31 cameras x 8 people x 19 joints = 4,712 robust ``TriangulationFactorCal3DS2``, Huber,
Point3 unknowns, Levenberg-Marquardt 4 iterations), against the 33 ms a step has at the speed aim of 30 steps/s.
Our stage (dome_calib.recon.people.temporal, the same data terms plus bones and motion over every time of a chunk)
is timed by bench/multiperson.py.

Run: .venv/bin/python bench/temporal_gtsam.py   (one JSON line)
"""
from __future__ import annotations

import json
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import gtsam  # noqa: E402
import numpy as np  # noqa: E402


def main() -> None:
    rng = np.random.default_rng(0)
    V, P, J = 31, 8, 19
    cams = []
    for v in range(V):
        a = 2 * np.pi * v / V
        c = np.array([400 * np.cos(a), 400 * np.sin(a), 150.0])
        z = -c / np.linalg.norm(c)
        x = np.cross([0, 0, 1.0], z)
        x /= np.linalg.norm(x)
        pose = gtsam.Pose3(gtsam.Rot3(np.stack([x, np.cross(z, x), z], 1)), c)
        cams.append(gtsam.PinholeCameraCal3DS2(pose, gtsam.Cal3DS2(1400, 1400, 0, 960, 540, -0.1, 0.02, 0, 0)))
    X = rng.normal(size=(P * J, 3)) * 50
    uv = [[cams[v].project(X[k]) + rng.normal(size=2) for v in range(V)] for k in range(P * J)]
    noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(3.0),
                                           gtsam.noiseModel.Isotropic.Sigma(2, 3.0))
    t0 = time.perf_counter()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k in range(P * J):
        values.insert(k, X[k] + rng.normal(size=3))
        for v in range(V):
            graph.add(gtsam.TriangulationFactorCal3DS2(cams[v], uv[k][v], noise, k))
    t1 = time.perf_counter()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(4)
    gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    t2 = time.perf_counter()
    print(json.dumps({"bench": "temporal_gtsam", "load_average_1min": round(os.getloadavg()[0], 1),
                      "factors_per_step": int(graph.size()), "build_ms_per_step": round(1000 * (t1 - t0), 1),
                      "solve_ms_per_step": round(1000 * (t2 - t1), 1), "budget_ms_per_step_at_30_per_s": 33.3}))


if __name__ == "__main__":
    main()
