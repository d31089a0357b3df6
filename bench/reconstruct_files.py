"""`dome-calib reconstruct` on a folder of 100,000 OpenPose files: this checkout against an older one, same run.

Run: .venv/bin/python bench/reconstruct_files.py --old /path/to/older/checkout [--files 100000] [--people 2]

Issue 42 asks that reading every detection through its declared schema (``dome_calib.recon.openpose_io``) leave
``reconstruct`` on 100,000 files no slower than before. This bench writes one synthetic group session (the 31 HD
cameras of the synthetic dome, ``--people`` people of the "mixed" scenario, the default detector model) long enough
for ``--files`` OpenPose files, writes the bundle beside it, and runs the command line of each checkout on it in a
child process (``PYTHONPATH`` = the checkout), one after the other and ``--repeat`` times, alternating which goes
first: the older checkout, this one as a user runs it (the body over time on), and this one with ``--per-frame``
(the same per-frame work as the older one: the reading and the per-frame stages compared alone).

Prints one JSON object per line: the setup (files, cameras, times, load), each run (wall and CPU seconds of the child,
bodies written), and the ratios new / old of the medians.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def write_session(work: Path, n_files: int, n_people: int, seed: int) -> tuple[Path, Path, int, int]:
    """The bundle and the detections folder (reused when present): (bundle, detections, cameras, files)."""
    from dome_calib.bundle_io import write_bundle
    from dome_calib.synth.dome import as_built_dome
    from dome_calib.synth.detector_model import DetectorModel
    from dome_calib.synth.group import GroupOptions
    from dome_calib.synth.group_session import GroupSessionOptions, make_group_session
    from dome_calib.synth.skeleton import synthetic_sync

    bundle_dir, session = work / "bundle", work / "session"
    detections = session / "detections"
    if (work / "done.json").exists():
        done = json.loads((work / "done.json").read_text())
        return bundle_dir, detections, done["cameras"], done["files"]
    shutil.rmtree(work, ignore_errors=True)
    bundle = as_built_dome("full", seed=seed)
    cams = sorted(n for n, c in bundle.cameras.items() if c.type == "hd")
    hd_fps = 30000 / 1001
    duration_ms = n_files / len(cams) / hd_fps * 1000.0
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=duration_ms + 1000.0, seed=seed)
    write_bundle(bundle, bundle_dir)
    # no confidence above 1 (real OpenPose writes a few): the older checkout refused them, and both must read the files
    make_group_session(session, bundle, GroupSessionOptions(
        group=GroupOptions(n_people=n_people, start_ms=500.0, duration_ms=duration_ms, seed=seed), cameras=cams,
        detector=DetectorModel(conf_above_1=0.0)))
    files = sum(1 for _ in detections.rglob("*.json"))
    (work / "done.json").write_text(json.dumps({"cameras": len(cams), "files": files}))
    return bundle_dir, detections, len(cams), files


def run_cli(tree: Path, detections: Path, bundle: Path, out: Path, *extra: str) -> dict:
    """`dome-calib reconstruct` of checkout ``tree`` in a child process: wall and CPU seconds, bodies written."""
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    cmd = [sys.executable, "-c", "import sys; from dome_calib.cli import main; sys.argv[0] = 'dome-calib'; main()",
           "reconstruct", str(detections), "--bundle", str(bundle), "--body-model", "BODY_25", "-o", str(out), *extra]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tree)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{tree}: reconstruct failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    bodies = sum(len(json.loads(p.read_text()).get("bodies", [])) for p in out.glob("*.json")
                 if p.name.startswith("body3DScene"))
    return {"seconds": round(wall, 2),
            "cpu_seconds": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 2),
            "body_frames": bodies, "load_average_1min": round(os.getloadavg()[0], 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, required=True, help="an older checkout (git worktree add --detach DIR REV)")
    ap.add_argument("--files", type=int, default=100_000)
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--work", type=Path, default=Path("/tmp/dome_reconstruct_files"))
    args = ap.parse_args()
    t0 = time.perf_counter()
    bundle, detections, n_cams, n_files = write_session(args.work, args.files, args.people, args.seed)
    emit(bench="reconstruct_files", stage="setup", files=n_files, cameras=n_cams, people=args.people,
         seconds=round(time.perf_counter() - t0, 1), old=str(args.old.resolve()), new=str(ROOT))
    runs = {"old": (args.old.resolve(), ()), "new": (ROOT, ()), "new_per_frame": (ROOT, ("--per-frame",))}
    results: dict[str, list[dict]] = {k: [] for k in runs}
    for k in range(args.repeat):
        order = list(runs) if k % 2 == 0 else list(reversed(runs))
        for which in order:
            tree, extra = runs[which]
            rec = run_cli(tree, detections, bundle, args.work / f"out_{which}", *extra)
            results[which].append(rec)
            emit(bench="reconstruct_files", stage="run", run=which, repeat=k, files=n_files, **rec)
    med = {w: {f: float(np.median([r[f] for r in rs])) for f in ("seconds", "cpu_seconds")}
           for w, rs in results.items()}
    emit(bench="reconstruct_files", stage="ratios", files=n_files, repeat=args.repeat,
         medians=med, per_frame_over_old={f: round(med["new_per_frame"][f] / med["old"][f], 3) for f in med["old"]},
         default_over_old={f: round(med["new"][f] / med["old"][f], 3) for f in med["old"]},
         files_per_cpu_second={w: round(n_files / m["cpu_seconds"], 1) for w, m in med.items()})


if __name__ == "__main__":
    main()
