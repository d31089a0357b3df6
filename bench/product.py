"""The whole product on one synthetic session: `dome-calib session` (calibrate + kinect + sync into one bundle),
then every pillar against the session's one ground truth, and the chain's time per stage.

    .venv/bin/python bench/product.py                  # panel preset (60 cameras), 3 tent positions
    .venv/bin/python bench/product.py --full           # the full dome (521 cameras)
    .venv/bin/python bench/product.py --preset tiny    # what `make demo` runs

Prints one JSON object per line: setup; "stage" lines (wall seconds of each part of the synthesis and of each
stage of the session run, calibrate's own stages inside it); "cameras" (per type, against the truth after a
similarity alignment); "kinect" per sensor (depth-to-colour translation mm, rotation deg); "sync" per stream
(frame-time error us RMS / max against the truth; Kinect streams with the bound the simulated jitter allows);
"skeleton" (MPJPE mm of the person triangulated from all streams with the produced bundle, with the ground-truth
bundle, and from VGA only with the produced bundle, on a 100 Hz grid: ``mpjpe_mm`` session-aligned (the aim's
figure), ``mpjpe_cameras_mm`` after the camera-centre similarity, ``mpjpe_world_mm`` in the bundle's own world,
``pa_mpjpe_mm`` per-time similarity; see dome_calib.synth.product_eval); "aims" (the issue's checks, true/false).
The session is kept in OUT/session and reused when it matches (its synthesis times are then not re-measured).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dome_calib.bundle_io import load_bundle  # noqa: E402
from dome_calib.compare import compare_cameras  # noqa: E402
from dome_calib.pipeline.demo import AIM_MPJPE_RATIO, AIM_VGA_HD_RMS_US  # noqa: E402
from dome_calib.pipeline.session import SessionOptions, run_session  # noqa: E402
from dome_calib.synth.product_eval import evaluate  # noqa: E402
from dome_calib.synth.session import SessionOptions as SynthSessionOptions  # noqa: E402
from dome_calib.synth.session import make_product_session  # noqa: E402


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="panel", choices=["tiny", "panel", "full"])
    ap.add_argument("--full", action="store_true", help="the full dome (same as --preset full)")
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="work folder (default /tmp/dome_product_<preset>)")
    args = ap.parse_args()
    preset = "full" if args.full else args.preset
    out = args.out or Path(f"/tmp/dome_product_{preset}")
    session, bundle_dir = out / "session", out / "bundle"
    emit(what="setup", preset=preset, scenes=args.scenes, seed=args.seed, cpu_count=os.cpu_count(),
         load_avg_1min=os.getloadavg()[0])

    marks: list[tuple[str, float]] = []
    make_product_session(session, SynthSessionOptions(preset=preset, scenes=args.scenes, seed=args.seed),
                         progress=lambda what: marks.append((what, time.perf_counter())))
    marks.append(("end", time.perf_counter()))
    for (what, t0), (_, t1) in zip(marks, marks[1:]):
        emit(what="stage", chain="synthesis", stage=what, wall_s=round(t1 - t0, 2))
    if not marks[:-1]:
        emit(what="stage", chain="synthesis", stage="reused", wall_s=0.0)

    shutil.rmtree(bundle_dir, ignore_errors=True)
    shutil.rmtree(bundle_dir.with_name(bundle_dir.name + ".work"), ignore_errors=True)  # a cold run, no resume
    t0 = time.perf_counter()
    result = run_session(session, bundle_dir, SessionOptions(seq="product"))
    total = time.perf_counter() - t0
    for name, s in result.calibration.stage_seconds.items():
        emit(what="stage", chain="session/calibrate", stage=name, wall_s=round(s, 2))
    for name, s in result.stage_seconds.items():
        emit(what="stage", chain="session", stage=name, wall_s=round(s, 2))
    emit(what="stage", chain="session", stage="total", wall_s=round(total, 2), load_avg_1min=os.getloadavg()[0])

    truth = load_bundle(session / "ground_truth")
    produced = load_bundle(bundle_dir)  # what a consumer reads back
    summary = compare_cameras(produced.cameras, truth.cameras).summary()
    for key, s in summary.items():
        emit(what="cameras", type=key, **{k: round(v, 4) if isinstance(v, float) else v for k, v in s.items()})
    t0 = time.perf_counter()
    fig = evaluate(produced, truth, session)
    eval_s = time.perf_counter() - t0
    for name, e in fig["kinect"].items():
        emit(what="kinect", sensor=name, **{k: round(v, 4) for k, v in e.items()})
    for key, e in fig["sync"].items():
        emit(what="sync", stream=key, **{k: round(v, 3) if isinstance(v, float) else v for k, v in e.items()})
    sk = fig["skeleton"]
    for name, e in sk.items():
        emit(what="skeleton", run=name, **{k: round(v, 4) if isinstance(v, float) else v for k, v in e.items()})
    emit(what="stage", chain="evaluate", stage="triangulate x3 + sync + kinect", wall_s=round(eval_s, 2))
    vga_hd = [e["err_rms_us"] for k, e in fig["sync"].items() if "/" not in k]
    ratio = sk["produced_all"]["mpjpe_mm"] / sk["truth_all"]["mpjpe_mm"]  # session-aligned: the aim's figure
    ratio_cam = sk["produced_all"]["mpjpe_cameras_mm"] / sk["truth_all"]["mpjpe_cameras_mm"]
    ratio_world = sk["produced_all"]["mpjpe_world_mm"] / sk["truth_all"]["mpjpe_world_mm"]
    emit(what="aims", vga_hd_within_10us_rms=max(vga_hd) <= AIM_VGA_HD_RMS_US, vga_hd_worst_rms_us=round(max(vga_hd), 3),
         kinect_within_jitter_bound=all(e["err_rms_us"] <= e["bound_rms_us"] for k, e in fig["sync"].items()
                                        if "/" in k),
         mpjpe_produced_over_truth=round(ratio, 4), mpjpe_within_10pct=ratio <= AIM_MPJPE_RATIO,
         mpjpe_cameras_aligned_produced_over_truth=round(ratio_cam, 4),
         mpjpe_world_produced_over_truth=round(ratio_world, 4),
         all_streams_below_vga_only=sk["produced_all"]["mpjpe_mm"] < sk["produced_vga"]["mpjpe_mm"],
         cameras_calibrated=f"{len(produced.cameras)}/{len(result.calibration.expected)}",
         load_avg_1min=os.getloadavg()[0])


if __name__ == "__main__":
    main()
