"""Few-camera bench: the rig most users have (dome_calib.synth.rig: 5 HD cameras round a 3 x 3 m area, one sync
stream at 29.97 fps), groups of 3 and 4 people close together (scenario "small_area": a conversation, one walking
round it, one crouching; people cut by image borders), the OpenPose-like detector with errors that last
(dome_calib.synth.detector: episodes, correlated noise and bias fitted to real OpenPose output), fixed seeds;
reconstructed per frame, with the body over time (the default) and by the oracle (the same per-frame
triangulation of perfectly associated detections).

Run: .venv/bin/python bench/fewcam.py [--people 3,4] [--seconds 8] [--seeds 1,2]
Prints one JSON object per line: per (people, seed) and method the MPJPE (cm, over the joints each method put out,
and over those both per-frame and temporal put out), PCP (Shelf-style limbs, alpha 0.5; a missing body or joint is
a wrong limb; over the (time, person) seen by >= 2 views), the share of true joints put out, ids, and for the body
over time what its confidence means: per bin of c, the share of joints within 5 and 10 cm of the truth; then the
aims (temporal >= 25 % lower MPJPE than per frame, PCP >= 98 %) and the time per step of each method.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from dome_calib.recon.people.run import PeopleOptions, reconstruct_people  # noqa: E402
from dome_calib.recon.people.sources import people_streams  # noqa: E402
from dome_calib.recon.people.temporal import TemporalOptions  # noqa: E402
from dome_calib.recon.project import view_set  # noqa: E402
from dome_calib.synth.detector import DetectorModel, synth_detections  # noqa: E402
from dome_calib.synth.rig import GROUP_MARGIN_MS, RigOptions, few_camera_rig, rig_group  # noqa: E402
from dome_calib.synth.group_eval import match_bodies, oracle, pcp  # noqa: E402

C_BINS = (0.0, 0.5, 0.8, 0.95, 0.99, 1.0001)


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def matched(seq, X, present):
    """Our bodies matched to the true people: joints (T, P, 19, 3) and their c (T, P, 19) (NaN: none)."""
    ids, ours, _ = match_bodies([b.ids for b in seq.bodies], [b.X_cm for b in seq.bodies], X, present)
    conf = np.full(ours.shape[:3], np.nan)
    for t, b in enumerate(seq.bodies):
        for p in np.flatnonzero(ids[t] >= 0):
            conf[t, p] = b.confidence[int(np.flatnonzero(b.ids == ids[t, p])[0])]
    return ours, conf, ids


def calibration(ours, conf, X) -> list[dict]:
    err = np.linalg.norm(ours - X, axis=-1)
    out = []
    for lo, hi in zip(C_BINS, C_BINS[1:]):
        k = np.isfinite(err) & (conf >= lo) & (conf < hi)
        out.append({"c": [lo, min(hi, 1.0)], "joints": int(k.sum()),
                    "within_5cm": round(float((err[k] < 5).mean()), 4) if k.any() else None,
                    "within_10cm": round(float((err[k] < 10).mean()), 4) if k.any() else None})
    return out


def run(n_people: int, seconds: float, seed: int) -> list[dict]:
    bundle = few_camera_rig(RigOptions(seed=seed, duration_ms=1000.0 * seconds + GROUP_MARGIN_MS + 100.0))
    truth = rig_group(bundle, n_people=n_people, seed=seed)
    det = synth_detections(bundle, truth, model=DetectorModel(seed=seed))
    streams = people_streams(bundle, det)
    table = bundle.sync.streams["hd"]
    span = (table.univ_time_ms >= truth.start_ms) & (table.univ_time_ms <= truth.start_ms + truth.duration_ms)
    times = table.univ_time_ms[span]
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    X, present = truth.joints_cm(times)
    base = PeopleOptions()
    results, rows = {}, []
    reconstruct_people(views, streams, times[:3], base)  # warm-up: compiled loops loaded, pairs ranked
    for mode, temporal in (("per_frame", TemporalOptions(enabled=False)), ("temporal", TemporalOptions())):
        wall, cpu = time.perf_counter(), time.process_time()
        seq = reconstruct_people(views, streams, times, dataclasses.replace(base, temporal=temporal))
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        results[mode] = matched(seq, X, present) + (1000 * wall / len(times), 1000 * cpu / len(times))
    oracle_X, seen = oracle(views, streams, times, X, present, base)
    results["oracle"] = (oracle_X, None, None, None, None)
    mask = present & (seen >= 2)
    both = np.isfinite(results["per_frame"][0]).all(-1) & np.isfinite(results["temporal"][0]).all(-1)
    for mode, (ours, conf, ids, ms_wall, ms_cpu) in results.items():
        err = np.linalg.norm(ours - X, axis=-1)
        row = {"people": n_people, "seed": seed, "views": len(views.names), "times": len(times), "method": mode,
               "mpjpe_cm": round(float(np.nanmean(err[mask])), 3),
               "mpjpe_common_cm": round(float(np.nanmean(err[both & mask[..., None]])), 3),
               "joints_out": round(float(np.isfinite(err)[mask].mean()), 4), "pcp": pcp(ours, X, mask)}
        if ids is not None:
            row.update(ids=len({int(i) for i in ids.ravel() if i >= 0}), ms_per_step=round(ms_wall, 2),
                       cpu_ms_per_step=round(ms_cpu, 2))
        if mode == "temporal":
            row["confidence"] = calibration(ours, conf, X)
        rows.append(row)
        emit(**row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--people", default="3,4")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--seeds", default="1,2")
    args = ap.parse_args()
    emit(bench="fewcam", cpus=os.cpu_count(), load_average_1min=round(os.getloadavg()[0], 1))
    rows = []
    for n in [int(x) for x in args.people.split(",")]:
        for seed in [int(x) for x in args.seeds.split(",")]:
            rows += run(n, args.seconds, seed)
    by = {m: [r for r in rows if r["method"] == m] for m in ("per_frame", "temporal", "oracle")}
    ratio = [t["mpjpe_common_cm"] / p["mpjpe_common_cm"] for t, p in zip(by["temporal"], by["per_frame"])]
    emit(aims={"temporal_mpjpe_ge_25pct_lower": all(r <= 0.75 for r in ratio),
               "temporal_pcp_ge_98": all(r["pcp"]["mean"] >= 98.0 for r in by["temporal"])},
         mpjpe_ratio_temporal_per_frame=[round(r, 3) for r in ratio],
         pcp_mean={m: [r["pcp"]["mean"] for r in v] for m, v in by.items()})


if __name__ == "__main__":
    main()
