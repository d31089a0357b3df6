"""Minor page faults and CPU seconds per call, in 4 kB pages only (numpy's huge-page advice off, so the counts do
not depend on the machine's free memory), of the bundle adjustment's per-iteration parts that used to map fresh
memory on every call: the residuals-and-Jacobians evaluation at the full dome's observation count (1,000,000, into
kept buffers, 2 threads), the residuals alone, and the inner constraints' rank-7 term added to a full-dome-sized
reduced system (7,800 unknowns). Four calls each; the first touches the kept buffers.

    PYTHONPATH=TREE .venv/bin/python bench/ba_faults.py     # TREE: the checkout to measure (an older one too)
"""
from __future__ import annotations

import json
import resource
import time
from pathlib import Path

import numpy as np
from numpy._core.multiarray import _set_madvise_hugepage


def faults() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def main() -> None:
    _set_madvise_hugepage(False)  # this process only: every fault one 4 kB page
    from dome_calib.ba import schur
    from dome_calib.ba.evaluate import residuals, residuals_and_jacobians
    from dome_calib.panoptic_io import read_calibration
    from dome_calib.synth.ba_problem import SyntheticOptions, make_problem

    cams, _ = read_calibration(Path(__file__).resolve().parents[1] / "tests/data/panoptic/calibration_160906_band1.json")
    names = sorted(cams)[::10]
    p = make_problem([cams[n] for n in names], SyntheticOptions(n_points=2000, target_observations=20000, seed=1)).start
    M = 1_000_000
    rep = np.tile(np.arange(p.n_observations), M // p.n_observations + 1)[:M]
    args = (p.camera_params, p.points_cm, p.camera_index[rep], p.point_index[rep], p.uv_px[rep])
    out = (np.zeros((2, M)), np.zeros((2, 15, M)), np.zeros((2, 3, M)))
    per: dict[str, list[int]] = {}
    cpu: dict[str, list[float]] = {}

    def timed(name, fn) -> None:
        f, c = faults(), time.process_time()
        fn()
        per.setdefault(name, []).append(faults() - f)
        cpu.setdefault(name, []).append(time.process_time() - c)

    n = 7800
    S = np.zeros((n, n))
    B = np.random.default_rng(0).normal(size=(n, 7))
    st = schur.build_structure(p.camera_index, p.point_index, np.ones(p.n_observations, bool), p.free, p.n_points)

    def gauge_term() -> None:
        if hasattr(schur, "add_outer_rows"):
            schur.add_outer_rows(S, B, st)
        else:  # an older tree: the former expression of build_reduced_system
            for i in range(0, n, 1024):
                S[i:i + 1024] += B[i:i + 1024] @ B.T

    for _ in range(4):
        timed("jacobians", lambda: residuals_and_jacobians(*args, n_threads=2, out=out))
        timed("residuals", lambda: residuals(*args, n_threads=2))
    for _ in range(4):
        timed("gauge_term", gauge_term)
    print(json.dumps({"bench": "ba_faults", "tree": str(Path(__import__("dome_calib").__file__).parents[1]),
                      "faults_per_call": per,
                      "cpu_s_per_call": {k: [round(x, 2) for x in v] for k, v in cpu.items()}}))


if __name__ == "__main__":
    main()
