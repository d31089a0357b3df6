"""The keypoint refinement's wall time by where its per-image tasks run, on a synthetic dome's merged observations.

    .venv/bin/python bench/refine_dispatch.py --preset panel                       # threads, serial, 2-process pool
    .venv/bin/python bench/refine_dispatch.py --preset panel --against /work/main   # + another checkout's refinement

The capture is synthesised once and its SfM run once with the refinement off (both kept in ``--work``); the merged
observations are then refined ``--repeat`` times per way, the ways interleaved (load drifts alike over all): in
this process's threads (``executor=None``: what ``calibrate`` does without ``--scheduler``), in series, and in a
2-process pool (the executor ``calibrate`` runs features and matching on; the patches then cross processes). ``--against DIR`` times DIR's ``projector.refine.refine_observations`` (threads: the
refinement before its work became per-image tasks) in a subprocess on the same observations, within the same
rounds. Prints one JSON object per line: per way the seconds of each round, their median, whether the refined
keypoints are the same bits as the first way's, and the load average.
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

# a checkout's refinement of the pickled observations, in its own process: prints seconds, writes the keypoints
_AGAINST = """
import pickle, sys, time
import numpy as np
from projector.refine import refine_observations
obs, capture, out = pickle.load(open(sys.argv[1], "rb")), sys.argv[2], sys.argv[3]
t0 = time.perf_counter()
refined, report = refine_observations(obs, lambda s: f"{capture}/scenes/{s}")
print(time.perf_counter() - t0)
np.save(out, refined.uv_px)
"""


def emit(**obj) -> None:
    print(json.dumps(obj), flush=True)


def merged_observations(capture: Path, work: Path, preset: str, scenes: int, seed: int):
    """The SfM's merged observations before refinement (synthesised and computed once, then read from ``work``)."""
    from dome_calib.synth.capture import SynthOptions, synthesize
    from projector.refine import RefineOptions
    from projector.sfm import SfmOptions, run_sfm

    kept = work / "merged.pkl"
    if kept.exists():
        return pickle.loads(kept.read_bytes())
    if not (capture / "capture.json").exists():
        synthesize(capture, SynthOptions(preset=preset, n_scenes=scenes, seed=seed, overwrite=True))
    obs = run_sfm(capture, work / "sfm", SfmOptions(refine=RefineOptions(enabled=False))).observations
    kept.write_bytes(pickle.dumps(obs))
    return obs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=["tiny", "panel", "full"], default="panel")
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--work", default="/tmp/refine_dispatch_bench")
    parser.add_argument("--against", type=Path, help="another checkout whose refinement is timed beside (threads)")
    args = parser.parse_args()

    from dome_calib.executor import SerialExecutor
    from dome_calib.executor.local import LocalProcessExecutor
    from projector.refine import refine_observations

    root = Path(args.work) / args.preset
    capture = root / "capture"
    obs = merged_observations(capture, root, args.preset, args.scenes, args.seed)
    emit(bench="refine_dispatch", stage="observations", preset=args.preset, scenes=len(obs.scene_points_cm),
         cameras=len(obs.camera_names), observations=obs.n_observations)

    def image_dir(s: str) -> Path:
        return capture / "scenes" / s

    pool = LocalProcessExecutor(2)
    list(pool.map(abs, range(8)))  # the workers started (calibrate's pool is running when the refinement starts)
    ways = {"threads": lambda: refine_observations(obs, image_dir),
            "serial": lambda: refine_observations(obs, image_dir, executor=SerialExecutor()),
            "pool_2": lambda: refine_observations(obs, image_dir, executor=pool)}
    if args.against:
        pkl = root / "merged.pkl"

        def against():
            out = root / "against_uv.npy"
            env = {**os.environ, "PYTHONPATH": str(args.against)}
            res = subprocess.run([sys.executable, "-c", _AGAINST, str(pkl), str(capture), str(out)], env=env,
                                 capture_output=True, text=True, check=True)
            return float(res.stdout.split()[-1]), np.load(out)

        ways["against"] = against
    seconds: dict[str, list[float]] = {w: [] for w in ways}
    first: np.ndarray | None = None
    same: dict[str, bool] = {}
    for _ in range(args.repeat):
        for way, run in ways.items():
            t0 = time.perf_counter()
            got = run()
            s, uv = (got[0], got[1]) if way == "against" else (time.perf_counter() - t0, got[0].uv_px)
            seconds[way].append(round(s, 2))
            first = uv if first is None else first
            same[way] = same.get(way, True) and bool(np.array_equal(uv, first))
            if way == "threads":
                moved, unreadable = got[1].moved, len(got[1].unreadable_images)
    pool.shutdown()
    for way, s in seconds.items():
        emit(bench="refine_dispatch", stage="refine", way=way, seconds=s, median_s=float(np.median(s)),
             same_bits_as_threads=same[way], **({"against": str(args.against)} if way == "against" else {}))
    emit(bench="refine_dispatch", stage="summary", moved=moved, unreadable_images=unreadable,
         pool_over_threads=round(float(np.median(seconds["pool_2"]) / np.median(seconds["threads"])), 3),
         **({"threads_over_against": round(float(np.median(seconds["threads"]) / np.median(seconds["against"])), 3),
             "pool_over_against": round(float(np.median(seconds["pool_2"]) / np.median(seconds["against"])), 3)}
            if args.against else {}), loadavg=os.getloadavg())


if __name__ == "__main__":
    main()
