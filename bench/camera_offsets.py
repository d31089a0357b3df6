"""A camera's offset measured and taken out, against the truth (issue 51, ``reconstruct --correct-offsets``): the
few-camera rig (5 HD cameras, the detector whose errors last, 2 people), ``--off`` of its cameras turned by
``--degrees`` about their own vertical axis and/or moved ``--move-cm`` sideways in the bundle given to the
reconstruction (the detections come from the true cameras), reconstructed (the body over time) with the true
bundle, with the wrong one, and with the wrong one whose cameras flagged for their offset had their principal point
moved by the offset measured (:mod:`dome_calib.recon.people.camera_offsets`), ``--rounds`` times.

Run: .venv/bin/python bench/camera_offsets.py [--off 1] [--degrees 1.0] [--move-cm 0] [--seeds 1,2] [--rounds 2]
Prints one JSON object per line: the load; per seed and bundle (``true``, ``wrong``, ``corrected_<k>``) the MPJPE
against the truth (cm, over the (time, person, joint) both hold), PCP, joints out, the flagged cameras, and per
camera the median offset measured and the shift the wrong camera gives the truth's joints (its true offset: median
of the true camera's projection minus the wrong one's, px) and the correction applied.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.bundle import Bundle  # noqa: E402
from dome_calib.recon.people.camera_offsets import shifted_bundle, with_offsets_corrected  # noqa: E402
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people  # noqa: E402
from dome_calib.recon.people.scene_io import camera_report  # noqa: E402
from dome_calib.recon.people.sources import people_streams  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402
from dome_calib.rotation import rotvec_to_matrix  # noqa: E402
from dome_calib.synth.detector import DetectorModel, synth_detections  # noqa: E402
from dome_calib.synth.group_eval import match_bodies, pcp  # noqa: E402
from dome_calib.synth.rig import GROUP_MARGIN_MS, RigOptions, few_camera_rig, rig_group  # noqa: E402


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def wrong_bundle(bundle: Bundle, names: list[str], degrees: float, move_cm: float) -> Bundle:
    """``names`` turned by ``degrees`` about their own vertical (image y) axis and moved ``move_cm`` along their own
    x axis (sideways)."""
    cams = dict(bundle.cameras)
    for name in names:
        cam = cams[name]
        R = rotvec_to_matrix(np.radians([0.0, degrees, 0.0])) @ cam.R
        centre = -cam.R.T @ cam.t_cm + move_cm * cam.R[0]
        cams[name] = dataclasses.replace(cam, R=R, t_cm=-R @ centre)
    return dataclasses.replace(bundle, cameras=cams, calib_data_source="wrong")


def true_offset_px(true: Bundle, wrong: Bundle, name: str, X: np.ndarray) -> list[float]:
    """Median over the truth's joints of the true camera's projection minus the wrong one's (px)."""
    pts = X.reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1)]
    d = (project_points(view_set(true, [name]), pts).uv_px[0] - project_points(view_set(wrong, [name]), pts).uv_px[0])
    return np.round(np.nanmedian(d, axis=0), 2).tolist()


def run(seed: int, args) -> None:
    bundle = few_camera_rig(RigOptions(seed=seed, duration_ms=1000.0 * args.seconds + GROUP_MARGIN_MS + 100.0))
    truth = rig_group(bundle, n_people=args.people, seed=seed)
    det = synth_detections(bundle, truth, model=DetectorModel(seed=seed))
    streams = people_streams(bundle, det)
    table = bundle.sync.streams["hd"]
    span = (table.univ_time_ms >= truth.start_ms) & (table.univ_time_ms <= truth.start_ms + truth.duration_ms)
    times = table.univ_time_ms[span]
    names = [n for s in streams for n in s.cameras]
    X, present = truth.joints_cm(times)
    wrong_names = sorted(bundle.cameras)[:args.off]
    wrong = wrong_bundle(bundle, wrong_names, args.degrees, args.move_cm)
    options = PeopleOptions()
    truths = {n: true_offset_px(bundle, wrong, n, X) for n in wrong_names}
    correction = None

    def people(label: str, b: Bundle, shifts: dict) -> dict:
        views = view_set(b, names)
        seq = reconstruct_people(views, streams, times, options)
        report = camera_report(seq.cameras, views.resolution, options.temporal.min_noise_px, corrected_px=shifts,
                               diverged=correction.diverged if correction else [])
        _, ours, _ = match_bodies([x.ids for x in seq.bodies], [x.X_cm for x in seq.bodies], X, present)
        err = np.linalg.norm(ours - X, axis=-1)
        mask = present[..., None] & np.ones(err.shape, bool)
        row = dict(seed=seed, bundle=label, off=wrong_names, degrees=args.degrees, move_cm=args.move_cm,
                   mpjpe_cm=round(float(np.nanmean(err[mask])), 3),
                   joints_out=round(float(np.isfinite(err)[mask].mean()), 4), pcp=pcp(ours, X, present)["mean"],
                   flagged=report["flagged"],
                   cameras={n: {"median_offset_px": c["median_offset_px"], "offset_flagged": c["offset_flagged"],
                                "median_reprojection_px": c["median_reprojection_px"],
                                "outvoted_share": c["outvoted_share"], "corrected_px": c["offset_corrected_px"],
                                **({"true_offset_px": truths[n]} if n in truths else {})}
                            for n, c in report["cameras"].items()})
        emit(**row)
        return {"row": row, "report": report}

    people("true", bundle, {})
    rounds = iter(range(1, args.rounds + 1))
    kept, correction = with_offsets_corrected(
        lambda shifts: people("wrong" if not shifts else f"corrected_{next(rounds)}", shifted_bundle(wrong, shifts),
                              shifts), lambda r: r["report"], args.rounds)
    emit(seed=seed, kept=kept["row"]["bundle"], mpjpe_cm=kept["row"]["mpjpe_cm"], diverged=correction.diverged,
         undone=correction.undone, undone_shifted=correction.undone_shifted,
         shifts_px={n: np.round(v, 2).tolist() for n, v in correction.shifts_px.items()})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--off", type=int, default=1)
    ap.add_argument("--degrees", type=float, default=1.0)
    ap.add_argument("--move-cm", type=float, default=0.0)
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--rounds", type=int, default=4)
    args = ap.parse_args()
    emit(machine={"loadavg": round(os.getloadavg()[0], 1)})
    for seed in [int(s) for s in args.seeds.split(",")]:
        run(seed, args)


if __name__ == "__main__":
    main()
