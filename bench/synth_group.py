"""Synthetic-group bench: cost of the body volume (occlusion) and of the OpenPose-like detector per frame time,
and the failure rates the detector showed against the rates it was set to.

Run: .venv/bin/python bench/synth_group.py [--seconds 1] [--people 8] [--seed 0] [--setups panel,full]
Prints one JSON object per line:
Wall and CPU (this process) times: the machine may be shared.
- ``occlusion``: ms per frame time of :func:`dome_calib.synth.body_volume.occluded_joints` for every view of the
  setup at once (panel: 48 VGA + 8 HD + 4 Kinect colour = 60 views; full: 521), and the share of joints hidden;
- ``detector``: wall time of :func:`dome_calib.synth.detector.synth_detections` on every colour camera at its own
  stream's frames over ``--seconds``, per frame time (VGA, HD and each Kinect's frames are separate times) and per
  image, with the observed rates next to the model's.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from dome_calib.recon.project import view_set  # noqa: E402
from dome_calib.synth.body_volume import occluded_joints  # noqa: E402
from dome_calib.synth.detector import DetectionCounts, DetectorModel, synth_detections  # noqa: E402
from dome_calib.synth.dome import as_built_dome  # noqa: E402
from dome_calib.synth.group import GroupOptions, make_group  # noqa: E402
from dome_calib.synth.skeleton import synthetic_sync  # noqa: E402

START_MS = 500.0


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def run(setup: str, n_people: int, seconds: float, seed: int) -> None:
    bundle = as_built_dome(setup, seed=seed)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=seconds * 1000.0 + 2 * START_MS, seed=seed)
    cams = sorted(n for n, c in bundle.cameras.items() if c.type in ("vga", "hd", "kinect-color"))
    truth = make_group(GroupOptions(n_people=n_people, start_ms=START_MS, duration_ms=max(seconds, 4.0) * 1000.0,
                                    seed=seed))
    centres = view_set(bundle, cams).center_cm
    times = START_MS + np.linspace(0.0, seconds * 1000.0, 12)
    X, present = truth.joints_cm(times)
    occluded_joints(centres, X[0], present[0])  # warm-up
    wall, cpu = time.perf_counter(), time.process_time()
    hidden = [occluded_joints(centres, X[k], present[k]) for k in range(len(times))]
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    share = float(np.mean([h[:, p].mean() for h, p in zip(hidden, present)]))
    emit(what="occlusion", setup=setup, views=len(cams), people=n_people, present=int(present.sum(1).max()),
         ms_per_frame_time=round(1000.0 * wall / len(times), 1),
         cpu_ms_per_frame_time=round(1000.0 * cpu / len(times), 1), hidden_share=round(share, 3))
    model = DetectorModel(seed=seed)
    counts = DetectionCounts()
    span = (START_MS, START_MS + seconds * 1000.0)
    wall, cpu = time.perf_counter(), time.process_time()
    det = synth_detections(bundle, truth, cameras=cams, univ_time_ms=span, model=model, counts=counts)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    frame_times = sum(int(np.sum((t.univ_time_ms >= span[0]) & (t.univ_time_ms <= span[1])))
                      for t in [*bundle.sync.streams.values(), *bundle.sync.kinect_color.values()])
    rates = {k: round(v, 4) for k, v in counts.rates().items()}
    expected = {"miss_visible": model.miss_base, "miss_hidden": model.miss_occluded,
                "swap_whole": model.swap_lr, "swap_limb": model.swap_limb, "neighbour_limb": model.neighbour_limb,
                "zero_coordinate": model.zero_coordinate, "confidence_above_1": model.conf_above_1,
                "false_people_per_view (drawn; fewer are reported)": model.false_people_per_view}
    emit(what="detector", setup=setup, views=len(cams), people=n_people, seconds=seconds, images=counts.images,
         frame_times=frame_times, wall_s=round(wall, 2), cpu_s=round(cpu, 2),
         cpu_ms_per_frame_time=round(1000.0 * cpu / frame_times, 1),
         cpu_ms_per_image=round(1000.0 * cpu / counts.images, 3),
         detections=int(sum(len(d) for c in det.values() for d in c.values())), observed=rates, set=expected)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--people", type=str, default="8")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--setups", type=str, default="panel,full")
    args = ap.parse_args()
    for setup in args.setups.split(","):
        for n in (int(x) for x in args.people.split(",")):
            run(setup, n, args.seconds, args.seed)


if __name__ == "__main__":
    main()
