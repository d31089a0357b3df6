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
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

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


def profiled(fn, label: str, top: int):
    """``fn()`` under cProfile on every thread of this process (the threads the SfM maps in each get a profiler of
    their own, merged at the end; the pool's worker processes are not followed: their tasks show as the wait for
    them); emits the ``top`` functions by cumulative and by own time."""
    import cProfile
    import pstats
    import threading

    threads: list[cProfile.Profile] = []

    def start_thread(*_) -> None:  # the first event of a new thread: a profiler of its own from here on
        prof = cProfile.Profile()
        threads.append(prof)
        prof.enable()

    main = cProfile.Profile()
    threading.setprofile(start_thread)
    try:
        result = main.runcall(fn)
    finally:
        threading.setprofile(None)
    stats = pstats.Stats(main)
    for prof in threads:
        stats.add(prof)

    def rows(key: int) -> list[dict]:
        items = sorted(stats.stats.items(), key=lambda kv: -kv[1][key])[:top]
        return [{"function": f"{Path(f).name}:{line}({name})", "calls": nc, "own_s": round(tt, 2),
                 "cumulative_s": round(ct, 2)} for (f, line, name), (cc, nc, tt, ct, _) in items]

    emit(bench="dome", stage="profile", run=label, threads=len(threads), by_cumulative=rows(3), by_own=rows(2))
    return result


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
    calibrate = partial(run_calibration, capture, out, CalibrateOptions(seq=f"bench_{args.preset}"))
    result = profiled(calibrate, args.preset, args.profile) if args.profile else calibrate()
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


def quick_capture(args, root: Path, truth: Bundle) -> tuple[Bundle, list[str], Path, str]:
    """The quick scenario's capture (synthesised once): the moved truth, the moved cameras, the capture, its kind."""
    moved, names, replaced = perturb_panel(truth, args.panel, args.seed + 100, rigid=args.rigid)
    kind = "quick_rigid" if args.rigid else "quick"
    layout = root / f"{kind}_truth"
    write_bundle(dataclasses.replace(moved, seq="quick"), layout)
    capture = root / f"{kind}_capture"
    t = synth(capture, args.preset, 1, args.seed, layout=layout / "calibration_quick.json")  # --only-changed uses 1
    emit(bench="dome", stage="quick_synth", seconds=round(t, 1), perturbed=names, replaced=replaced, rigid=args.rigid)
    return moved, names, capture, kind


def quick(args, root: Path, truth: Bundle) -> None:
    """Issue 8's quick recalibration: one panel disturbed, `calibrate --prior --only-changed`."""
    moved, names, capture, kind = quick_capture(args, root, truth)
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


#: Accuracy figures compared by --compare: every error against the truth, median and max.
ERRORS = ("center_mm", "rotation_deg", "focal_pct", "principal_px", "distortion_px")


def errors(cameras: dict, truth: Bundle, names: list[str] | None = None) -> dict:
    """Every error of ``cameras`` against the truth after a similarity (``compare_cameras``): median and max."""
    cams = cameras if names is None else {n: cameras[n] for n in names if n in cameras}
    s = compare_cameras(cams, truth.cameras).summary()["all"]
    out = {"cameras": s["count"]}
    for e in ERRORS:
        key, scale = (("center_cm", 10.0) if e == "center_mm" else (e, 1.0))
        out[f"{e}_median"], out[f"{e}_max"] = s[f"{key}_median"] * scale, s[f"{key}_max"] * scale
    return out


def calibrate_in(tree: Path, capture: Path, out: Path, *extra: str) -> dict:
    """`calibrate` with the toolkit of checkout ``tree``, in a child process (bench/calibrate_in.py): its figures."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, str(Path(__file__).with_name("calibrate_in.py")), str(tree), str(capture), str(out), *extra]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"calibrate with {tree} failed ({proc.returncode}): {proc.stderr.strip()[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _ratio(new: float | None, old: float | None) -> float | None:
    if new is None or old is None or not np.isfinite(old) or old == 0:
        return None
    return round(float(new) / float(old), 4)


def _medians(records: list[dict], key: str) -> dict:
    """Per field the median over the runs of ``records[i][key]`` (a dict of numbers)."""
    fields = sorted({f for r in records for f, v in (r.get(key) or {}).items() if isinstance(v, (int, float))})
    return {f: float(np.median([r[key][f] for r in records if isinstance((r.get(key) or {}).get(f), (int, float))]))
            for f in fields}


@dataclasses.dataclass(kw_only=True)
class Case:
    """One capture both checkouts calibrate: its seed, folder, truth and (quick scenario) the moved cameras."""

    seed: int
    root: Path
    capture: Path
    truth: Bundle
    names: list[str] | None = None
    extra: list[str] = dataclasses.field(default_factory=list)  # calibrate's options for this capture


def compare_runs(args, label: str, cases: list[Case]) -> None:
    """Old (``--compare REF``) and new (this checkout) on the same captures (one per seed), one after the other,
    ``--repeat`` times (alternating which goes first); each run's figures, then the ratios new / old: of the median
    times over every run, of each error's mean over the seeds (its median over the repeats of a seed)."""
    trees = {"old": Path(args.compare).resolve(), "new": ROOT}
    records: dict[str, dict[int, list[dict]]] = {"old": {}, "new": {}}
    for case in cases:
        for k in range(args.repeat):
            for which in (("old", "new") if k % 2 == 0 else ("new", "old")):
                out = case.root / f"compare_{label}_{which}"
                rec = calibrate_in(trees[which], case.capture, out, *case.extra)
                rec["errors"] = errors(load_bundle(out).cameras, case.truth, case.names)
                if case.names is not None:  # the quick scenario: which cameras it re-estimated
                    rec["found_exactly_the_changed"] = rec.get("changes") == sorted(case.names)
                records[which].setdefault(case.seed, []).append(rec)
                emit(bench="dome", stage="compare", scenario=label, preset=args.preset, seed=case.seed, run=which,
                     repeat=k, tree=str(trees[which]), **rec)
    every = {w: [r for rs in records[w].values() for r in rs] for w in records}
    summary = {}
    for w in records:
        per_seed = {seed: _medians(rs, "errors") for seed, rs in records[w].items()}
        keys = sorted({k for e in per_seed.values() for k in e})
        summary[w] = {"seconds_total": float(np.median([r["seconds_total"] for r in every[w]])),
                      "seconds": _medians(every[w], "seconds"), "sfm_seconds": _medians(every[w], "sfm_seconds"),
                      "errors": {k: float(np.mean([e[k] for e in per_seed.values() if k in e])) for k in keys},
                      "per_seed": per_seed}
    new, old = summary["new"], summary["old"]
    ratios = {k: _ratio(new["errors"].get(k), v) for k, v in old["errors"].items() if k != "cameras"}
    emit(bench="dome", stage="compare_ratios", scenario=label, preset=args.preset, seeds=[c.seed for c in cases],
         runs_each=args.repeat, old=str(trees["old"]), new=str(trees["new"]),
         seconds_total={"old": round(old["seconds_total"], 1), "new": round(new["seconds_total"], 1),
                        "new_over_old": _ratio(new["seconds_total"], old["seconds_total"])},
         stage_new_over_old={k: _ratio(new["seconds"].get(k), v) for k, v in old["seconds"].items()},
         sfm_new_over_old={k: _ratio(new["sfm_seconds"].get(k), v) for k, v in old["sfm_seconds"].items()},
         errors_new_over_old=ratios,
         errors_new_over_old_per_seed={seed: {k: _ratio(new["per_seed"].get(seed, {}).get(k), v)
                                              for k, v in e.items() if k != "cameras"}
                                       for seed, e in old["per_seed"].items()},
         errors_old={k: round(v, 5) for k, v in old["errors"].items()},
         errors_new={k: round(v, 5) for k, v in new["errors"].items()},
         every_camera_calibrated={w: all(not r["not_calibrated"] and r["calibrated"] == r["expected"]
                                         for r in every[w]) for w in every},
         worst_error_ratio=max((v for v in ratios.values() if v is not None), default=None),
         load_average_1min=[r["load_average_1min"] for w in every for r in every[w]])


def replay_ba(args) -> None:
    """``--replay-ba``: the bundle adjustment stage again on an earlier run's SfM result (``bundle.work/sfm.pkl``
    under ``--work``), timed (wall and CPU), with the accuracy against the truth; ``--lens-passes`` sets the lens
    model's decide-and-solve passes. A stage-level benchmark: the SfM is not run again."""
    import pickle

    from dome_calib.ba.lens_model import LensModelOptions
    from dome_calib.pipeline.stages import run_ba_stage

    root = Path(args.work) / args.preset
    truth = load_bundle(root / "capture" / "ground_truth")
    with open(root / "bundle.work" / "sfm.pkl", "rb") as f:
        sfm = pickle.load(f)
    lens = LensModelOptions(**({"max_passes": args.lens_passes} if args.lens_passes else {}))
    t0, cpu0 = time.perf_counter(), time.process_time()
    ba = run_ba_stage(sfm.problem, lens=lens)
    emit(bench="dome", stage="replay_ba", preset=args.preset, seconds=round(time.perf_counter() - t0, 1),
         cpu_seconds=round(time.process_time() - cpu0, 1), load_average_1min=round(os.getloadavg()[0], 1),
         lens_max_passes=lens.max_passes, observations=sfm.problem.n_observations,
         ba={k: v for k, v in ba.stats.items() if k != "termination"}, **errors(ba.cameras, truth))


#: a child of ``--compare-ba``: the bundle adjustment stage of one checkout (its tree first on the path) on an
#: SfM result, timed, its cameras saved
_REPLAY_CHILD = r"""
import json, os, pickle, resource, sys, time
import numpy as np
from dome_calib.pipeline.stages import run_ba_stage
with open(sys.argv[1], "rb") as f:
    sfm = pickle.load(f)
r0, t0, cpu0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter(), time.process_time()
ba = run_ba_stage(sfm.problem)
r1 = resource.getrusage(resource.RUSAGE_SELF)
np.savez(sys.argv[2], names=np.array(ba.problem.camera_names), params=ba.problem.camera_params,
         lens=json.dumps(ba.lens_model, sort_keys=True, default=str))
print(json.dumps({"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - cpu0,
                  "system_seconds": r1.ru_stime - r0.ru_stime, "minor_faults": r1.ru_minflt - r0.ru_minflt,
                  "peak_rss_gb": r1.ru_maxrss / 1e6, "load_average_1min": os.getloadavg()[0],
                  "ba": {k: v for k, v in ba.stats.items() if k != "termination"}}))
"""


def _centres_cm(params: np.ndarray) -> np.ndarray:
    from dome_calib.rotation import rotvec_to_matrix

    return -np.einsum("cji,cj->ci", rotvec_to_matrix(params[:, 0:3]), params[:, 3:6])


def compare_ba(args) -> None:
    """``--compare-ba REF``: the bundle adjustment stage of REF (a checkout) and of this checkout on the same SfM
    result (``bundle.work/sfm.pkl`` under ``--work``), each in a child process with its own tree first on the path,
    ``--repeat`` times each, alternating which goes first; then the ratio of the median times and how far this
    checkout's cameras are from REF's (centres in mm and focal lengths relative, in the solve's own frame: both
    start from the same problem, so no alignment), and whether the lens model chose the same terms."""
    sfm = Path(args.work) / args.preset / "bundle.work" / "sfm.pkl"
    trees = {"old": Path(args.compare_ba).resolve(), "new": ROOT}
    runs: dict[str, list[dict]] = {"old": [], "new": []}
    saved: dict[str, list[Path]] = {"old": [], "new": []}
    for rep in range(args.repeat):
        for which in (("old", "new") if rep % 2 == 0 else ("new", "old")):
            out = Path(args.work) / args.preset / f"replay_{which}_{rep}.npz"
            env = {**os.environ, "PYTHONPATH": str(trees[which])}
            proc = subprocess.run([sys.executable, "-c", _REPLAY_CHILD, str(sfm), str(out)], env=env,
                                  cwd=trees[which], capture_output=True, text=True, check=True)
            run = json.loads(proc.stdout.strip().splitlines()[-1])
            runs[which].append(run)
            saved[which].append(out)
            emit(bench="dome", stage="compare_ba_run", preset=args.preset, checkout=which, repeat=rep,
                 **{k: (round(v, 2) if isinstance(v, float) else v) for k, v in run.items()})
    cams = {w: [np.load(p) for p in saved[w]] for w in saved}
    old, new = cams["old"][0], cams["new"][0]
    if list(old["names"]) != list(new["names"]):
        raise SystemExit("the two checkouts refined different cameras")
    centre_mm = 10.0 * np.linalg.norm(_centres_cm(new["params"]) - _centres_cm(old["params"]), axis=1)
    focal_rel = np.abs(new["params"][:, 6:8] / old["params"][:, 6:8] - 1.0)
    median = {w: float(np.median([r["seconds"] for r in runs[w]])) for w in runs}
    cpu = {w: float(np.median([r["cpu_seconds"] for r in runs[w]])) for w in runs}
    emit(bench="dome", stage="compare_ba", preset=args.preset, reference=str(trees["old"]), repeat=args.repeat,
         seconds_old=round(median["old"], 1), seconds_new=round(median["new"], 1),
         new_over_old=round(median["new"] / median["old"], 3), cpu_seconds_old=round(cpu["old"], 1),
         cpu_seconds_new=round(cpu["new"], 1), cpu_new_over_old=round(cpu["new"] / cpu["old"], 3),
         centre_diff_mm_max=float(centre_mm.max()), focal_diff_rel_max=float(focal_rel.max()),
         same_lens_model=str(old["lens"]) == str(new["lens"]),
         same_bits_on_rerun={w: all(np.array_equal(c["params"], cams[w][0]["params"]) for c in cams[w]) for w in cams},
         load_average_1min=[r["load_average_1min"] for w in runs for r in runs[w]])


def compare(args) -> None:
    """``--compare REF``: today's main (REF, a checkout) and this checkout on the same captures, in one run."""
    cases, quick_cases = [], []
    for seed in args.seeds or [args.seed]:
        root = Path(args.work) / (args.preset if seed == args.seed else f"{args.preset}_seed{seed}")
        capture = root / "capture"
        layout = None
        if not args.design_truth:
            layout = write_bundle(as_built_dome(args.preset, seed), root / "as_built") / "calibration_as_built.json"
        t = synth(capture, args.preset, args.scenes, seed, layout=layout)
        truth = load_bundle(capture / "ground_truth")
        emit(bench="dome", stage="synth", preset=args.preset, seed=seed, scenes=args.scenes,
             cameras=len(truth.cameras), seconds=round(t, 1), reused=t == 0.0)
        cases.append(Case(seed=seed, root=root, capture=capture, truth=truth, extra=["--seq", f"bench_{args.preset}"]))
        if args.quick or args.quick_only:
            moved, names, quick_cap, _ = quick_capture(argparse.Namespace(**{**vars(args), "seed": seed}), root, truth)
            quick_cases.append(Case(seed=seed, root=root, capture=quick_cap, truth=moved, names=names,
                                    extra=["--prior", str(capture / "ground_truth"), "--only-changed"]))
    if not args.quick_only:
        compare_runs(args, "full", cases)
    if quick_cases:
        compare_runs(args, "quick_rigid" if args.rigid else "quick", quick_cases)

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
    parser.add_argument("--profile", type=int, default=0, metavar="N", help="profile the calibration (every thread "
                        "of the main process) and print its N costliest functions by cumulative and by own time")
    parser.add_argument("--compare", metavar="REF", help="a checkout of the toolkit to compare with (e.g. `git "
                        "worktree add /tmp/base main`): REF and this checkout calibrate the same captures one after "
                        "the other, each in a child process; prints each run and the ratios new / old of the time, "
                        "every stage and every error against the truth (with --quick / --quick-only: that scenario too)")
    parser.add_argument("--seeds", type=int, nargs="+", help="--compare: one capture per seed (the errors' ratios "
                        "are of their means over the seeds; the panel's medians move by 10-20 %% from one set of "
                        "observations to another); default --seed")
    parser.add_argument("--repeat", type=int, default=1, help="--compare: runs of each checkout (alternating which "
                        "goes first); the ratios are of the medians")
    parser.add_argument("--replay-ba", action="store_true", help="only the bundle adjustment stage, again, on the "
                        "SfM result an earlier run left in the work folder (timed, with the accuracy)")
    parser.add_argument("--lens-passes", type=int, default=0, help="--replay-ba: the lens model's decide-and-solve "
                        "passes (default: calibrate's)")
    parser.add_argument("--compare-ba", metavar="REF", help="only the bundle adjustment stage, of REF (a checkout) and "
                        "of this checkout, on the SfM result an earlier run left in the work folder, --repeat times "
                        "each, alternating: the time ratio and how far this checkout's cameras are from REF's")
    args = parser.parse_args()
    if args.compare_ba:
        compare_ba(args)
    elif args.replay_ba:
        replay_ba(args)
    else:
        compare(args) if args.compare else run(args)


if __name__ == "__main__":
    main()
