"""Start-up of `dome-calib calibrate`: the seconds from the process start to its first stage, and of `--help`, for
two source trees run back to back (the one before the input schemas, and this one).

Run: .venv/bin/python bench/startup.py --old /path/to/old/checkout [--new .] [--repeats 7]
(an old checkout: ``git archive 2a6a476 | tar -x -C /tmp/old``, then ``--old /tmp/old --old-label 2a6a476``)

Makes a tiny synthetic capture once (`dome-calib synth --preset tiny --scenes 3`, 48 images), then alternates
old and new, each in a fresh Python process with that tree on PYTHONPATH: ``calibrate CAPTURE -o OUT --prior
GROUND_TRUTH`` stopped where its first stage would start (``run_full`` replaced by a clock), so the figure holds
every check made before the work (capture.json and every image name, the same-picture check, the prior and the
output places, the work folder's fingerprint) and the imports; and ``dome-calib --help``. Prints one JSON object
per line: setup (machine, load, commits), one line per run, and the medians with the ratio new / old.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Run inside the measured process: the clock stops where calibrate's first stage would start.
PROBE = """
import json, os, sys, time
import dome_calib.pipeline.full as full

def first_stage(inputs, state):
    print(json.dumps({"to_first_stage_s": time.time() - float(os.environ["BENCH_T0"])}), flush=True)
    os._exit(0)

full.run_full = first_stage
from dome_calib.cli import main
sys.argv = ["dome-calib", *sys.argv[1:]]
main()
"""


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def commit(tree: Path) -> str:
    run = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return run.stdout.strip() or "?"


def to_first_stage(tree: Path, capture: Path, work: Path) -> float:
    out = work / "out"
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(work / "out.work", ignore_errors=True)
    env = {**os.environ, "PYTHONPATH": str(tree), "BENCH_T0": repr(time.time())}
    run = subprocess.run([sys.executable, "-c", PROBE, "calibrate", str(capture), "-o", str(out), "--prior",
                          str(capture / "ground_truth")], capture_output=True, text=True, env=env, cwd=work)
    lines = [ln for ln in run.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        raise SystemExit(f"{tree}: calibrate did not reach its first stage:\n{run.stderr}")
    return json.loads(lines[-1])["to_first_stage_s"]


def help_seconds(tree: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", "from dome_calib.cli import main; main()", "--help"],
                         capture_output=True, text=True, env=env)
    if run.returncode != 0:
        raise SystemExit(f"{tree}: --help failed:\n{run.stderr}")
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", type=Path, required=True, help="checkout before the input schemas")
    parser.add_argument("--new", type=Path, default=ROOT)
    parser.add_argument("--old-label", default=None, help="its commit, when the checkout is no git tree")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    trees = {"old": args.old.resolve(), "new": args.new.resolve()}
    emit(bench="startup", machine=platform.machine(), cpus=os.cpu_count(), load=os.getloadavg()[0],
         old=args.old_label or commit(trees["old"]), new=commit(trees["new"]), repeats=args.repeats)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        capture = work / "capture"
        made = subprocess.run([sys.executable, "-c", "from dome_calib.cli import main; main()", "synth", str(capture),
                               "--preset", "tiny", "--scenes", "3"], capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(trees["new"])})
        if made.returncode != 0:
            raise SystemExit(made.stderr)
        n_images = sum(1 for _ in (capture / "scenes").rglob("*.png"))
        times: dict[str, dict[str, list[float]]] = {k: {"to_first_stage_s": [], "help_s": []} for k in trees}
        for i in range(args.repeats):
            for name, tree in (trees.items() if i % 2 == 0 else reversed(trees.items())):  # back to back, both orders
                t_stage, t_help = to_first_stage(tree, capture, work), help_seconds(tree)
                times[name]["to_first_stage_s"].append(t_stage)
                times[name]["help_s"].append(t_help)
                emit(run=i, tree=name, images=n_images, to_first_stage_s=round(t_stage, 3), help_s=round(t_help, 3))
    for what in ("to_first_stage_s", "help_s"):
        old, new = (statistics.median(times[k][what]) for k in ("old", "new"))
        emit(summary=what, old_median=round(old, 3), new_median=round(new, 3), ratio_new_over_old=round(new / old, 3),
             load=os.getloadavg()[0])


if __name__ == "__main__":
    main()
