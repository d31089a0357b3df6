"""Reconstruction bench: a synthetic moving skeleton seen by every VGA, HD and Kinect colour camera at their own frame
times, triangulated with the ground-truth bundle and with a calibrated-like bundle; Kinect depth of a tent.

Run: .venv/bin/python bench/recon.py [--seconds 4] [--seed 0] [--dome nominal|real]
Prints one JSON object per line: setup, one line per (bundle, streams) with MPJPE (mm) and frames per second,
ratios and aims, and the Kinect point cloud's distance to the true surface.

The "calibrated" bundle is NOT the output of the calibration pipeline (too heavy for a bench on 521 cameras):
it is the ground truth perturbed like a good calibration result, independently per camera: centre 1.5 mm RMS,
rotation 0.02 deg per axis, focal length 0.05 %, principal point 0.3 px, k1/k2 0.2 % of their value.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small batched solves: threads only contend

import argparse  # noqa: E402
import copy  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from dome_calib.bundle import Bundle  # noqa: E402
from dome_calib.panoptic_io import read_calibration, read_kcalibration  # noqa: E402
from dome_calib.recon.depth import pointcloud_at  # noqa: E402
from dome_calib.recon.project import view_set  # noqa: E402
from dome_calib.synth.skeleton import DetectionNoise, skeleton_cm, synthetic_sync, synthetic_tracks  # noqa: E402
from dome_calib.recon.streams import InterpolationOptions, triangulate_streams  # noqa: E402
from dome_calib.synth.depth import distance_to_triangles, render_depth_mm, tent_triangles  # noqa: E402
from dome_calib.rotation import rotvec_to_matrix  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REAL_CALIBRATION = ROOT / "tests" / "data" / "panoptic" / "calibration_160906_band1.json"
REAL_KCALIBRATION = ROOT / "tests" / "data" / "panoptic" / "kcalibration_171026_cello3.json"
DEPTH_NOISE_MM = 2.0


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def ground_truth(dome: str, seconds: float, seed: int) -> Bundle:
    if dome == "nominal":
        from dome_calib.layout import nominal_dome

        bundle = nominal_dome("full", seed=seed)
    else:
        cameras, source = read_calibration(REAL_CALIBRATION)
        bundle = Bundle(seq="band1", cameras=cameras, calib_data_source=source)
    bundle.kinect = read_kcalibration(REAL_KCALIBRATION)  # real depth-colour calibration on the 50_xx cameras
    bundle.sync = synthetic_sync(bundle, start_ms=1000.0, duration_ms=seconds * 1000.0, seed=seed)
    return bundle


def calibrated_like(truth: Bundle, seed: int) -> Bundle:
    """The ground truth perturbed per camera like a good calibration result (see the module docstring)."""
    rng = np.random.default_rng(seed + 1000)
    out = copy.deepcopy(truth)
    for cam in out.cameras.values():
        centre = cam.center_cm + rng.normal(scale=0.15 / np.sqrt(3), size=3)  # 1.5 mm RMS
        cam.R = rotvec_to_matrix(rng.normal(scale=np.radians(0.02), size=3)) @ cam.R
        cam.t_cm = -cam.R @ centre
        K = cam.K.copy()
        K[[0, 1], [0, 1]] *= 1.0 + rng.normal(scale=5e-4)
        K[[0, 1], [2, 2]] += rng.normal(scale=0.3, size=2)
        cam.K = K
        cam.dist = cam.dist.copy()
        cam.dist[:2] *= 1.0 + rng.normal(scale=2e-3, size=2)
    return out


def run(bundle: Bundle, streams, times: np.ndarray, truth_X: np.ndarray, mode: str = "linear") -> dict:
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    c0, w0 = time.process_time(), time.perf_counter()
    seq = triangulate_streams(views, streams, times, interpolation=InterpolationOptions(mode=mode))
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    err_mm = np.linalg.norm(seq.X_cm - truth_X, axis=-1) * 10.0
    ok = np.isfinite(err_mm)
    return {"views": len(views.names), "frames": len(times), "mpjpe_mm": round(float(err_mm[ok].mean()), 4),
            "p95_mm": round(float(np.percentile(err_mm[ok], 95)), 4),
            "reconstructed": round(float(ok.mean()), 4),
            "median_inlier_views": float(np.median(seq.n_inliers[ok])),
            "fps_wall": round(len(times) / wall, 1), "fps_cpu": round(len(times) / cpu, 1)}


def skeleton_bench(dome: str, seconds: float, seed: int) -> None:
    truth = ground_truth(dome, seconds, seed)
    calibrated = calibrated_like(truth, seed)
    noise = DetectionNoise(noise_px=2.0, wrong_fraction=0.10)
    names = sorted(truth.cameras)
    tracks = synthetic_tracks(truth, names, noise=noise, seed=seed)
    counts = {t: len(truth.of_type(t)) for t in ("vga", "hd", "kinect-color")}
    sync = truth.sync
    emit(what="setup", dome=dome, cameras=len(names), **{f"n_{k.replace('-', '_')}": v for k, v in counts.items()},
         seconds=seconds, noise_px=noise.noise_px, wrong_fraction=noise.wrong_fraction,
         vga_period_ms=round(float(np.median(np.diff(sync.streams["vga"].univ_time_ms))), 5),
         hd_period_ms=round(float(np.median(np.diff(sync.streams["hd"].univ_time_ms))), 5),
         kinect_period_ms=[round(float(np.median(np.diff(t.univ_time_ms))), 5) for t in sync.kinect_color.values()],
         kinect_dropped_frames=sum(int(t.index[-1] - t.index[0] + 1 - len(t.index))
                                   for t in sync.kinect_color.values()),
         load_avg_1min=os.getloadavg()[0], calibrated_bundle="ground truth perturbed like a good calibration "
         "(centre 1.5 mm, rotation 0.02 deg, focal 0.05 %, pp 0.3 px, k1/k2 0.2 %); not the calibration pipeline")
    vga_times = sync.streams["vga"].univ_time_ms
    times = vga_times[(vga_times > 1050.0) & (vga_times < 1000.0 + seconds * 1000.0 - 50.0)]
    truth_X = skeleton_cm(times)
    vga_only = [s for s in tracks if s.stream == "vga"]
    results = {}
    for bname, bundle in (("ground_truth", truth), ("calibrated", calibrated)):
        for sname, streams in (("vga_only", vga_only), ("all_interpolated", tracks)):
            r = run(bundle, streams, times, truth_X)
            results[(bname, sname)] = r
            emit(what="skeleton", bundle=bname, streams=sname, times="vga frame times", **r)
    # Any universal time: all streams at a 100 Hz grid (between everyone's frames); nearest frame as ablation.
    grid = np.arange(times[0], times[-1], 10.0)
    for mode in ("linear", "nearest"):
        r = run(truth, tracks, grid, skeleton_cm(grid), mode=mode)
        sname = "all_interpolated" if mode == "linear" else "all_nearest_frame"
        emit(what="skeleton", bundle="ground_truth", streams=sname, times="100 Hz grid", **r)
    r = run(truth, tracks, times, truth_X, mode="nearest")
    emit(what="skeleton", bundle="ground_truth", streams="all_nearest_frame", times="vga frame times", **r)
    # Throughput: best of 3 runs (all streams, ground truth), wall clock and CPU time of this process.
    views = view_set(truth, [n for s in tracks for n in s.cameras])
    walls, cpus = [], []
    for _ in range(3):
        c0, w0 = time.process_time(), time.perf_counter()
        triangulate_streams(views, tracks, times)
        cpus.append(time.process_time() - c0)
        walls.append(time.perf_counter() - w0)
    emit(what="throughput", views=len(views.names), joints=19, frames=len(times),
         fps_wall_best_of_3=round(len(times) / min(walls), 1), fps_cpu_best_of_3=round(len(times) / min(cpus), 1),
         cpu_count=os.cpu_count(), load_avg_1min=os.getloadavg()[0])
    gt_all, gt_vga = results[("ground_truth", "all_interpolated")], results[("ground_truth", "vga_only")]
    cal_all, cal_vga = results[("calibrated", "all_interpolated")], results[("calibrated", "vga_only")]
    fps = max(gt_all["fps_wall"], cal_all["fps_wall"], len(times) / min(walls))
    emit(what="ratios", all_over_vga_only_gt=round(gt_all["mpjpe_mm"] / gt_vga["mpjpe_mm"], 4),
         all_over_vga_only_calibrated=round(cal_all["mpjpe_mm"] / cal_vga["mpjpe_mm"], 4),
         calibrated_over_gt_all=round(cal_all["mpjpe_mm"] / gt_all["mpjpe_mm"], 4),
         calibrated_over_gt_vga_only=round(cal_vga["mpjpe_mm"] / gt_vga["mpjpe_mm"], 4))
    emit(what="aims", all_streams_lower_than_vga_only=gt_all["mpjpe_mm"] < gt_vga["mpjpe_mm"],
         calibrated_within_10pct_of_gt=cal_all["mpjpe_mm"] <= 1.1 * gt_all["mpjpe_mm"],
         fps_at_least_100_for_all_views=bool(fps >= 100.0), fps_wall_best=round(fps, 1),
         fps_cpu_best=round(max(gt_all["fps_cpu"], cal_all["fps_cpu"], len(times) / min(cpus)), 1),
         views=gt_all["views"],
         load_avg_1min=os.getloadavg()[0])


def kinect_bench(dome: str, seed: int, n_sensors: int) -> None:
    bundle = ground_truth(dome, 1.0, seed)
    for i, sensor in enumerate(bundle.kinect.sensors.values()):
        sensor.depth_bias_mm, sensor.depth_scale = 10.0 - i, 0.003 - 0.0005 * i
    tris = tent_triangles()
    nodes = sorted(bundle.kinect.sensors, key=lambda n: (len(n), n))[:n_sensors]
    rng = np.random.default_rng(seed)
    frames = {n: render_depth_mm(bundle, n, tris, noise_mm=DEPTH_NOISE_MM, rng=rng) for n in nodes}
    t0 = time.perf_counter()
    cloud = pointcloud_at(bundle, 1500.0, lambda n, k: frames.get(n), nodes=nodes)
    seconds = time.perf_counter() - t0
    sample = cloud.xyz_cm[rng.choice(len(cloud.xyz_cm), 20000, replace=False)]
    d_mm = distance_to_triangles(sample, tris) * 10.0
    emit(what="kinect_pointcloud", surface="tent + floor", sensors=len(nodes), points=len(cloud.xyz_cm),
         median_distance_mm=round(float(np.median(d_mm)), 3), p90_distance_mm=round(float(np.percentile(d_mm, 90)), 3),
         depth_noise_sigma_mm=DEPTH_NOISE_MM, aim_median_mm=5.0 + DEPTH_NOISE_MM,
         within_aim=bool(np.median(d_mm) < 5.0 + DEPTH_NOISE_MM),
         time_offsets_ms=[round(float(cloud.time_offset_ms[cloud.sensor == i][0]), 2) for i in range(len(nodes))],
         seconds=round(seconds, 2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dome", choices=["nominal", "real"], default="nominal",
                    help="nominal: the synthetic 521-camera dome; real: the 520-camera Panoptic calibration")
    ap.add_argument("--kinects", type=int, default=4, help="Kinects rendered for the point-cloud check")
    args = ap.parse_args()
    skeleton_bench(args.dome, args.seconds, args.seed)
    kinect_bench(args.dome, args.seed, args.kinects)


if __name__ == "__main__":
    main()
