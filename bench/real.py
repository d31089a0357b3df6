"""Real photographs: `dome-calib calibrate --prior` and pycolmap's incremental mapping, both judged against the
reference cameras of a survey (Strecha et al., CVPR 2008, Herz-Jesu-P8; see the data folder's PROVENANCE.md).

    .venv/bin/python bench/real.py                          # data: ../shared/data/real/herzjesu_p8
    .venv/bin/python bench/real.py --data DIR --work DIR --seed 0

The capture: one scene, the 8 photographs as ``scenes/scene_01/00_NN.png`` (8-bit grey, the JPEGs decoded once:
both solvers read the same PNGs). The reference cameras go into the dome's frame and size: centred on the
camera centroid and scaled by ``--cm-per-m`` (default 25: the 17 m camera path becomes 4.2 m, inside the dome);
the survey's rotations, written with 6 digits, are re-orthonormalised (SVD); K is halved for the half-size
images with OpenCV's pixel-centre convention (``c' = (c + 0.5) / 2 - 0.5``). The prior is the reference
perturbed like an old calibration (fixed seed): every centre moved 5 cm in a random direction, every camera
turned 1 deg about a random axis, focal lengths +3 %, principal point and the zero distortion kept.

- ours: ``dome-calib calibrate CAPTURE -o OUT --prior PRIOR`` (the CLI, in a subprocess);
- colmap: pycolmap 4 ``extract_features`` (OPENCV, one camera per image, started from the prior's intrinsics),
  ``match_exhaustive``, ``incremental_mapping`` with its defaults (focal and distortion refined, principal point
  held), fixed seed, 2 threads.

Scoring (:func:`dome_calib.compare.compare_cameras`): a similarity onto the reference on the camera centres
(pycolmap's ``estimate_sim3d_robust``, then ``estimate_sim3d`` on its inliers), then per camera the centre (cm in
the dome-sized frame), focal (%), principal point (px) and lens error: the largest difference between the two
lenses' distortion displacements over a 17 x 13 grid spanning the whole image (px). Rotations three ways: the
error of every camera pair's relative rotation ``R_a R_b^T`` (no alignment: ``rotation_pair``, the headline), per
camera after a similarity fitted to the centres and a point one lever along each optical axis
(``rotation_axes_sim``), and per camera after the centres' similarity (``rotation_centres_sim``). The last is
mostly alignment noise here: the 8 centres lie near one curve, so the centres' similarity leaves the rotation
about it loose (2.5 mm of centre error across the 1.3 m width of the path tilts every camera by 0.1 deg).
Signed focal errors (``focal_signed_pct``: ``100 (f_est / f_ref - 1)`` per camera, the mean of fx and fy, and
each of them; their mean, spread and whether all cameras share a sign) beside the unsigned median: issue 52's
question, whether one sign on every camera is a bias. ``--lens-variants A,B`` (or ``all``) then re-runs calibrate's
bundle-adjustment stage on ours' stored SfM problem once per hypothesis of :data:`LENS_VARIANTS` (principal point
forced free, lens terms held, the rule's noise floor, ...), ``--variants-only`` on the SfM of an earlier run in the
same ``--work``, and prints one ``ours_lens_variant`` object per hypothesis.
Prints one JSON object per line; the last one (without variants) holds the ratios ours / COLMAP of the medians.
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import pickle
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pycolmap

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.align import AlignOptions, transform_cameras  # noqa: E402
from dome_calib.bundle import Bundle, Camera, CameraType  # noqa: E402
from dome_calib.ba.lens_model import LensModelOptions  # noqa: E402
from dome_calib.bundle_io import load_bundle, write_bundle  # noqa: E402
from dome_calib.camera import colmap_to_opencv_px, opencv_to_colmap_px  # noqa: E402
from dome_calib.compare import compare_cameras  # noqa: E402
from dome_calib.pipeline.stages import ba_options, run_ba_stage  # noqa: E402
from dome_calib.rotation import rotation_angle_deg, rotvec_to_matrix  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "real" / "herzjesu_p8"
SCENE = "scene_01"
CENTER_PERTURB_CM = 5.0
ROTATION_PERTURB_DEG = 1.0
FOCAL_PERTURB = 1.03
ALIGN_MAX_ERROR_CM = 20.0  # inlier threshold of the scoring similarity: only gross failures are left out


def emit(**obj) -> None:
    print(json.dumps(obj, default=lambda o: o.item() if isinstance(o, np.generic) else str(o)), flush=True)


def load_avg() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


# ----------------------------------------------------------------------------------------------- reference
def read_strecha_camera(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """One ``.camera`` file: K (3, 3) px of the full-size image, world_from_camera R (3, 3), centre (3,) m, size."""
    try:
        rows = [[float(v) for v in line.split()] for line in path.read_text().splitlines() if line.strip()]
        K, R, C, size = np.array(rows[0:3]), np.array(rows[4:7]), np.array(rows[7]), rows[8]
        if K.shape != (3, 3) or R.shape != (3, 3) or C.shape != (3,) or len(size) != 2:
            raise ValueError(f"rows of {[len(r) for r in rows]} numbers")
    except (OSError, ValueError, IndexError) as exc:
        raise SystemExit(f"{path}: not a Strecha .camera file (K 3 rows, distortion, R 3 rows, C, size): {exc}")
    return K, R, C, (int(size[0]), int(size[1]))


def orthonormalise(R: np.ndarray) -> np.ndarray:
    """The rotation nearest to R (Frobenius): U V^T of its SVD, with det +1."""
    U, _, Vt = np.linalg.svd(R)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def reference_cameras(data: Path, cm_per_m: float) -> tuple[dict[str, Camera], dict[str, Path]]:
    """Reference cameras (dome frame: centroid of the centres at the origin, ``cm_per_m`` cm per survey metre) by
    name ``00_NN``, and the image file of each."""
    files = sorted((data / "cameras").glob("*.camera"))
    if not files:
        raise SystemExit(f"{data / 'cameras'}: no .camera files")
    raw = {f"00_{i:02d}": (read_strecha_camera(f), data / "images" / f"{f.stem}.jpg") for i, f in enumerate(files)}
    centroid_m = np.mean([c[2] for c, _ in raw.values()], axis=0)
    cams, images = {}, {}
    for node, (name, ((K, R_wfc, C_m, (w, h)), image)) in enumerate(sorted(raw.items()), start=1):
        intr = np.array([K[0, 0] / 2, K[1, 1] / 2, (K[0, 2] + 0.5) / 2 - 0.5, (K[1, 2] + 0.5) / 2 - 0.5])
        R = orthonormalise(R_wfc.T)  # cam_from_world
        C_cm = (C_m - centroid_m) * cm_per_m
        cams[name] = Camera(name=name, type=CameraType.HD, resolution=(w // 2, h // 2),
                            K=np.array([[intr[0], 0, intr[2]], [0, intr[1], intr[3]], [0, 0, 1.0]]), dist=np.zeros(5),
                            R=R, t_cm=-R @ C_cm, panel=0, node=node)
        images[name] = image
    return cams, images


def perturbed_prior(reference: dict[str, Camera], seed: int) -> dict[str, Camera]:
    """The reference with each centre moved CENTER_PERTURB_CM in a random direction, each camera turned
    ROTATION_PERTURB_DEG about a random axis, focal lengths times FOCAL_PERTURB (fixed seed, cameras by name)."""
    rng = np.random.default_rng(seed)
    out = {}
    for name, cam in sorted(reference.items()):
        d, a = rng.normal(size=3), rng.normal(size=3)
        C = cam.center_cm + CENTER_PERTURB_CM * d / np.linalg.norm(d)
        R = rotvec_to_matrix(np.radians(ROTATION_PERTURB_DEG) * a / np.linalg.norm(a)) @ cam.R
        K = cam.K.copy()
        K[0, 0] *= FOCAL_PERTURB
        K[1, 1] *= FOCAL_PERTURB
        out[name] = Camera(name=name, type=cam.type, resolution=cam.resolution, K=K, dist=cam.dist.copy(), R=R,
                           t_cm=-R @ C, panel=cam.panel, node=cam.node)
    return out


def build_capture(capture: Path, reference: dict[str, Camera], images: dict[str, Path], data: Path) -> None:
    """CAPTURE/capture.json, scenes/scene_01/<camera>.png (grey) and ground_truth/ (the reference bundle)."""
    tmp = capture.with_name(f".{capture.name}.tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "scenes" / SCENE).mkdir(parents=True)
    for name, path in sorted(images.items()):
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
        if grey is None:
            raise SystemExit(f"{path}: camera {name}: unreadable image")
        w, h = reference[name].resolution
        if grey.shape != (h, w):
            raise SystemExit(f"{path}: camera {name}: image is {grey.shape[1]}x{grey.shape[0]}, expected {w}x{h} "
                             "(half of the reference size)")
        cv2.imwrite(str(tmp / "scenes" / SCENE / f"{name}.png"), grey)
    write_bundle(Bundle(seq="reference", cameras=reference, calib_data_source=f"survey: {data}"), tmp / "ground_truth")
    meta = {"scenes": [SCENE], "cameras": sorted(reference), "source": str(data),
            "ground_truth": "ground_truth/calibration_reference.json"}
    (tmp / "capture.json").write_text(json.dumps(meta, indent=1))
    shutil.rmtree(capture, ignore_errors=True)
    tmp.replace(capture)


# ----------------------------------------------------------------------------------------------- solvers
def run_ours(capture: Path, prior: Path, out: Path) -> tuple[dict[str, Camera], dict, float]:
    """`dome-calib calibrate CAPTURE -o OUT --prior PRIOR` (fresh work folder); cameras, report, wall seconds."""
    work = out.with_name(out.name + ".work")
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(work, ignore_errors=True)
    exe = Path(sys.executable).with_name("dome-calib")
    cmd = [str(exe), "calibrate", str(capture), "-o", str(out), "--prior", str(prior), "--seq", "real"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"dome-calib calibrate failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    report = json.loads((out / "report" / "report.json").read_text())
    return load_bundle(out).cameras, report, seconds


def run_colmap(capture: Path, prior: dict[str, Camera], work: Path, seed: int) -> tuple[dict[str, Camera], dict, float]:
    """pycolmap's own pipeline on the capture's PNGs; cameras (OpenCV convention, k3 = 0) by name."""
    pycolmap.logging.minloglevel = max(int(pycolmap.logging.minloglevel), 1)  # its INFO lines drown ours
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    image_dir = capture / "scenes" / SCENE
    db = work / "database.db"
    first = prior[sorted(prior)[0]]
    if any(not np.allclose(c.K, first.K) for c in prior.values()):
        raise SystemExit("the prior's cameras differ in K: one ImageReaderOptions.camera_params cannot start them all")
    cx, cy = opencv_to_colmap_px(first.intr[2:])
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "OPENCV"
    reader.camera_params = ",".join(f"{v:.6f}" for v in (*first.intr[:2], cx, cy, 0, 0, 0, 0))
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = 2
    t0 = time.perf_counter()
    pycolmap.extract_features(db, image_dir, camera_mode=pycolmap.CameraMode.PER_IMAGE, reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = 2
    pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = 2
    mapping.random_seed = seed
    models = pycolmap.incremental_mapping(db, image_dir, work / "sparse", mapping)
    seconds = time.perf_counter() - t0
    if not models:
        return {}, {"models": 0}, seconds
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    cams = {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        name = Path(image.name).stem
        cam = rec.cameras[image.camera_id]
        fx, fy, cx, cy, k1, k2, p1, p2 = cam.params
        c = colmap_to_opencv_px(np.array([cx, cy]))
        T = image.cam_from_world()
        cams[name] = Camera(name=name, type=CameraType.HD, resolution=(cam.width, cam.height),
                            K=np.array([[fx, 0, c[0]], [0, fy, c[1]], [0, 0, 1.0]]),
                            dist=np.array([k1, k2, p1, p2, 0.0]), R=np.asarray(T.rotation.matrix()),
                            t_cm=np.asarray(T.translation), panel=0, node=0)
    info = {"models": len(models), "points": rec.num_points3D(), "rms_px": rec.compute_mean_reprojection_error()}
    return cams, info, seconds


#: Hypotheses of issue 52 (a focal bias of one sign on a shallow scene), each the bundle-adjustment stage re-run on
#: ours' stored SfM problem (``ours.work/sfm.pkl``) with one change: (candidate lens terms the rule may free or
#: None for all, lens-rule options, lens rule on). ``rule``: calibrate's own stage (the reference of the others).
LENS_VARIANTS: dict[str, tuple[tuple[str, ...] | None, dict, bool]] = {
    "rule": (None, {}, True),
    "focal_only": ((), {}, True),  # every lens term but fx, fy held at the prior
    "k1_only": (("k1",), {}, True),  # the rule judges k1 alone; principal point and the rest held
    "pp_free": (None, {"max_principal_point_sigma_px": 1e9}, True),  # principal point always freed
    "pp_free_dist_held": (("cx", "cy"), {"max_principal_point_sigma_px": 1e9}, True),
    "all_free": (None, {}, False),  # no rule: every lens term free in one solve
    "floor_0.1": (None, {"min_noise_px": 0.1}, True),
    "floor_0.4": (None, {"min_noise_px": 0.4}, True),
}


def run_lens_variant(sfm_pickle: Path, name: str) -> tuple[dict[str, Camera], dict]:
    """The BA stage of calibrate on the stored SfM outcome with one :data:`LENS_VARIANTS` change; cameras, lens
    terms freed per camera."""
    terms, lens_options, rule = LENS_VARIANTS[name]
    problem = pickle.loads(sfm_pickle.read_bytes()).problem.copy()  # our own work folder, written by calibrate
    if terms is not None:
        for j, term in enumerate(("cx", "cy", "k1", "k2", "p1", "p2", "k3")):
            if term not in terms:
                problem.free[:, 8 + j] = False
    options = ba_options() if rule else dataclasses.replace(ba_options(), compute_uncertainty=False)
    out = run_ba_stage(problem, options=options, lens=LensModelOptions(**lens_options))
    free = ({n: c["free"] for n, c in out.lens_model["cameras"].items()} if out.lens_model else
            {n: [t for t, f in zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), problem.free[i, 6:]) if f]
             for i, n in enumerate(problem.camera_names)})
    return out.cameras, free


# ----------------------------------------------------------------------------------------------- scoring
def axis_aligned_rotation_deg(cameras: dict[str, Camera], reference: dict[str, Camera]) -> np.ndarray:
    """Per camera rotation error (deg) after a similarity fitted to every camera's centre and a point one lever
    further along its optical axis (lever: the RMS spread of the reference centres), so that orientations fix it
    too (pycolmap's ``estimate_sim3d``)."""
    names = sorted(set(cameras) & set(reference))
    c_est = np.array([cameras[n].center_cm for n in names])
    c_ref = np.array([reference[n].center_cm for n in names])
    lever = float(np.sqrt(np.mean(np.sum((c_ref - c_ref.mean(axis=0)) ** 2, axis=1))))
    scale = pycolmap.estimate_sim3d(c_est, c_ref).scale  # only to put the estimate's lever in its own units
    src = np.concatenate([c_est, c_est + lever / scale * np.array([cameras[n].R[2] for n in names])])
    tgt = np.concatenate([c_ref, c_ref + lever * np.array([reference[n].R[2] for n in names])])
    aligned = transform_cameras({n: cameras[n] for n in names}, pycolmap.estimate_sim3d(src, tgt))
    return np.array([rotation_angle_deg(aligned[n].R, reference[n].R) for n in names])


def pairwise_rotation_deg(cameras: dict[str, Camera], reference: dict[str, Camera]) -> np.ndarray:
    """Angle (deg) between estimated and reference relative rotations R_a R_b^T of every camera pair (no
    alignment involved)."""
    names = sorted(set(cameras) & set(reference))
    return np.array([rotation_angle_deg(cameras[a].R @ cameras[b].R.T, reference[a].R @ reference[b].R.T)
                     for a, b in itertools.combinations(names, 2)])


def score(cameras: dict[str, Camera], reference: dict[str, Camera]) -> dict:
    """Medians and maxima of the per-camera errors after the centres' similarity, and of the rotation errors
    measured without it (camera pairs) and after a similarity that includes the optical axes."""
    if len(set(cameras) & set(reference)) < 3:
        return {"registered": len(cameras)}
    cmp = compare_cameras(cameras, reference, AlignOptions(max_error_cm=ALIGN_MAX_ERROR_CM))
    s = cmp.summary()["all"]
    out = {"registered": len(cameras), "scored": s["count"], "align_inliers": cmp.align_inliers}
    for metric in ("center_cm", "focal_pct", "principal_px", "distortion_px"):
        key = "lens_px" if metric == "distortion_px" else metric
        out[f"{key}_median"], out[f"{key}_max"] = s[f"{metric}_median"], s[f"{metric}_max"]
    pairs = pairwise_rotation_deg(cameras, reference)
    out["rotation_pair_deg_median"], out["rotation_pair_deg_max"] = float(np.median(pairs)), float(pairs.max())
    axes = axis_aligned_rotation_deg(cameras, reference)
    out["rotation_axes_sim_deg_median"], out["rotation_axes_sim_deg_max"] = float(np.median(axes)), float(axes.max())
    out["rotation_centres_sim_deg_median"] = s["rotation_deg_median"]
    out["rotation_centres_sim_deg_max"] = s["rotation_deg_max"]
    out["per_camera"] = {n: {k: round(v, 4) for k, v in e.as_dict().items() if isinstance(v, float)}
                         for n, e in sorted(cmp.cameras.items())}
    return out | signed_focal(cameras, reference)


def signed_focal(cameras: dict[str, Camera], reference: dict[str, Camera]) -> dict:
    """Signed focal errors (%, ``100 (f_est / f_ref - 1)``; no alignment involved) per camera: fx, fy and their mean,
    with the mean over cameras, the spread (sample SD) and whether every camera has the same sign (issue 52)."""
    names = sorted(set(cameras) & set(reference))
    fx, fy = ([100.0 * (cameras[n].K[a, a] / reference[n].K[a, a] - 1.0) for n in names] for a in (0, 1))
    f = (np.array(fx) + np.array(fy)) / 2
    return {"focal_signed_pct": {n: round(float(v), 4) for n, v in zip(names, f)},
            "fx_signed_pct": {n: round(float(v), 4) for n, v in zip(names, fx)},
            "fy_signed_pct": {n: round(float(v), 4) for n, v in zip(names, fy)},
            "focal_signed_mean_pct": float(f.mean()),
            "focal_signed_sd_pct": float(f.std(ddof=1)) if len(f) > 1 else None,
            "focal_one_sign": bool(np.all(f > 0) or np.all(f < 0))}


def run_variants(sfm_pickle: Path, variants: list[str], reference: dict[str, Camera]) -> None:
    if variants and not sfm_pickle.is_file():
        raise SystemExit(f"{sfm_pickle}: no SfM of ours to re-run (run without --variants-only first)")
    for name in variants:
        t0 = time.perf_counter()
        cams, free = run_lens_variant(sfm_pickle, name)
        emit(what="ours_lens_variant", variant=name, seconds=round(time.perf_counter() - t0, 1),
             **score(cams, reference), free=free)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA, help="folder with cameras/*.camera and images/*.jpg")
    ap.add_argument("--work", type=Path, default=Path("/tmp/real_bench"))
    ap.add_argument("--seed", type=int, default=0, help="seed of the prior's perturbation and of COLMAP")
    ap.add_argument("--cm-per-m", type=float, default=25.0, help="dome cm per survey metre")
    ap.add_argument("--skip-colmap", action="store_true")
    ap.add_argument("--lens-variants", default="", metavar="A,B",
                    help=f"also re-run the bundle adjustment on ours' SfM with each of: {', '.join(LENS_VARIANTS)} "
                         "(issue 52's hypotheses; 'all' for every one)")
    ap.add_argument("--variants-only", action="store_true",
                    help="only the --lens-variants, on the SfM of an earlier run in the same --work")
    args = ap.parse_args()
    variants = list(LENS_VARIANTS) if args.lens_variants == "all" else [v for v in args.lens_variants.split(",") if v]
    if unknown := sorted(set(variants) - set(LENS_VARIANTS)):
        ap.error(f"--lens-variants: unknown {', '.join(unknown)} (choose from {', '.join(LENS_VARIANTS)})")

    reference, images = reference_cameras(args.data, args.cm_per_m)
    capture, prior_dir = args.work / "capture", args.work / "prior"
    build_capture(capture, reference, images, args.data)
    prior = perturbed_prior(reference, args.seed)
    write_bundle(Bundle(seq="prior", cameras=prior, calib_data_source="reference, perturbed"), prior_dir)
    spread = np.ptp(np.array([c.center_cm for c in reference.values()]), axis=0)
    emit(what="capture", data=str(args.data), cameras=len(reference), scenes=1,
         image_px=list(next(iter(reference.values())).resolution), cm_per_m=args.cm_per_m,
         camera_spread_cm=spread.round(1).tolist(), seed=args.seed,
         prior={"center_cm": CENTER_PERTURB_CM, "rotation_deg": ROTATION_PERTURB_DEG, "focal": FOCAL_PERTURB},
         prior_error=score(prior, reference) | {"per_camera": None})

    if args.variants_only:
        run_variants(args.work / "ours.work" / "sfm.pkl", variants, reference)
        return 0
    load0 = load_avg()
    ours, report, t_ours = run_ours(capture, prior_dir, args.work / "ours")
    s_ours = score(ours, reference)
    emit(what="ours", seconds=round(t_ours, 1), load_avg=[load0, load_avg()], rms_px=report["rms_px"],
         expected=len(reference), **s_ours)
    lens = report.get("lens_model")
    if lens is not None:
        emit(what="ours_lens_model", per_camera={n: {"free": v["free"], "held": v["held"]}
                                                 for n, v in sorted(lens.get("cameras", {}).items())},
             rule=lens.get("rule"))
    run_variants(args.work / "ours.work" / "sfm.pkl", variants, reference)
    if args.skip_colmap:
        return 0
    load0 = load_avg()
    colmap, info, t_colmap = run_colmap(capture, prior, args.work / "colmap", args.seed)
    s_colmap = score(colmap, reference)
    emit(what="colmap", seconds=round(t_colmap, 1), load_avg=[load0, load_avg()], expected=len(reference),
         **info, **s_colmap)
    ratios = {}
    for key in ("center_cm_median", "rotation_pair_deg_median", "rotation_axes_sim_deg_median",
                "rotation_centres_sim_deg_median", "focal_pct_median", "principal_px_median", "lens_px_median",
                "lens_px_max"):
        if key in s_ours and key in s_colmap:
            ratios[key] = s_ours[key] / s_colmap[key] if s_colmap[key] > 0 else None
    emit(what="ours_over_colmap", **ratios, registered_ours=s_ours["registered"],
         registered_colmap=s_colmap["registered"], expected=len(reference))
    return 0


if __name__ == "__main__":
    sys.exit(main())
