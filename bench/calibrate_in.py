"""One calibration with the toolkit of a given checkout, timed: the child process of ``bench/dome.py --compare``.

    .venv/bin/python bench/calibrate_in.py TREE CAPTURE OUT [--prior BUNDLE --only-changed] [--seq SEQ]

TREE is a checkout of dome-calib (``git worktree add``): its toolkit is imported (TREE first on ``sys.path``; the
pool's worker processes, started with spawn, get the same path), so two checkouts calibrate the same capture in
the same way, one after the other, on the same machine. The work folder is ``OUT.work``, emptied first. Prints one
JSON object: the wall time, every stage's and the SfM's own seconds, the bundle adjustment's solves, cameras
calibrated, load averages before and after, peak memory. The bundle in OUT is judged by the parent (the same code
for both checkouts).

Only what every checkout has is used: ``run_calibration`` and ``CalibrateOptions`` (the flat house before issue 35
or the ``dome_calib.pipeline`` package after it).
"""
from __future__ import annotations

import json
import os
import resource
import shutil
import sys
import time
from pathlib import Path

if len(sys.argv) > 1 and Path(sys.argv[1]).is_dir():  # the tree first, for this process and its spawned workers
    sys.path.insert(0, str(Path(sys.argv[1]).resolve()))


def main() -> None:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tree", type=Path)
    parser.add_argument("capture", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--prior", type=Path)
    parser.add_argument("--only-changed", action="store_true")
    parser.add_argument("--seq")
    args = parser.parse_args()
    try:
        from dome_calib.pipeline.full import run_calibration
        from dome_calib.pipeline.types import CalibrateOptions
    except ImportError:  # the flat house
        from dome_calib.pipeline import CalibrateOptions, run_calibration
    import dome_calib

    work = args.out.with_name(args.out.name + ".work")
    shutil.rmtree(args.out, ignore_errors=True)
    shutil.rmtree(work, ignore_errors=True)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    result = run_calibration(args.capture, args.out, CalibrateOptions(
        prior=args.prior, only_changed=args.only_changed, seq=args.seq, work_dir=work))
    total = time.perf_counter() - t0
    stats = result.stats or {}
    sfm, ba = stats.get("sfm") or {}, stats.get("ba") or {}
    print(json.dumps({
        "toolkit": str(Path(dome_calib.__file__).resolve().parents[1]), "seconds_total": round(total, 2),
        "seconds": {k: round(v, 2) for k, v in result.stage_seconds.items()},
        "sfm_seconds": {k: round(v, 2) for k, v in (sfm.get("seconds") or {}).items()},
        "sfm_scenes": {s: {"mapping": v.get("mapping"), "pairs": v.get("pairs"), "points": v.get("points"),
                           "observations": v.get("observations"), "seconds": v.get("seconds")}
                       for s, v in (sfm.get("scenes") or {}).items()},
        "ba": {k: ba.get(k) for k in ("solves", "iterations_per_solve", "n_used", "n_rejected", "rms_px", "seconds")
               if k in ba},
        "quick_seconds": (stats.get("quick") or {}).get("seconds"),
        "changes": sorted(result.changes) if result.changes is not None else None,
        "calibrated": len(result.bundle.cameras), "expected": len(result.expected),
        "not_calibrated": sorted(result.failures),
        "load_average_1min": [round(load0[0], 2), round(os.getloadavg()[0], 2)],
        "peak_rss_gb": {"calibrate": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, 2),
                        "largest_worker": round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6, 2)},
    }), flush=True)


if __name__ == "__main__":
    main()
