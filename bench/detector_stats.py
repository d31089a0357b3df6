"""How real OpenPose output errs, and whether the synthetic detector errs the same way.

Real: Pose2Sim's demo capture (one person balancing, 4 phone cameras 1088 x 1920, 100 frames at 60 fps, OpenPose
BODY_25B; ``tests/data/pose2sim_balancing``, see its PROVENANCE.md). Its calibration is imported as
``dome-calib import --from pose2sim`` does (:func:`dome_calib.interop.convert.read_foreign`), the detections are
read by ``dome-calib reconstruct``'s reader, the 3D reference is a robust body per frame with the cameras' poses
refined (:func:`dome_calib.synth.detector_reference.fit_reference`), and the statistics are those of
:func:`dome_calib.synth.detector_stats.measure` (noise per joint relative to the person's height, its distribution
and time correlation, per-joint bias, outliers with their durations and sizes, misses, swaps, confidences).

Synthetic twin: the same four cameras (as refined), one synthetic person of the same size standing where the real
one stood, facing the same way, detected by :func:`dome_calib.synth.detector.synth_detections` with the default
:class:`~dome_calib.synth.detector_model.DetectorModel` at 60 fps for 100 frames, and measured by the same
procedure (fit, refinement and all); ``--seeds`` draws (seed 0..n-1) give the synthetic spread. Against the truth
(seed 0) beside it: what the fitting procedure itself does to the figures.

Run: .venv/bin/python bench/detector_stats.py [--data tests/data/pose2sim_balancing] [--seeds 8]
Prints one JSON object per line: the real statistics section by section; the model they fit beside the defaults
(``defaults_match``); then one line per key figure: real, synthetic mean and sd over the seeds, truth-referenced.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict, fields, replace  # noqa: E402
from fractions import Fraction  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from dome_calib.bundle import Bundle, SyncTables  # noqa: E402
from dome_calib.interop.common import ImportOptions  # noqa: E402
from dome_calib.interop.convert import read_foreign  # noqa: E402
from dome_calib.recon.openpose_io import read_openpose_folder  # noqa: E402
from dome_calib.synth.detector import synth_detections  # noqa: E402
from dome_calib.synth.detector_model import TWIN_CORRECTED, DetectorModel  # noqa: E402
from dome_calib.synth.detector_reference import NOMINAL_HEIGHT_CM, fit_reference, truth_track  # noqa: E402
from dome_calib.synth.detector_stats import fitted_model, measure  # noqa: E402
from dome_calib.synth.group import GroupTruth, PersonPlan  # noqa: E402
from dome_calib.synth.skeleton import clock_table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FPS = Fraction(60)
FRAME_MS = float(1000 / FPS)
START_MS = 2000.0
#: Options the fitting procedure reads off by more than the seeds' spread (the twin, against its own settings):
#: their defaults are the real figure times (setting / what the twin's same procedure reads of it).
CORRECTED = {"noise_bias_share": ("noise_time", "bias_share"), "noise_tau_ms": ("noise_time", "tau_ms"),
             "hidden_noise": ("noise", "sigma_rel_hidden_over_visible"), "miss_base": ("misses", "visible", "rate"),
             "outlier_size_rel": ("outliers", "size_rel", "median")}
assert set(CORRECTED) == set(TWIN_CORRECTED)
KEY_FIGURES = [("noise", "sigma_rel_median"), ("noise", "core_kurtosis"), ("noise", "sigma_rel_hidden_over_visible"),
               ("noise_time", "tau_ms"), ("noise_time", "bias_share"), ("noise_time", "white_share"),
               ("outliers", "rate"), ("outliers", "rate_by_k", "5"), ("outliers", "rate_by_class", "wrists"),
               ("outliers", "episodes"), ("outliers", "duration_ms", "median"),
               ("outliers", "size_rel", "median"), ("misses", "visible", "rate"), ("misses", "hidden", "rate"),
               ("misses", "hidden", "duration_ms", "median"), ("hidden", "share"), ("swaps", "pairs_swapped"),
               ("confidence", "visible_inliers", 4), ("confidence", "hidden_inliers", 4),
               ("confidence", "outliers", 4), ("confidence", "tau_ms"), ("confidence", "bias_share"),
               ("quirks", "zero_coordinate_with_confidence")]


def emit(**fields_) -> None:
    print(json.dumps(fields_, default=lambda o: asdict(o) if hasattr(o, "__dataclass_fields__") else str(o)),
          flush=True)


def figure(sections: dict, path: tuple) -> float | None:
    v = sections
    for k in path:
        if v is None:
            return None
        v = v[k]
    return None if v is None else float(v)


def real_capture(data: Path) -> tuple[Bundle, dict, int]:
    names = {f"cam_{k:02d}": f"00_{k:02d}" for k in range(1, 5)}
    bundle, _ = read_foreign(data / "calibration" / "Calib_qualisys.toml", "pose2sim",
                             ImportOptions(names=names, seq="pose2sim"))
    det = read_openpose_folder(data / "pose", body_model="BODY_25B",
                               camera_map={f"cam{k:02d}_json": f"00_{k:02d}" for k in range(1, 5)})
    return bundle, det.people, len(next(iter(det.people.values())))


def twin(reference) -> tuple[Bundle, GroupTruth]:
    """The refined real cameras, the world moved so the person stands at the origin; the synthetic person."""
    X = reference.X_cm
    centre = np.nanmedian(X[:, 2], axis=0) * np.array([1.0, 0.0, 1.0])
    cams = {n: replace(c, t_cm=c.t_cm + c.R @ centre) for n, c in reference.bundle.cameras.items()}
    right = -np.nanmedian(X[:, 6] - X[:, 12], axis=0)  # l_hip - r_hip points to the body's left
    heading = float(np.arctan2(right[0], -right[2]))
    plan = PersonPlan(id=0, role="talk", scale=reference.scale, waypoints_cm=((0.0, 0.0),), facing_rad=heading)
    duration = 99 * FRAME_MS
    bundle = Bundle(seq="twin", cameras=cams, sync=SyncTables(streams={"hd": clock_table(
        FPS, start_ms=START_MS - 1000.0, duration_ms=duration + 1200.0)}, kinect_color={}, kinect_depth={}))
    return bundle, GroupTruth(ids=[0], plans=(plan,), start_ms=START_MS, duration_ms=duration)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT / "tests" / "data" / "pose2sim_balancing")
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()
    emit(bench="detector_stats", cpus=os.cpu_count(), load_average_1min=round(os.getloadavg()[0], 1),
         data=str(args.data))
    bundle, people, n_frames = real_capture(args.data)
    t0 = time.perf_counter()
    ref = fit_reference(bundle, people, np.arange(n_frames), FRAME_MS)
    emit(what="reference", source="real", seconds=round(time.perf_counter() - t0, 2), frames=n_frames,
         cameras_refined=ref.cameras, ba_sigma_px=round(ref.ba_sigma_px, 2),
         ba_threshold_px=round(ref.ba_threshold_px, 1), person_scale=round(ref.scale, 3),
         person_height_cm=round(NOMINAL_HEIGHT_CM * ref.scale, 1))
    extra = {c: int(sum(max(len(p) - 1, 0) for p in frames.values())) for c, frames in sorted(people.items())}
    emit(what="other_detections", source="real", per_camera=extra, note="cameras 00_01 and 00_02: a partial onlooker "
         "whose two views agree in 3D (tests/test_people_real.py): a real person, not a false one; 00_03 and 00_04: "
         "none; false people 0 in 400 images (95 % upper bound 3 / 400)")
    real = measure(ref.track)
    for name, section in real.items():
        emit(what=name, source="real", **section)
    height_px = float(bundle.cameras["00_01"].resolution[1])
    fit = fitted_model(real, image_height_px=height_px, false_people_bound=3.0 / (4 * n_frames))
    defaults = DetectorModel()
    mismatch = [k for k, v in fit.items() if k not in CORRECTED
                and not np.allclose(_flat(v), _flat(getattr(defaults, k)), rtol=0.02)]
    emit(what="fitted_model", fitted=fit, defaults={f.name: getattr(defaults, f.name) for f in fields(defaults)
                                                    if f.name in fit}, defaults_match=not mismatch,
         mismatched=mismatch, corrected_by_the_twin=sorted(CORRECTED))
    tb, truth = twin(ref)
    table = tb.sync.streams["hd"]
    keep = (table.univ_time_ms >= START_MS - 1.0) & (table.univ_time_ms <= START_MS + truth.duration_ms + 1.0)
    frames, times = table.index[keep], table.univ_time_ms[keep]
    synthetic, wall = [], time.perf_counter()
    truth_ref = None
    for seed in range(args.seeds):
        det, ids = synth_detections(tb, truth, univ_time_ms=(float(times[0]), float(times[-1])),
                                    model=DetectorModel(seed=seed), with_ids=True)
        r = fit_reference(tb, det, frames, FRAME_MS)
        synthetic.append(measure(r.track))
        if seed == 0:
            truth_ref = measure(truth_track(tb, truth, det, ids, frames, times, FRAME_MS))
    emit(what="twin", seeds=args.seeds, frames=int(len(frames)), seconds=round(time.perf_counter() - wall, 1))
    for name, path in CORRECTED.items():
        twin_mean = float(np.mean([figure(x, path) for x in synthetic]))
        setting = _flat(getattr(defaults, name))[0]
        suggested = figure(real, path) * setting / twin_mean
        emit(what="correction", option=name, figure=".".join(path), real=figure(real, path), setting=setting,
             twin_reads=round(twin_mean, 5), factor=round(setting / twin_mean, 3), suggested=round(suggested, 5),
             default_within_10pct=bool(abs(setting / suggested - 1.0) <= 0.10))
    for path in KEY_FIGURES:
        values = [figure(s, path) for s in synthetic]
        values = [v for v in values if v is not None and np.isfinite(v)]
        emit(what="key_figure", figure=".".join(map(str, path)), real=figure(real, path),
             synthetic_mean=round(float(np.mean(values)), 5) if values else None,
             synthetic_sd=round(float(np.std(values, ddof=1)), 5) if len(values) > 1 else None,
             synthetic_vs_truth_seed0=figure(truth_ref, path))


def _flat(v) -> np.ndarray:
    if hasattr(v, "median"):
        return np.array([v.median, v.log_sd], dtype=float)
    return np.atleast_1d(np.asarray(v, dtype=float))


if __name__ == "__main__":
    main()
