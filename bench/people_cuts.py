"""Does any result of `reconstruct` depend on how the work was cut? A long session of the synthetic group ("mixed":
walking past, talking, crouching, leaving, entering; dome_calib.synth.detector's failures) seen by the panel setup
(panels 1-2: 48 VGA, 8 HD, 4 Kinect colour), reconstructed once over everything and again cut other ways: the
default chunks of 600 times (issue 42's case: 637 times, two chunks), chunks of 100 on a 2-process pool, batches
of 5 times; the body over time on (the default: windows of the session's own time index, 4 of them here). Each cut
is compared with the whole run, body by body and joint by joint.

Run: .venv/bin/python bench/people_cuts.py [--times 637] [--people 7] [--seed 0]
Prints one JSON object per line: the machine, then per run its speed (ms per time, wall and process time of this
process), then per cut against the whole run:

- ids_equal: every time holds the same ids; bodies_only_in_one: (time, id) present in one run only;
- max_joint_diff_cm, joints_over_1cm, joints_over_1e-3cm: over the joints both runs reconstructed, bodies paired by
  id; joints_in_one_only: joints one run reconstructed and the other did not; max_c_diff: of the joints' c;
- camera_tallies_equal: cameras.json's counts (detections, used, error histogram, the body over time's judged and
  outvoted detections, the noise histogram) equal.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small batched solves: threads only contend
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from dome_calib.executor.local import LocalProcessExecutor  # noqa: E402
from dome_calib.recon.people.chunks import reconstruct_people_chunked  # noqa: E402
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people  # noqa: E402
from dome_calib.recon.people.sources import people_streams  # noqa: E402
from dome_calib.recon.project import view_set  # noqa: E402
from dome_calib.synth.detector import DetectorModel, synth_detections  # noqa: E402
from dome_calib.synth.dome import as_built_dome  # noqa: E402
from dome_calib.synth.group import GroupOptions, make_group  # noqa: E402
from dome_calib.synth.skeleton import synthetic_sync  # noqa: E402

START_MS = 500.0
VGA_FPS = 25.0


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def compare(whole, other) -> dict:
    """The cut ``other`` against ``whole`` (see the module docstring)."""
    ids_equal, only_one, diffs, one_sided, dc = True, 0, [], 0, 0.0
    for a, b in zip(whole.bodies, other.bodies):
        ia, ib = set(a.ids.tolist()), set(b.ids.tolist())
        ids_equal &= ia == ib
        only_one += len(ia ^ ib)
        for i in ia & ib:
            Xa, Xb = a.X_cm[a.ids == i][0], b.X_cm[b.ids == i][0]
            both = np.isfinite(Xa).all(1) & np.isfinite(Xb).all(1)
            one_sided += int((np.isfinite(Xa).all(1) != np.isfinite(Xb).all(1)).sum())
            diffs.append(np.linalg.norm(Xa[both] - Xb[both], axis=1))
            dc = max(dc, float(np.abs(a.confidence[a.ids == i][0] - b.confidence[b.ids == i][0]).max()))
    d = np.concatenate(diffs) if diffs else np.zeros(0)
    tallies = all(np.array_equal(getattr(whole.cameras, f), getattr(other.cameras, f))
                  for f in ("detected", "used", "hist", "judged", "outvoted", "noise"))
    return {"ids_equal": bool(ids_equal), "bodies_only_in_one": only_one,
            "max_joint_diff_cm": round(float(d.max(initial=0.0)), 6), "joints_over_1cm": int((d > 1.0).sum()),
            "joints_over_1e-3cm": int((d > 1e-3).sum()), "joints_in_one_only": one_sided,
            "joints_compared": int(len(d)), "max_c_diff": round(dc, 8), "camera_tallies_equal": bool(tallies)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--times", type=int, default=637, help="reference (VGA) times of the session")
    ap.add_argument("--people", type=int, default=7)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    emit(bench="people_cuts", cpus=os.cpu_count(), load_average_1min=round(os.getloadavg()[0], 1))
    duration_ms = args.times * 1000.0 / VGA_FPS
    bundle = as_built_dome("panel", seed=args.seed)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=duration_ms + 2 * START_MS, seed=args.seed)
    cams = sorted(n for n, c in bundle.cameras.items() if c.type in ("vga", "hd", "kinect-color"))
    truth = make_group(GroupOptions(n_people=args.people, duration_ms=duration_ms + 200.0, start_ms=START_MS - 100.0,
                                    seed=args.seed))
    det = synth_detections(bundle, truth, cameras=cams, univ_time_ms=(START_MS - 200, START_MS + duration_ms + 200),
                           model=DetectorModel(seed=args.seed))
    streams = people_streams(bundle, det)
    vga = bundle.sync.streams["vga"]
    times = vga.univ_time_ms[vga.univ_time_ms >= START_MS][: args.times]
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    runs = {}

    def timed(name, fn):
        wall, cpu = time.perf_counter(), time.process_time()
        runs[name] = fn()
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        people = len({int(i) for b in runs[name].bodies for i in b.ids})
        emit(run=name, times=len(times), views=len(views.names), people=people,
             ms_per_time_wall=round(1000 * wall / len(times), 1), ms_per_time_cpu=round(1000 * cpu / len(times), 1))

    timed("whole", lambda: reconstruct_people(views, streams, times, PeopleOptions(chunk_times=10**9)))
    timed("chunks_600", lambda: reconstruct_people_chunked(views, streams, times, PeopleOptions()))
    with LocalProcessExecutor(2) as pool:
        timed("chunks_100_pool_2", lambda: reconstruct_people_chunked(views, streams, times,
                                                                       PeopleOptions(chunk_times=100), executor=pool))
    timed("batches_5", lambda: reconstruct_people(views, streams, times, PeopleOptions(batch_times=5)))
    for name, seq in runs.items():
        if name != "whole":
            emit(cut=name, against="whole", **compare(runs["whole"], seq))


if __name__ == "__main__":
    main()
