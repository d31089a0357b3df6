"""Benchmark of the synthetic capture generator. One JSON object per line.

Prints: render time and peak memory of the `panel` preset with 3 scenes (and `full` with --full); SIFT feature
counts in VGA/HD images with the fraction of the view that is tent; SIFT matches between neighbouring cameras
verified against the ground truth (ray from camera A through the keypoint, first hit on the true tent, projected
into camera B by its true calibration, must land within 1.5 px of the matched keypoint and be unoccluded);
marker spots located against their true projections.

    .venv/bin/python bench/synth.py            # panel (~60 cameras x 3 scenes) + features + markers
    .venv/bin/python bench/synth.py --full     # also the full 521-camera dome x 3 scenes (~10 min)
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from dome_calib.bundle_io import load_bundle
from dome_calib.camera import project
from dome_calib.synth.capture import SynthOptions, synthesize
from dome_calib.synth.dome import projectors
from dome_calib.synth.markers import locate_spot, marker_view, spot_window_px, surface_points_seen_by
from dome_calib.synth.rays import CameraRays
from dome_calib.synth.render import RenderOptions, camera_rays, prepare_scene, render_image
from dome_calib.synth.tent import TentPose, intersect_scene

VERIFY_TOL_PX = 1.5


def emit(**record) -> None:
    print(json.dumps(record), flush=True)


def _cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and its reaped children (the render workers)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def peak_rss_mb() -> dict:
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return {"peak_rss_main_mb": round(own), "peak_rss_worker_mb": round(children)}


def render_preset(preset: str, work: Path, workers: int) -> Path:
    out = work / preset
    t0 = time.perf_counter()
    cpu0 = _cpu_seconds()
    summary = synthesize(out, SynthOptions(preset=preset, n_scenes=3, seed=0, workers=workers))
    seconds = time.perf_counter() - t0
    cpu = _cpu_seconds() - cpu0
    meta = json.loads((out / "capture.json").read_text())
    gt = load_bundle(out / "ground_truth")
    n_vga = sum(c.type == "vga" for c in gt.cameras.values()) * 3
    mem = peak_rss_mb()
    emit(bench="synth_render", preset=preset, scenes=3, cameras=len(summary.cameras), images=summary.n_images,
         vga_images=n_vga, hd_size_images=summary.n_images - n_vga, workers=workers, seconds=round(seconds, 1),
         cpu_seconds=round(cpu, 1),
         load_average_1min=round(os.getloadavg()[0], 1), est_unloaded_seconds=round(cpu / workers, 1),
         prepare_scenes_s=meta["seconds"]["prepare_scenes"],
         aim_full_s=600, **mem, peak_rss_total_est_mb=mem["peak_rss_main_mb"] + workers * mem["peak_rss_worker_mb"],
         aim_total_mb=8192)
    return out


def tent_fraction(rays: CameraRays, pose: TentPose) -> float:
    return float(np.mean(intersect_scene(rays.origin_cm, rays.base_dirs, pose).kind == 1))


def verified_matches(capture: Path, scene: str, a: str, b: str, sift) -> dict:
    gt = load_bundle(capture / "ground_truth")
    meta = json.loads((capture / "capture.json").read_text())
    p = meta["tent_poses"][scene]
    pose = TentPose(yaw_rad=p["yaw_rad"], x_cm=p["x_cm"], z_cm=p["z_cm"])
    imgs = [cv2.imread(str(capture / "scenes" / scene / f"{n}.png"), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION) for n in (a, b)]
    (ka, da), (kb, db) = (sift.detectAndCompute(im, None) for im in imgs)
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
    good = [m for m, n in (p for p in pairs if len(p) == 2) if m.distance < 0.8 * n.distance]
    uv_a = np.array([ka[m.queryIdx].pt for m in good])
    uv_b = np.array([kb[m.trainIdx].pt for m in good])
    cam_a, cam_b = gt.cameras[a], gt.cameras[b]
    hits = intersect_scene(cam_a.center_cm, CameraRays(cam_a).dirs_at(uv_a), pose)
    X = hits.X_cm
    proj = project(X, cam_b.R, cam_b.t_cm, cam_b.intr, cam_b.dist)
    to_x = X - cam_b.center_cm
    dist = np.linalg.norm(to_x, axis=1)
    seen = intersect_scene(cam_b.center_cm, to_x / np.where(dist > 0, dist, 1)[:, None], pose)
    unoccluded = np.abs(seen.s - dist) < 0.5
    err = np.linalg.norm(proj.uv_px - uv_b, axis=1)
    ok = (hits.kind > 0) & unoccluded & (err < VERIFY_TOL_PX)
    return dict(bench="synth_matches", scene=scene, camera_a=a, camera_b=b,
                baseline_cm=round(float(np.linalg.norm(cam_a.center_cm - cam_b.center_cm)), 1),
                features_a=len(ka), features_b=len(kb), ratio_test_matches=len(good), gt_verified=int(ok.sum()),
                gt_verified_fraction=round(float(ok.mean()), 3) if len(good) else 0.0,
                median_error_verified_px=round(float(np.median(err[ok])), 3) if ok.any() else None,
                tol_px=VERIFY_TOL_PX)


def feature_stats(capture: Path, sift) -> None:
    gt = load_bundle(capture / "ground_truth")
    meta = json.loads((capture / "capture.json").read_text())
    for scene in meta["scenes"][:1]:
        p = meta["tent_poses"][scene]
        pose = TentPose(yaw_rad=p["yaw_rad"], x_cm=p["x_cm"], z_cm=p["z_cm"])
        for ctype in ("vga", "hd", "kinect-color"):
            names = sorted(gt.of_type(ctype))
            counts, fracs = [], []
            for n in names:
                img = cv2.imread(str(capture / "scenes" / scene / f"{n}.png"), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
                counts.append(len(sift.detect(img)))
                fracs.append(tent_fraction(CameraRays(gt.cameras[n]), pose))
            counts, fracs = np.array(counts), np.array(fracs)
            mostly = counts[fracs > 0.5]
            emit(bench="synth_sift_features", scene=scene, type=ctype, images=len(names),
                 min=int(counts.min()), median=int(np.median(counts)), max=int(counts.max()),
                 images_mostly_tent=int(len(mostly)),
                 min_when_mostly_tent=int(mostly.min()) if len(mostly) else None,
                 median_tent_fraction=round(float(np.median(fracs)), 2), aim_vga_min=2000)


def marker_accuracy() -> None:
    from dome_calib.layout import nominal_dome
    from dome_calib.synth.tent import scene_poses

    bundle = nominal_dome("tiny", seed=0)
    errors = {}
    for si, pose in enumerate(scene_poses(2, seed=0)):
        ref = CameraRays(bundle.cameras["01_01"])
        grid = np.array([[u, v] for u in (200.0, 320.0, 440.0) for v in (180.0, 300.0, 400.0)])
        X = surface_points_seen_by(ref, pose, grid)
        X = X[np.all(np.isfinite(X), axis=1)]
        options = RenderOptions(flat_patterns=True, markers_cm=X, projector_power=0.0, ambient=0.3)
        scene = prepare_scene(f"scene_{si + 1:02d}", pose, projectors(0), {}, options)
        for name, cam in bundle.cameras.items():
            img = render_image(camera_rays(cam, options), scene, options, seed=0)
            for x in X:
                view = marker_view(cam, x, pose)
                if view.visible:
                    found = locate_spot(img, view.uv_px, search_px=spot_window_px(cam))
                    errors.setdefault(str(cam.type), []).append(float(np.linalg.norm(found - view.uv_px)))
    for ctype, e in errors.items():
        e = np.array(e)
        emit(bench="synth_markers", type=ctype, spots=len(e), median_px=round(float(np.median(e)), 4),
             p95_px=round(float(np.percentile(e, 95)), 4), max_px=round(float(e.max()), 4), tol_px=0.1,
             within_tol=int(np.sum(e < 0.1)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="also render the full 521-camera preset (long)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--keep", type=Path, default=None, help="copy the panel capture here")
    parser.add_argument("--skip-markers", action="store_true")
    parser.add_argument("--markers-only", action="store_true", help="only the marker-spot accuracy lines")
    args = parser.parse_args()
    if args.markers_only:
        marker_accuracy()
        return 0
    work = Path(tempfile.mkdtemp(prefix="bench_synth_"))
    try:
        sift = cv2.SIFT_create()
        panel = render_preset("panel", work, args.workers)
        if args.full:  # timed right after panel, before the analysis below
            shutil.rmtree(render_preset("full", work, args.workers), ignore_errors=True)
        feature_stats(panel, sift)
        gt = load_bundle(panel / "ground_truth")
        for a, b in (("01_01", "01_02"), ("01_07", "01_08"), ("01_03", "02_05"), ("00_00", "01_01")):
            if a in gt.cameras and b in gt.cameras:
                emit(**verified_matches(panel, "scene_01", a, b, sift))
        if args.keep:
            shutil.copytree(panel, args.keep, dirs_exist_ok=True)
        if not args.skip_markers:
            marker_accuracy()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
