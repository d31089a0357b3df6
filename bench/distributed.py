"""`dome-calib calibrate` with the local process pool, with a Dask LocalCluster of 2 single-threaded workers, and
with a `dask scheduler` + 2 separate `dask worker` processes on 127.0.0.1 holding half of the cameras each
(capture.json "nodes"): wall time per stage, per-task times, scheduler overhead per task, bytes moved, and a
scaling model of the full dome on 1, 4, 16 and 32 two-core nodes. One JSON object per line.

Scheduler overhead per task = (stage wall x worker slots - sum of task seconds) / tasks: the time a worker slot
spends not running a task (scheduling, transfer, the head writing results), per task.

Scaling model: T(n) = serial + (images x t_image + pairs x t_pair) / (2 n) + tasks x overhead / (2 n), with the
serial part = mapping + merge + bundle adjustment (on the head) and overhead the no-op round trip per task. The full dome's counts and serial times are the
README's measured `bench/sfm.py --full` / `bench/dome.py --preset full` figures (1,563 images, 22,500 pairs,
mapping 241 s, merge 7 s, BA 492 s); t_image and t_pair are per-task seconds measured on the full dome
(117 s x 2 workers / 1,563 images; 207 s x 2 / 22,500 pairs) and, beside them, those measured here.

    python bench/distributed.py [--preset tiny|panel] [--scenes 2] [--work DIR]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if Path(sys.path[0]).resolve() == Path(__file__).resolve().parent:
    sys.path.pop(0)  # this file is named distributed.py: the `distributed` package must not resolve to it

from dome_calib.synth.capture import split_onto_nodes  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
FULL = {"images": 1563, "pairs": 22500, "features_s_2cores": 117.0, "matching_s_2cores": 207.0,
        "mapping_s": 241.0, "merge_s": 7.0, "ba_s": 492.0}
ENV1 = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def loadavg() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def emit(obj: dict) -> None:
    print(json.dumps(obj), flush=True)


def calibrate(capture: Path, out: Path, scheduler: str | None) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(out.with_name(out.name + ".work"), ignore_errors=True)
    cmd = [sys.executable, "-c", "from dome_calib.cli import main; main()", "calibrate", str(capture), "-o", str(out)]
    if scheduler:
        cmd += ["--scheduler", scheduler]
    load0, t0 = loadavg(), time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"calibrate failed: {res.stderr.strip().splitlines()[-1]}")
    work = out.with_name(out.name + ".work")
    sfm = json.loads((work / "sfm" / "sfm_report.json").read_text())
    stages = {k: 0.0 for k in ("features", "matching", "mapping")}
    for sc in sfm["scenes"].values():
        for k in stages:
            stages[k] += sc["seconds"][k]
    m = re.search(r"stage times: (.*)", res.stdout)
    for part in (m.group(1).split(", ") if m else []):
        name, sec, _ = part.split(" ")
        stages[name] = float(sec)
    cluster = json.loads((work / "cluster.json").read_text()) if (work / "cluster.json").exists() else {}
    pairs = sum(sc["pairs"] for sc in sfm["scenes"].values())
    return {"wall_s": round(wall, 1), "stages_s": {k: round(v, 1) for k, v in stages.items()}, "pairs": pairs,
            "cluster": cluster.get("stages", {}), "load_before": load0, "load_after": loadavg()}


def start_cluster(base: Path, folders: dict[str, Path]) -> tuple[str, list[subprocess.Popen]]:
    sched_file = base / "scheduler.json"
    sched_file.unlink(missing_ok=True)
    procs = [subprocess.Popen([BIN / "dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", sched_file], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True, env=ENV1)]
    while not sched_file.exists():
        time.sleep(0.1)
    address = json.loads(sched_file.read_text())["address"]
    for node, folder in folders.items():
        procs.append(subprocess.Popen([BIN / "dask", "worker", address, "--name", node, "--nthreads", "1", "--host",
                                       "127.0.0.1", "--no-dashboard", "--local-directory", base / f"{node}.dask"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                                      env={**ENV1, "DOME_CALIB_CAPTURE_ROOT": str(folder)}))
    return address, procs


def noop(x: int) -> int:
    return x


def round_trip_overhead(address: str, tasks: int = 400) -> float:
    """Seconds of a worker slot per no-op task through the executor (the scheduler's own cost per task)."""
    from dome_calib.executor.dask import DaskExecutor

    with DaskExecutor(address) as ex:
        slots = sum(ex.client.nthreads().values())
        t0 = time.perf_counter()
        assert len(list(ex.map(noop, range(tasks)))) == tasks
        return (time.perf_counter() - t0) * slots / tasks


def per_task(run: dict, slots: int) -> dict:
    out = {}
    for fn, s in run["cluster"].items():
        n = max(s["tasks"], 1)
        out[fn] = {"tasks": s["tasks"], "workers": s["workers"], "task_s_mean": round(s["task_s"] / n, 4),
                   "overhead_s_per_task": round((s["wall_s"] * slots - s["task_s"]) / n, 4),
                   "mb_moved": round((s["bytes_out"] + s["bytes_back"]) / 1e6, 2)}
    return out


def scaling(t_image: float, t_pair: float, overhead_s: float, tasks: float) -> list[dict]:
    serial = FULL["mapping_s"] + FULL["merge_s"] + FULL["ba_s"]
    rows = []
    for nodes in (1, 4, 16, 32):
        cores = 2 * nodes
        front = (FULL["images"] * t_image + FULL["pairs"] * t_pair + tasks * overhead_s) / cores
        rows.append({"nodes": nodes, "front_end_s": round(front, 1), "serial_s": serial,
                     "total_min": round((front + serial) / 60, 1)})
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="tiny", choices=["tiny", "panel"])
    ap.add_argument("--scenes", type=int, default=2)
    ap.add_argument("--work", type=Path)
    args = ap.parse_args(argv)
    base = args.work or Path(tempfile.mkdtemp(prefix="dome_dask_"))
    base.mkdir(parents=True, exist_ok=True)
    capture = base / "capture"
    if not (capture / "capture.json").exists():
        subprocess.run([sys.executable, "-c", "from dome_calib.cli import main; main()", "synth", str(capture),
                        "--preset", args.preset, "--scenes", str(args.scenes), "--overwrite"], check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL)
    runs = {}
    runs["local_pool"] = calibrate(capture, base / "out_local", None)
    emit({"bench": "distributed", "run": "local_pool", "preset": args.preset, **runs["local_pool"]})

    from distributed import LocalCluster

    os.environ.update({k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", scheduler_port=0,
                      dashboard_address=None) as lc:
        runs["local_cluster"] = calibrate(capture, base / "out_lc", lc.scheduler_address)
    emit({"bench": "distributed", "run": "local_cluster_2x1", "preset": args.preset, **runs["local_cluster"],
          "per_task": per_task(runs["local_cluster"], 2)})

    head, folders = split_onto_nodes(capture, base, ("nodeA", "nodeB"))
    address, procs = start_cluster(base, folders)
    try:
        runs["workers"] = calibrate(head, base / "out_workers", address)
        noop_overhead = round_trip_overhead(address)
    finally:
        for p in reversed(procs):
            try:
                os.killpg(p.pid, 9)
            except ProcessLookupError:
                pass
            p.wait()
    emit({"bench": "distributed", "run": "two_worker_processes_nodes", "preset": args.preset, **runs["workers"],
          "per_task": per_task(runs["workers"], 2), "noop_task_overhead_s": round(noop_overhead, 4)})

    local = runs["local_pool"]["stages_s"]
    for name in ("local_cluster", "workers"):
        st = runs[name]["stages_s"]
        fm_local, fm = local["features"] + local["matching"], st["features"] + st["matching"]
        emit({"bench": "distributed", "compare": f"{name}_vs_local_pool",
              "features_matching_ratio": round(fm / fm_local, 3),
              "total_ratio": round(runs[name]["wall_s"] / runs["local_pool"]["wall_s"], 3), "aim": "<= 1.10"})

    pt = per_task(runs["workers"], 2)
    feat, match = pt.get("extract_image", {}), pt.get("match_batch", {})
    pairs_per_task = runs["workers"]["pairs"] / max(match.get("tasks", 1), 1)
    overhead = noop_overhead  # the scheduler's cost per task; idle time of a busy run is in per_task above
    tasks_full = FULL["images"] + FULL["pairs"] / 40
    t_image_full = FULL["features_s_2cores"] * 2 / FULL["images"]
    t_pair_full = FULL["matching_s_2cores"] * 2 / FULL["pairs"]
    emit({"bench": "distributed", "model": "full dome, per-task times of the full dome", "t_image_s": round(t_image_full, 4),
          "t_pair_s": round(t_pair_full, 4), "overhead_s_per_task": round(overhead, 4),
          "serial": "mapping 241 s + merge 7 s + bundle adjustment 492 s (head)",
          "rows": scaling(t_image_full, t_pair_full, overhead, tasks_full)})
    t_image_here = feat.get("task_s_mean", 0.0)
    t_pair_here = match.get("task_s_mean", 0.0) / max(pairs_per_task, 1)
    emit({"bench": "distributed", "model": f"full dome, per-task times measured here ({args.preset})",
          "t_image_s": round(t_image_here, 4), "t_pair_s": round(t_pair_here, 4),
          "rows": scaling(t_image_here, t_pair_here, overhead, tasks_full)})


if __name__ == "__main__":
    main()
