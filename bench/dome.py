"""End-to-end benchmark of `dome-calib calibrate` on a synthetic dome, with the oracle beside it.

    .venv/bin/python bench/dome.py --preset panel          # ~60 cameras, 3 scenes
    .venv/bin/python bench/dome.py --preset full           # 521 cameras, 3 scenes
    .venv/bin/python bench/dome.py --preset full --quick   # + quick recalibration after a panel was disturbed
    .venv/bin/python bench/dome.py --preset full --quick-only --rigid   # only that, the panel moved as one body

Prints one JSON object per line: the synthetic capture, the wall time of every calibrate stage, accuracy against
ground truth (after a similarity alignment), and the oracle: the same bundle adjustment started from the ground
truth on the same matched observations (the best these observations allow), with ratios ours / oracle.
"Feature noise" is the per-coordinate RMS with the ground-truth cameras held and only the points fitted: of the
observations the bundle adjustment got (``feature_noise_px``) and of the SfM's before the keypoint refinement
(``feature_noise_sift_px``: SIFT's keypoints; the SfM run again on the same work folder with the refinement off).

The synthetic dome is the dome AS BUILT (``dome_calib.synth.dome.as_built_dome``), not the design that calibrate
starts from without --prior (``nominal_dome(preset, seed)``): another draw of every camera's intrinsics,
distortion, aim and roll (HD focal lengths differ by up to 23 %, aims by 4 deg median) and centres off the design
by 1 cm RMS per axis. ``--design-truth`` renders the design itself (the start is then exact).
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import resource
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

if __name__ == "__main__":
    # The toolkit is imported here only, not when calibrate's SfM worker processes (started with spawn) run this
    # file's top level again as their main module: they then start as fast as under `dome-calib calibrate`, whose
    # main module imports 0.07 s of it (these imports took each worker ~1 s more, at the start of every pool).
    from dome_calib.align import align_cameras, sim3_apply, transform_cameras
    from dome_calib.ba.problem import ParamGroup, camera_to_params
    from dome_calib.ba.solver import bundle_adjust
    from dome_calib.bundle import Bundle
    from dome_calib.bundle_io import load_bundle, write_bundle
    from dome_calib.compare import compare_cameras
    from dome_calib.pipeline.full import run_calibration
    from dome_calib.pipeline.types import CalibrateOptions
    from dome_calib.pipeline.stages import ba_options as _ba_options
    from dome_calib.reasons import ReasonCode
    from dome_calib.synth.dome import as_built_dome


def ba_options():
    """Our calibrate's solver settings, without the covariance (not compared here)."""
    return dataclasses.replace(_ba_options(), compute_uncertainty=False)


def emit(**obj) -> None:
    print(json.dumps(obj, default=lambda o: o.item() if isinstance(o, np.generic) else str(o)), flush=True)


def synth(folder: Path, preset: str, scenes: int, seed: int, layout: Path | None = None) -> float:
    from dome_calib.synth.capture import SynthOptions, synthesize

    meta = folder / "capture.json"
    stamp = folder / "layout.sha256"  # the layout file's content: the same path may hold another dome
    digest = hashlib.sha256(Path(layout).read_bytes()).hexdigest() if layout else "nominal"
    if meta.exists() and stamp.exists():
        old = json.loads(meta.read_text())
        if (old["preset"] == preset and old["seed"] == seed and len(old["scenes"]) == scenes
                and stamp.read_text() == digest):
            return 0.0
    t0 = time.perf_counter()
    synthesize(folder, SynthOptions(preset=preset, n_scenes=scenes, seed=seed, layout=layout, overwrite=True))
    stamp.write_text(digest)
    return time.perf_counter() - t0


def accuracy(cameras: dict, truth: Bundle, names: list[str] | None = None) -> dict:
    cams = cameras if names is None else {n: cameras[n] for n in names if n in cameras}
    s = compare_cameras(cams, truth.cameras).summary()["all"]
    return {"cameras": s["count"], "center_mm_median": s["center_cm_median"] * 10, "center_mm_max": s["center_cm_max"] * 10,
            "rotation_deg_median": s["rotation_deg_median"], "focal_pct_median": s["focal_pct_median"],
            "focal_pct_max": s["focal_pct_max"], "distortion_px_max": s["distortion_px_max"]}


def oracle(problem, ba_problem, truth: Bundle, free_names: list[str] | None = None) -> dict:
    """BA from ground truth on the same observations: points first (cameras held), then everything free as in ours.

    Returns the points-only fit (feature-noise estimate) and the oracle's BA result.
    """
    names = [n for n in problem.camera_names if n in truth.cameras]
    sim = align_cameras({n: ba_problem.camera(n) for n in names}, truth.cameras).tgt_from_src
    start = problem.copy()
    for i, n in enumerate(start.camera_names):
        start.camera_params[i] = camera_to_params(truth.cameras[n])
    start.points_cm = sim3_apply(sim, ba_problem.points_cm)  # our points moved into the truth frame
    held = start.copy()
    held.fix(ParamGroup.ALL)
    pts_only = bundle_adjust(held, dataclasses.replace(ba_options(), outlier_rounds=1))
    start.points_cm = pts_only.problem.points_cm
    start.free = problem.free.copy()
    result = bundle_adjust(start, ba_options())
    return {"points_only": pts_only, "result": result}


def sift_feature_noise(capture: Path, work: Path, truth: Bundle) -> tuple[float, int]:
    """Feature noise (px, per-coordinate RMS and observations used) of the SfM's observations BEFORE the keypoint
    refinement: the same work folder's SfM again with the refinement off (features, matches and models reused),
    its points fitted with the ground-truth cameras held, as the oracle's points-only fit."""
    from dome_calib.pipeline.stages import problem_from_observations, prune_problem
    from projector.refine import RefineOptions
    from projector.sfm import SfmOptions, run_sfm

    raw = run_sfm(capture, work, SfmOptions(refine=RefineOptions(enabled=False)))
    problem, _ = prune_problem(problem_from_observations(raw.observations))
    names = [n for n in problem.camera_names if n in truth.cameras]
    sim = align_cameras({n: problem.camera(n) for n in names}, truth.cameras).tgt_from_src
    for i, n in enumerate(problem.camera_names):
        problem.camera_params[i] = camera_to_params(truth.cameras[n])
    problem.points_cm = sim3_apply(sim, problem.points_cm)
    problem.fix(ParamGroup.ALL)
    fit = bundle_adjust(problem, dataclasses.replace(ba_options(), outlier_rounds=1))
    return float(fit.rms_px), int(np.sum(fit.used))


def run(args) -> None:
    root = Path(args.work) / args.preset
    capture = root / "capture"
    layout = None
    if not args.design_truth:
        layout = write_bundle(as_built_dome(args.preset, args.seed), root / "as_built") / "calibration_as_built.json"
    t = synth(capture, args.preset, args.scenes, args.seed, layout=layout)
    truth = load_bundle(capture / "ground_truth")
    emit(bench="dome", stage="synth", preset=args.preset, scenes=args.scenes, cameras=len(truth.cameras),
         seconds=round(t, 1), reused=t == 0.0)
    if args.quick_only:
        quick(args, root, truth)
        return
    out = root / "bundle"
    shutil.rmtree(out, ignore_errors=True)
    if not args.resume:
        shutil.rmtree(root / "bundle.work", ignore_errors=True)
    t0 = time.perf_counter()
    result = run_calibration(capture, out, CalibrateOptions(seq=f"bench_{args.preset}"))
    total = time.perf_counter() - t0
    emit(bench="dome", stage="calibrate", preset=args.preset, seconds_total=round(total, 1),
         resumed_stages=result.resumed,  # their seconds are those measured when they ran
         load_average_1min=round(os.getloadavg()[0], 1),
         peak_rss_gb={"calibrate": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, 2),
                      "largest_worker": round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6, 2)},
         seconds={k: round(v, 1) for k, v in result.stage_seconds.items()}, sfm=result.sfm.stats,
         ba={k: v for k, v in result.ba.stats.items() if k != "termination"},
         calibrated=len(result.bundle.cameras), expected=len(result.expected), not_calibrated=result.failures,
         world_frame=result.normalized.describe())
    ours = accuracy(result.bundle.cameras, truth)
    emit(bench="dome", stage="accuracy", preset=args.preset, **ours)
    if args.skip_oracle:
        if args.quick:
            quick(args, root, truth)
        return
    t0 = time.perf_counter()
    orc = oracle(result.sfm.problem, result.ba.problem, truth)
    pts, o = orc["points_only"], orc["result"]
    o_cams = {n: o.problem.camera(n) for n in o.problem.camera_names}
    theirs = accuracy(o_cams, truth)
    both = result.ba.inlier & o.used
    ours_r = result.ba.problem  # same observations, our solution
    from dome_calib.pipeline.stages import observation_residuals

    cost_ours = 0.5 * float(np.sum(observation_residuals(ours_r)[both] ** 2))
    cost_oracle = 0.5 * float(np.sum(np.asarray(o.residuals_px)[both] ** 2))
    noise = float(pts.rms_px)
    sift_noise, sift_used = sift_feature_noise(capture, root / "bundle.work" / "sfm", truth)
    emit(bench="dome", stage="oracle", preset=args.preset, seconds=round(time.perf_counter() - t0, 1), **theirs,
         feature_noise_px=noise, feature_noise_used=int(np.sum(pts.used)), feature_noise_sift_px=sift_noise,
         feature_noise_sift_used=sift_used, refine=result.sfm.stats.get("refine"), oracle_rms_px=o.rms_px)
    emit(bench="dome", stage="ratios", preset=args.preset,
         cost_ours_over_oracle=cost_ours / cost_oracle,
         center_median_ours_over_oracle=ours["center_mm_median"] / theirs["center_mm_median"],
         center_max_ours_over_oracle=ours["center_mm_max"] / theirs["center_mm_max"],
         focal_median_ours_over_oracle=ours["focal_pct_median"] / max(theirs["focal_pct_median"], 1e-12),
         rms_over_feature_noise=result.ba.stats["rms_px"] / noise,
         every_seen_camera_calibrated=not result.failures,
         total_minutes=round(sum(result.stage_seconds.values()) / 60, 2))
    if args.quick:
        quick(args, root, truth)


def perturb_panel(truth: Bundle, panel: int, seed: int, rigid: bool = False) -> tuple[Bundle, list[str], str]:
    """Move the cameras of one panel 2-5 cm, rotate them 1-2 deg (``rigid``: the panel as one body, turned about
    its centre, so its cameras keep their relative poses); replace one (focal -4 %, other distortion)."""
    from scipy.spatial.transform import Rotation

    def motion():
        d, axis = rng.normal(size=3), rng.normal(size=3)
        dR = Rotation.from_rotvec(np.radians(rng.uniform(1, 2)) * axis / np.linalg.norm(axis)).as_matrix()
        return dR, rng.uniform(2, 5) * d / np.linalg.norm(d)

    rng = np.random.default_rng(seed)
    cams = dict(truth.cameras)
    names = sorted(n for n, c in cams.items() if c.panel == panel and c.type == "vga")
    middle = np.mean([cams[n].center_cm for n in names], axis=0)
    body = motion() if rigid else None
    for n in names:
        c = cams[n]
        dR, shift = body if rigid else motion()
        center = (middle + dR @ (c.center_cm - middle) if rigid else c.center_cm) + shift
        R = c.R @ dR.T if rigid else dR @ c.R
        cams[n] = dataclasses.replace(c, R=R, t_cm=-R @ center)
    replaced = names[len(names) // 2]
    c = cams[replaced]
    K = c.K.copy()
    K[0, 0] *= 0.96
    K[1, 1] *= 0.96
    cams[replaced] = dataclasses.replace(c, K=K, dist=c.dist * [0.9, 1.1, 1, 1, 1])
    return dataclasses.replace(truth, cameras=cams), names, replaced


def quick(args, root: Path, truth: Bundle) -> None:
    """Issue 8's quick recalibration: one panel disturbed, `calibrate --prior --only-changed`."""
    moved, names, replaced = perturb_panel(truth, args.panel, args.seed + 100, rigid=args.rigid)
    kind = "quick_rigid" if args.rigid else "quick"
    layout = root / f"{kind}_truth"
    write_bundle(dataclasses.replace(moved, seq="quick"), layout)
    capture = root / f"{kind}_capture"
    t = synth(capture, args.preset, 1, args.seed, layout=layout / "calibration_quick.json")  # --only-changed uses 1
    emit(bench="dome", stage="quick_synth", seconds=round(t, 1), perturbed=names, replaced=replaced, rigid=args.rigid)
    out = root / f"{kind}_bundle"
    shutil.rmtree(out, ignore_errors=True)
    if not args.resume:
        shutil.rmtree(root / f"{kind}_bundle.work", ignore_errors=True)
    t0 = time.perf_counter()
    result = run_calibration(capture, out, CalibrateOptions(prior=Path(root / "capture" / "ground_truth"),
                                                            only_changed=True))
    total = time.perf_counter() - t0
    found = sorted(result.changes)
    ours = accuracy(result.bundle.cameras, moved, names)
    emit(bench="dome", stage="quick", seconds_total=round(sum(result.stage_seconds.values()), 1),
         resumed_stages=result.resumed,
         seconds={k: round(v, 1) for k, v in result.stage_seconds.items()},
         match_split_s={k: round(v, 1) for k, v in result.stats["quick"]["seconds"].items()}, found=found,
         load_average_1min=round(os.getloadavg()[0], 1), found_exactly_the_changed=found == names,
         missed=sorted(set(names) - set(found)),
         given_new_intrinsics=sorted(n for n, c in result.changes.items() if any(r.code == ReasonCode.INTRINSICS_CHANGED for r in c.reasons)),
         counts={k: v for k, v in result.stats["quick"].items() if k not in ("suspects", "seconds")},
         false_alarms=sorted(set(found) - set(names)), **ours)
    orc = oracle(result.ba.problem, result.ba.problem, moved)["result"]
    theirs = accuracy({n: orc.problem.camera(n) for n in orc.problem.camera_names}, moved, names)
    emit(bench="dome", stage="quick_oracle", **theirs,
         center_median_ours_over_oracle=ours["center_mm_median"] / theirs["center_mm_median"],
         center_max_ours_over_oracle=ours["center_mm_max"] / theirs["center_mm_max"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=["tiny", "panel", "full"], default="panel")
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", default="/tmp/dome_bench")
    parser.add_argument("--skip-oracle", action="store_true")
    parser.add_argument("--design-truth", action="store_true", help="render the nominal design itself instead of "
                        "the dome as built (calibrate then starts from the exact cameras)")
    parser.add_argument("--resume", action="store_true", help="keep the work folder: finished stages are reused "
                        "and reported with the time they took when they ran")
    parser.add_argument("--quick", action="store_true", help="also run the quick-recalibration scenario")
    parser.add_argument("--quick-only", action="store_true", help="only the quick-recalibration scenario")
    parser.add_argument("--panel", type=int, default=1, help="panel disturbed in the quick scenario")
    parser.add_argument("--rigid", action="store_true", help="quick scenario: the panel moved as one rigid body "
                        "(its cameras keep their relative poses) instead of each camera on its own")
    run(parser.parse_args())


if __name__ == "__main__":
    main()
