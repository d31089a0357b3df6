"""The Kinects' depth as a witness: how many wrong joints it removes and how many right ones it wrongly removes.

Setup: the real Panoptic dome calibration with its 10 Kinects (tests/data/panoptic: calibration + kcalibration),
synthetic sync tables, a synthetic group (``--people``, scenario mixed) and its depth frames rendered for every
Kinect at its own depth-frame times (:mod:`dome_calib.synth.depth_people`: the people's capsules, the floor, the
dome's far wall; the sensor's bias model, Kinect v2 axial noise, 1 mm steps; 0.5-4.5 m), read back from disk
through the depth folder reader, as ``reconstruct --depth`` reads them.

1. Controlled joints at every VGA time of the span, judged by :func:`~dome_calib.recon.people.depth_witness.
   judge_joints` with the default options and a few margins:
   - right: every true joint moved by a reconstruction-like error (Gaussian, ``--joint-error-cm`` per axis);
   - ghosts: the two-view point of one person's joint in one camera and another person's same joint in another
     (closest approach of the two rays; kept when the rays pass within 10 cm, as a triangulation would accept them,
     inside the capture volume);
   - swapped limbs: the two-view point of a person's left wrist / ankle in one camera and its right one in another
     (kept when more than 10 cm from both true joints and the rays pass within 10 cm).
2. End to end: ``reconstruct``'s stage (dome_calib.recon.people.run) on the group's synthetic OpenPose detections
   (the persistent detector; ``--setups``: panels 1-2's 48 VGA + 8 HD cameras, and 8 HD cameras alone) with and
   without the witness: joints of bodies matched to a true person more than 10 cm from it, joints of bodies
   matching nobody, MPJPE, the joints removed.

Run: .venv/bin/python bench/depth_witness.py [--people 8] [--seconds 2] [--seed 0]
Prints one JSON object per line.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from dome_calib.bundle import Bundle  # noqa: E402
from dome_calib.panoptic_io import read_calibration, read_kcalibration  # noqa: E402
from dome_calib.recon.body_models import JOINTS19  # noqa: E402
from dome_calib.recon.depth import depth_folder_reader  # noqa: E402
from dome_calib.recon.people.depth_witness import (DepthSensors, DepthWitness, DepthWitnessOptions,  # noqa: E402
                                                   judge_joints)
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people  # noqa: E402
from dome_calib.recon.people.sources import people_streams  # noqa: E402
from dome_calib.recon.project import view_set  # noqa: E402
from dome_calib.synth.depth_people import write_group_depth  # noqa: E402
from dome_calib.synth.detector import DetectorModel, synth_detections  # noqa: E402
from dome_calib.synth.group import GroupOptions, make_group  # noqa: E402
from dome_calib.synth.group_eval import match_bodies  # noqa: E402
from dome_calib.synth.skeleton import synthetic_sync  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "panoptic"
START_MS = 1500.0
WRONG_CM = 10.0


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def dome(seconds: float, seed: int) -> Bundle:
    cams, source = read_calibration(DATA / "calibration_160906_band1.json")
    bundle = Bundle(seq="witness", cameras=cams, calib_data_source=source)
    bundle.kinect = read_kcalibration(DATA / "kcalibration_171026_cello3.json")
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=seconds * 1000.0 + 2 * START_MS, seed=seed)
    return bundle


def two_view_points(C1: np.ndarray, A: np.ndarray, C2: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest approach of rays C1 -> A and C2 -> B (each (N, 3)): (midpoints (N, 3), gaps (N,) cm)."""
    d1, d2 = A - C1, B - C2
    w0 = C1 - C2
    a, b, c = (d1 * d1).sum(1), (d1 * d2).sum(1), (d2 * d2).sum(1)
    d, e = (d1 * w0).sum(1), (d2 * w0).sum(1)
    den = np.maximum(a * c - b * b, 1e-9)
    s, t = (b * e - c * d) / den, (a * e - b * d) / den
    p, q = C1 + s[:, None] * d1, C2 + t[:, None] * d2
    return 0.5 * (p + q), np.linalg.norm(p - q, axis=1)


def in_volume(X: np.ndarray) -> np.ndarray:
    return (np.hypot(X[:, 0], X[:, 2]) < 230.0) & (X[:, 1] < 0.0) & (X[:, 1] > -210.0)


def controlled(bundle, truth, witness: DepthWitness, times, centres, rng, joint_error_cm) -> dict[str, list]:
    """Per time: the right, ghost and swapped-limb joints and their verdicts' inputs."""
    X, present = truth.joints_cm(times)
    sets: dict[str, list] = {"right": [], "ghost": [], "swapped_limb": []}
    for k, t in enumerate(times):
        people = np.flatnonzero(present[k])
        if len(people) < 2:
            continue
        Xp = X[k, people]
        frames = witness.frames_at(float(t))
        right = Xp + rng.normal(0.0, joint_error_cm, Xp.shape)
        n = 6000
        c1, c2 = rng.integers(0, len(centres), n), rng.integers(0, len(centres), n)
        p1, p2 = rng.integers(0, len(people), n), rng.integers(0, len(people), n)
        j = rng.integers(0, 19, n)
        ok = (c1 != c2) & (p1 != p2)
        G, gap = two_view_points(centres[c1], Xp[p1, j], centres[c2], Xp[p2, j])
        ok &= (gap < 10.0) & in_volume(G)
        ok &= np.min(np.linalg.norm(G[:, None] - Xp.reshape(1, -1, 3), axis=-1), axis=1) > WRONG_CM
        ghosts = G[ok]
        pairs = np.array([[5, 11], [8, 14]])
        which = pairs[rng.integers(0, 2, n)]
        S, gap = two_view_points(centres[c1], Xp[p1, which[:, 0]], centres[c2], Xp[p1, which[:, 1]])
        far = np.minimum(np.linalg.norm(S - Xp[p1, which[:, 0]], axis=1), np.linalg.norm(S - Xp[p1, which[:, 1]],
                                                                                           axis=1))
        swapped = S[(c1 != c2) & (gap < 10.0) & (far > WRONG_CM) & in_volume(S)]
        for name, pts in (("right", right.reshape(-1, 3)), ("ghost", ghosts), ("swapped_limb", swapped)):
            sets[name].append((pts, frames))
    return sets


def judge_sets(sets, sensors, options) -> dict:
    out = {}
    for name, items in sets.items():
        judged = rejected = total = 0
        by_joint = np.zeros(19, dtype=np.int64)
        for pts, frames in items:
            if not len(pts):
                continue
            pad = (-len(pts)) % 19
            P = np.concatenate([pts, np.full((pad, 3), np.nan)]).reshape(-1, 19, 3)
            v = judge_joints(P, frames, sensors, options)
            real = np.isfinite(P).all(-1)
            total += int(real.sum())
            judged += int((v.judged[real] > 0).sum())
            rejected += int(v.reject[real].sum())
            if name == "right":
                by_joint += (v.reject & real).sum(0)
        out[name] = {"joints": total, "judged": round(judged / max(total, 1), 4),
                     "removed": round(rejected / max(total, 1), 4)}
        if name == "right":
            out[name]["removed_by_joint"] = {JOINTS19[j]: int(by_joint[j]) for j in np.flatnonzero(by_joint)}
    return out


def end_to_end(bundle, truth, det, times, witness, options) -> dict:
    streams = people_streams(bundle, det)
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    truth_X, present = truth.joints_cm(times)
    out = {}
    for name, depth in (("without", None), ("with", witness)):
        wall = time.perf_counter()
        seq = reconstruct_people(views, streams, times, options, depth=depth)
        wall = time.perf_counter() - wall
        match_id, ours, unmatched = match_bodies([b.ids for b in seq.bodies], [b.X_cm for b in seq.bodies], truth_X,
                                                 present)
        err = np.linalg.norm(ours - truth_X, axis=-1)
        have = np.isfinite(err)
        ghost_joints = sum(int(np.isfinite(seq.bodies[t].X_cm[list(seq.bodies[t].ids).index(i)]).all(-1).sum())
                           for i, ts in unmatched.items() for t in ts)
        out[name] = {"body_frames": int(sum(len(b.ids) for b in seq.bodies)),
                     "joints": int(sum(np.isfinite(b.X_cm).all(-1).sum() for b in seq.bodies)),
                     "matched_joints": int(have.sum()), "wrong_joints_gt10cm": int((err[have] > WRONG_CM).sum()),
                     "joints_of_unmatched_bodies": ghost_joints,
                     "unmatched_body_frames": int(sum(len(ts) for ts in unmatched.values())),
                     "mpjpe_cm": round(float(np.mean(err[have])), 3), "seconds": round(wall, 2)}
    w, wo = out["with"], out["without"]
    out["removed"] = {"wrong_joints": wo["wrong_joints_gt10cm"] - w["wrong_joints_gt10cm"],
                      "joints_of_unmatched_bodies": wo["joints_of_unmatched_bodies"] - w["joints_of_unmatched_bodies"],
                      "right_joints_lost": max(0, (wo["matched_joints"] - wo["wrong_joints_gt10cm"])
                                               - (w["matched_joints"] - w["wrong_joints_gt10cm"]))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--people", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--joint-error-cm", type=float, default=1.5)
    ap.add_argument("--setups", default="panel,hd8", help="end to end: panel = panels 1-2's 48 VGA + 8 HD cameras; "
                    "hd8 = 8 HD cameras (a few-camera view of the same dome)")
    args = ap.parse_args()
    emit(bench="depth_witness", cpus=os.cpu_count(), load_average_1min=round(os.getloadavg()[0], 1))
    bundle = dome(args.seconds, args.seed)
    truth = make_group(GroupOptions(n_people=args.people, scenario="mixed", start_ms=START_MS,
                                    duration_ms=args.seconds * 1000.0, seed=args.seed))
    span = (START_MS, START_MS + args.seconds * 1000.0)
    vga = bundle.sync.streams["vga"]
    times = vga.univ_time_ms[(vga.univ_time_ms >= span[0]) & (vga.univ_time_ms <= span[1])]
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        wall = time.perf_counter()
        folder = write_group_depth(Path(tmp) / "depth", bundle, truth, (span[0] - 50.0, span[1] + 50.0),
                                   seed=args.seed)
        frames = sum(len(list(p.iterdir())) for p in folder.iterdir())
        emit(what="depth_frames", sensors=len(list(folder.iterdir())), frames=frames,
             seconds=round(time.perf_counter() - wall, 1))
        witness = DepthWitness.of(bundle, depth_folder_reader(folder))
        hd8 = sorted(n for n, c in bundle.cameras.items() if c.type == "hd")[::4]
        cams = sorted(n for n, c in bundle.cameras.items() if c.type == "vga" and c.panel in (1, 2)) + hd8
        centres = view_set(bundle, cams).center_cm
        sets = controlled(bundle, truth, witness, times, centres, rng, args.joint_error_cm)
        sensors = DepthSensors.of(bundle, list(witness.tables))
        base = witness.options
        variants = {"default": base}
        for n_sigma in (2.0, 8.0):
            variants[f"n_sigma_{n_sigma:g}"] = replace(base, n_sigma=n_sigma)
        for joint_cm in (2.0, 10.0):
            variants[f"joint_cm_{joint_cm:g}"] = replace(base, joint_cm=joint_cm)
        for name, options in variants.items():
            emit(what="controlled", options=name, n_sigma=options.n_sigma, joint_cm=options.joint_cm,
                 joint_error_cm=args.joint_error_cm, **judge_sets(sets, sensors, options))
        for setup in args.setups.split(","):
            use = {"panel": cams, "hd8": hd8}[setup]
            det = synth_detections(bundle, truth, cameras=use, univ_time_ms=span, model=DetectorModel(seed=args.seed))
            emit(what="end_to_end", setup=setup, cameras=len(use), times=len(times), people=args.people,
                 **end_to_end(bundle, truth, det, times, witness, PeopleOptions()))


if __name__ == "__main__":
    main()
