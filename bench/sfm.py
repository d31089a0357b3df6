"""Benchmark of the projector-pattern SfM front end on a synthetic capture (one JSON object per line).

    .venv/bin/python bench/sfm.py                 # panel preset, 3 scenes (generated if missing)
    .venv/bin/python bench/sfm.py --full          # the full dome (521 cameras)
    .venv/bin/python bench/sfm.py --prior nominal # pairs/intrinsics from the nominal layout instead of truth

Per stage and scene: time and counts (features per image, pairs matched, verified pairs and matches,
registered cameras); then the cameras that see the tent (ground truth) versus those registered, and the camera
centre / rotation errors after a similarity alignment to the ground truth (before any fine bundle adjustment).
Peer comparison in the same run: pycolmap's CPU matcher against the BLAS matcher on a few pairs (time ratio,
match-count ratio).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np
import pycolmap

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.bundle_io import load_bundle  # noqa: E402
from dome_calib.camera import project  # noqa: E402


def emit(**kw) -> None:
    print(json.dumps(kw, default=lambda o: round(float(o), 4) if isinstance(o, (float, np.floating)) else str(o)),
          flush=True)


def ensure_capture(path: Path, preset: str, scenes: int) -> None:
    if (path / "capture.json").exists():
        return
    from dome_calib.synth.capture import SynthOptions, synthesize

    t = time.perf_counter()
    s = synthesize(path, SynthOptions(preset=preset, n_scenes=scenes, seed=0, workers=2, overwrite=True))
    emit(stage="synth", preset=preset, images=s.n_images, seconds=time.perf_counter() - t)


def tent_visible(capture: Path, gt) -> dict[str, set[str]]:
    """Scene -> cameras with at least 1% of tent vertices (facing the camera) inside the image."""
    out = {}
    for npz in sorted((capture / "ground_truth").glob("tent_*.npz")):
        scene = npz.stem.removeprefix("tent_")
        V = np.load(npz)["vertices_cm"]
        seen = set()
        for name, cam in gt.cameras.items():
            p = project(V, cam.R[None], cam.t_cm[None], cam.intr[None], cam.dist[None])
            if p.in_image(np.array([cam.resolution]))[0].mean() > 0.01:
                seen.add(name)
        out[scene] = seen
    return out


def umeyama(src: np.ndarray, tgt: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity tgt ~ s R src + t (pycolmap's closed form)."""
    sim = pycolmap.estimate_sim3d(np.asarray(src, dtype=float), np.asarray(tgt, dtype=float))
    return float(sim.scale), np.asarray(sim.rotation.matrix()), np.asarray(sim.translation)


def compare_matchers(db: Path, pairs: list[tuple[str, str]], n: int = 6) -> None:
    from projector.database import FeatureReader, image_name
    from projector.matching import MatchOptions, _pycolmap_match, match_descriptors

    reader = FeatureReader(db)
    t_blas = t_colmap = 0.0
    m_blas = m_colmap = 0
    for a, b in pairs[:n]:
        _, d1 = reader.features(image_name(a))
        _, d2 = reader.features(image_name(b))
        t = time.perf_counter()
        m_blas += len(match_descriptors(d1, d2))
        t_blas += time.perf_counter() - t
        t = time.perf_counter()
        m_colmap += len(_pycolmap_match(d1, d2, MatchOptions()))
        t_colmap += time.perf_counter() - t
    emit(stage="peer_matcher", pairs=min(n, len(pairs)), blas_s_per_pair=t_blas / n, pycolmap_s_per_pair=t_colmap / n,
         pycolmap_over_blas_time=t_colmap / max(t_blas, 1e-9), blas_over_pycolmap_matches=m_blas / max(m_colmap, 1))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="the full dome instead of the panel preset")
    ap.add_argument("--capture", type=Path, help="an existing capture folder (default: generated under /tmp)")
    ap.add_argument("--work", type=Path, help="work folder (default: fresh under /tmp; reuse one to time resumes)")
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--prior", choices=["truth", "nominal"], default="truth",
                    help="prior calibration: the ground truth (a previous calibration) or the nominal layout")
    ap.add_argument("--mapper", choices=["global", "incremental"], default="global")
    ap.add_argument("--refine-focal", action="store_true", help="refine focal lengths in per-scene mapping")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)

    from projector.mapping import Mapper
    from projector.sfm import SfmOptions, run_sfm

    preset = "full" if args.full else "panel"
    capture = args.capture or Path(f"/tmp/bench_sfm/{preset}")
    ensure_capture(capture, preset, args.scenes)
    work = args.work or Path(f"/tmp/bench_sfm/work_{preset}_{args.prior}_{args.mapper}_{int(time.time())}")
    gt = load_bundle(capture / "ground_truth")
    if args.prior == "truth":
        prior = gt
    else:
        from dome_calib.layout import nominal_dome

        prior = nominal_dome("full", 1)  # another draw of the nominal layout: not the truth
    options = SfmOptions()
    options.mapping.mapper = Mapper(args.mapper)
    options.mapping.refine_focal_length = args.refine_focal
    t0 = time.perf_counter()
    result = run_sfm(capture, work, options, prior=prior)
    total = time.perf_counter() - t0
    t_feat = t_match = t_map = 0.0
    for scene, st in result.scenes.items():
        nf = np.array(list(st.features.num_features.values()) or [0])
        emit(stage="features", preset=preset, scene=scene, seconds=st.features.seconds,
             images=len(st.features.num_features) + len(st.features.failures), failed=len(st.features.failures),
             features_per_image_mean=nf.mean(), features_per_image_min=int(nf.min()), features_per_image_max=int(nf.max()))
        n_img = len(st.features.num_features)
        emit(stage="matching", preset=preset, scene=scene, seconds=st.matches.seconds, pairs_matched=st.matches.num_pairs,
             exhaustive_pairs=n_img * (n_img - 1) // 2, verified_pairs=st.matches.num_verified_pairs,
             verified_matches=st.matches.num_inlier_matches)
        emit(stage="mapping", preset=preset, scene=scene, mapper=args.mapper, seconds=st.model.seconds,
             registered=len(st.model.registered), images=n_img,
             points=st.model.reconstruction.num_points3D() if st.model.reconstruction else 0)
        t_feat += st.features.seconds
        t_match += st.matches.seconds
        t_map += st.model.seconds
    visible = tent_visible(capture, gt)
    sees = set().union(*visible.values()) if visible else set(gt.cameras)
    registered = set(result.cameras)
    names = sorted(registered & set(gt.cameras))
    src = np.stack([result.cameras[n].center_cm for n in names])
    tgt = np.stack([gt.cameras[n].center_cm for n in names])
    s, R, t = umeyama(src, tgt)
    err = np.linalg.norm(src @ (s * R).T + t - tgt, axis=1)
    rot = [np.degrees(np.arccos(np.clip((np.trace(gt.cameras[n].R @ (result.cameras[n].R @ R.T).T) - 1) / 2, -1, 1)))
           for n in names]
    emit(stage="registration", preset=preset, prior=args.prior, cameras=len(gt.cameras), see_tent=len(sees),
         registered=len(registered), registered_of_those_seeing_tent=len(sees & registered),
         missing=sorted(sees - registered), all_seeing_cameras_registered=sees <= registered,
         problem_observations=result.observations.n_observations if result.observations else 0,
         problem_points=result.observations.n_points if result.observations else 0)
    worst = names[int(np.argmax(err))]
    emit(stage="accuracy", preset=preset, prior=args.prior, refine_focal=args.refine_focal, center_err_cm_median=np.median(err),
         center_err_cm_mean=err.mean(), center_err_cm_max=err.max(), worst_camera=worst,
         within_1cm=int((err < 1.0).sum()), of=len(err), rotation_err_deg_median=np.median(rot),
         rotation_err_deg_max=max(rot), scale_to_truth=s)
    emit(stage="total", preset=preset, features_s=t_feat, matching_s=t_match, features_plus_matching_s=t_feat + t_match,
         mapping_s=t_map, merge_s=result.seconds["merge"], wall_s=total, failures=len(result.failures),
         load_avg_1_5_15=[round(x, 1) for x in os.getloadavg()], cores=os.cpu_count())
    if not args.full:  # pair selection on the full nominal dome (cheap): how many pairs the full run matches
        from dome_calib.layout import nominal_dome
        from projector.pairs import PairOptions, pairs_from_prior

        dome = nominal_dome("full", 0).cameras
        t = time.perf_counter()
        full_pairs = pairs_from_prior(dome, list(dome), PairOptions())
        degree = np.bincount(np.searchsorted(sorted(dome), np.array(full_pairs).ravel()), minlength=len(dome))
        emit(stage="pairs_full_dome", cameras=len(dome), pairs=len(full_pairs),
             exhaustive_pairs=len(dome) * (len(dome) - 1) // 2, min_pairs_per_camera=int(degree.min()),
             seconds=time.perf_counter() - t)
    first = next(iter(result.scenes))
    pairs_file = work / first / "pairs.txt"
    pairs = [tuple(Path(x).stem for x in line.split()) for line in pairs_file.read_text().splitlines()]
    compare_matchers(work / first / "database.db", pairs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
