"""Benchmark of dome_calib.ba at dome scale against ground truth, the ML optimum and pycolmap's Ceres BA.

    .venv/bin/python bench/ba.py            # 520 real cameras, 3 scenes, 100k points, ~1M observations
    .venv/bin/python bench/ba.py --small    # 130 cameras, 10k points, ~100k observations (a minute or two)
    .venv/bin/python bench/ba.py --double --skip-peer --only ours   # 1,040 cameras (panels twice as dense), ~2M obs.
    .venv/bin/python bench/ba.py --small --load   # the same while two CPU-bound processes share the 2 cores
    .venv/bin/python bench/ba.py --solve-phases [--double | --pair] [--no-huge-pages]   # our whole solve's parts:
        # CPU seconds and minor page faults of each, reduced systems, per camera, peak memory (--pair: two domes
        # side by side, 1,040 cameras, each point seen by about as many cameras as in one dome)

Problem: the real Panoptic layout and distortion (tests/data/panoptic/calibration_160906_band1.json, 520
cameras), points on a tent-like surface, Gaussian pixel noise sigma = 0.5 px, 1 % gross outliers; the start
is perturbed like an SfM result (centres ~3 cm per axis, rotation 0.2 deg, focal 2 %, principal point 2 px,
distortion zero, points 1 cm). Each solver runs in its own process (peak memory = that process's max RSS):

- ours: dome_calib.ba.bundle_adjust from the perturbed start (Huber 2 px, reject at 5 sigma, least squares);
  ``time_s`` is the solve (the work Ceres does), ``uncertainty_s`` the covariance calibrate adds after it;
- oracle: the same solver from ground truth (the maximum-likelihood optimum of the same schedule);
- colmap: pycolmap's Ceres BA, FULL_OPENCV with k4, k5, k6 held at zero (pyceres SubsetManifold), TWO_CAMS_FROM_WORLD
  gauge, 2 threads, the same schedule (Huber 2 px on all observations, the same rejection rule, then least squares);
- k1: our solver with only k1 free (k2, p1, p2, k3 = 0), started from the truth: why five terms are needed.

Prints one JSON object per line. Errors are after a similarity alignment of camera centres to ground truth.
cost_true_inliers = 0.5 * sum |r|^2 over the observations that are not gross outliers (the same set for all).
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import json
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pycolmap

ROOT = Path(__file__).resolve().parents[1]
CALIBRATION = ROOT / "tests/data/panoptic/calibration_160906_band1.json"


def emit(obj: dict) -> None:
    print(json.dumps(obj), flush=True)


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # Linux: kB


# ----------------------------------------------------------------------------------------------- workers
def worker_ours(data: dict, start_key: str, ba_options: dict | None = None) -> dict:
    from dome_calib.ba import BAOptions, bundle_adjust, solution_uncertainty

    problem = data[start_key]
    t0, c0 = time.perf_counter(), time.process_time()
    options = BAOptions(n_threads=2, compute_uncertainty=False, **(ba_options or {}))
    res = bundle_adjust(problem, options)  # the work Ceres does
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    t1 = time.perf_counter()
    u = res.uncertainty = solution_uncertainty(res, n_threads=2)  # what calibrate adds: timed apart
    uncertainty_s = time.perf_counter() - t1
    return dict(camera_params=res.problem.camera_params, points_cm=res.problem.points_cm, used=res.used,
                time_s=elapsed, cpu_s=cpu, uncertainty_s=uncertainty_s, iterations=len(res.iterations),
                reduced_systems=sum(it.reduced_systems for it in res.iterations),
                factorisations=sum(it.factorisations for it in res.iterations),
                rejected_steps=sum(it.rejected_steps for it in res.iterations),
                shortened_steps=sum(it.shortened for it in res.iterations),
                cost=res.cost, n_params=res.n_params,
                n_used=int(res.used.sum()), termination=res.termination,
                sigma_center_centroid_cm_median=float(np.median(u.sigma_center_centroid_cm))
                if u is not None and u.sigma_center_centroid_cm is not None else None,
                sigma_focal_px_median=float(np.median(u.sigma_intr_px[:, :2])) if u is not None else None)


def worker_k1(data: dict) -> dict:
    """The one-parameter model's best fit: from the truth with k2, p1, p2, k3 zeroed and held, k1 free."""
    from dome_calib.ba import BAOptions, ParamGroup, bundle_adjust

    problem = data["truth"].copy()
    problem.camera_params[:, 11:15] = 0.0
    problem.fix([ParamGroup.K2, ParamGroup.P1, ParamGroup.P2, ParamGroup.K3])
    t0 = time.perf_counter()
    res = bundle_adjust(problem, BAOptions(n_threads=2, compute_uncertainty=False))
    return dict(camera_params=res.problem.camera_params, points_cm=res.problem.points_cm, used=res.used,
                time_s=time.perf_counter() - t0, iterations=len(res.iterations), cost=res.cost,
                n_params=res.n_params, n_used=int(res.used.sum()), termination=res.termination)


def _colmap_reconstruction(problem, pycolmap):
    from dome_calib.camera import opencv_to_colmap_px

    rec = pycolmap.Reconstruction()
    order = np.argsort(problem.camera_index, kind="stable")
    starts = np.searchsorted(problem.camera_index[order], np.arange(problem.n_cameras + 1))
    point2d_idx = np.empty(problem.n_observations, dtype=np.int64)
    for i, cam in enumerate(problem.cameras):
        p = problem.camera_params[i]
        params = np.array([p[6], p[7], p[8] + 0.5, p[9] + 0.5, p[10], p[11], p[12], p[13], p[14], 0.0, 0.0, 0.0])
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model="FULL_OPENCV", width=cam.resolution[0],
                                                        height=cam.resolution[1], params=params, camera_id=i + 1))
        obs = order[starts[i]:starts[i + 1]]
        point2d_idx[obs] = np.arange(len(obs))
        image = pycolmap.Image(name=problem.camera_names[i], keypoints=opencv_to_colmap_px(problem.uv_px[obs]),
                               camera_id=i + 1, image_id=i + 1)
        from dome_calib.rotation import rotvec_to_matrix
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(rotvec_to_matrix(p[0:3])), p[3:6])
        rec.add_image_with_trivial_frame(image, pose)
    by_point = np.argsort(problem.point_index, kind="stable")
    pstarts = np.searchsorted(problem.point_index[by_point], np.arange(problem.n_points + 1))
    point_ids = np.zeros(problem.n_points, dtype=np.int64)
    for k in range(problem.n_points):
        obs = by_point[pstarts[k]:pstarts[k + 1]]
        if len(obs) < 2:
            continue
        track = pycolmap.Track([pycolmap.TrackElement(int(i) + 1, int(j))
                                for i, j in zip(problem.camera_index[obs], point2d_idx[obs])])
        point_ids[k] = rec.add_point3D(problem.points_cm[k], track)
    return rec, point_ids, point2d_idx


_CPU_S: list[float] = []  # CPU seconds (all threads) of each Ceres stage
PEER_TIME_LIMIT_S: float | None = None  # per stage; None = no limit (set by --peer-time-limit-s)


def _colmap_solve(rec, pycolmap, pyceres, loss: str, n_images: int, ftol: float) -> tuple[float, int, str]:
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_principal_point = True
    options.print_summary = False
    options.ceres.loss_function_type = getattr(pycolmap.LossFunctionType, loss)
    options.ceres.loss_function_scale = 2.0
    options.ceres.solver_options.num_threads = 2
    options.ceres.solver_options.function_tolerance = ftol  # same stopping rule as ours (COLMAP's default is 0)
    if PEER_TIME_LIMIT_S is not None:
        options.ceres.solver_options.max_solver_time_in_seconds = PEER_TIME_LIMIT_S
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in range(1, n_images + 1):
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    t0, c0 = time.perf_counter(), time.process_time()
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(options, config, rec)
    manifolds = []  # keep alive while the problem exists
    for cam_id in range(1, n_images + 1):
        params = rec.cameras[cam_id].params
        if adjuster.problem.has_parameter_block(params):
            m = pyceres.SubsetManifold(12, [9, 10, 11])
            adjuster.problem.set_manifold(params, m)
            manifolds.append(m)
    if len(manifolds) != n_images:
        raise RuntimeError(f"could hold k4..k6 on {len(manifolds)} of {n_images} cameras only")
    summary = adjuster.solve()
    elapsed = time.perf_counter() - t0
    _CPU_S.append(time.process_time() - c0)
    cs = summary.ceres_summary
    iterations = int(cs.num_successful_steps + cs.num_unsuccessful_steps)
    termination = str(cs.termination_type).split(".")[-1]
    del adjuster, manifolds
    return elapsed, iterations, termination


def _colmap_params(rec, problem, point_ids, pycolmap) -> tuple[np.ndarray, np.ndarray]:
    from dome_calib.rotation import matrix_to_rotvec

    cp = np.empty_like(problem.camera_params)
    for i in range(problem.n_cameras):
        q = np.asarray(rec.cameras[i + 1].params)
        if np.any(q[9:12] != 0.0):
            raise RuntimeError(f"k4..k6 of camera {i + 1} moved: {q[9:12]}")
        pose = rec.images[i + 1].cam_from_world()
        cp[i, 0:3] = matrix_to_rotvec(np.asarray(pose.rotation.matrix()))
        cp[i, 3:6] = np.asarray(pose.translation)
        cp[i, 6:15] = [q[0], q[1], q[2] - 0.5, q[3] - 0.5, q[4], q[5], q[6], q[7], q[8]]
    pts = problem.points_cm.copy()
    for k, pid in enumerate(point_ids):
        if pid and rec.exists_point3D(int(pid)):
            pts[k] = np.asarray(rec.points3D[int(pid)].xyz)
    return cp, pts


def worker_colmap(data: dict) -> dict:
    import pyceres
    import pycolmap

    from dome_calib.ba.evaluate import residuals
    from dome_calib.ba.robust import robust_sigma_px

    problem = data["start"]
    t_build = time.perf_counter()
    rec, point_ids, p2d = _colmap_reconstruction(problem, pycolmap)
    t_build = time.perf_counter() - t_build
    t1, it1, term1 = _colmap_solve(rec, pycolmap, pyceres, "HUBER", problem.n_cameras, 1e-3)
    cp, pts = _colmap_params(rec, problem, point_ids, pycolmap)
    # same rejection rule as ours: 5 x robust sigma, then least squares on the rest
    r = residuals(cp, pts, problem.camera_index, problem.point_index, problem.uv_px)
    err = np.linalg.norm(r, axis=1)
    thr = 5.0 * robust_sigma_px(r[np.isfinite(err)])
    bad = np.flatnonzero(~(err <= thr))
    t_rej = time.perf_counter()
    for m in bad:
        pid = int(point_ids[problem.point_index[m]])
        if pid and rec.exists_point3D(pid):
            rec.delete_observation(int(problem.camera_index[m] + 1), int(p2d[m]))
    t_rej = time.perf_counter() - t_rej
    t2, it2, term2 = _colmap_solve(rec, pycolmap, pyceres, "TRIVIAL", problem.n_cameras, 1e-7)
    cp, pts = _colmap_params(rec, problem, point_ids, pycolmap)
    used = np.ones(problem.n_observations, dtype=bool)
    used[bad] = False
    return dict(camera_params=cp, points_cm=pts, used=used, time_s=t1 + t_rej + t2, iterations=it1 + it2,
                build_s=t_build, stage_times_s=[t1, t2], stage_iterations=[it1, it2], rejected=int(len(bad)),
                termination=[term1, term2], time_limit_s_per_stage=PEER_TIME_LIMIT_S, cpu_s=sum(_CPU_S))


# ----------------------------------------------------------------------------------------------- metrics
def _similarity(src: np.ndarray, tgt: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity tgt ~ s R src + t (pycolmap's closed form)."""
    sim = pycolmap.estimate_sim3d(np.asarray(src, dtype=float), np.asarray(tgt, dtype=float))
    return float(sim.scale), np.asarray(sim.rotation.matrix()), np.asarray(sim.translation)


def _image_grid_px(wh: np.ndarray) -> np.ndarray:
    """(C, 33 * 25, 2) pixel grid over each image."""
    gx, gy = np.meshgrid(np.linspace(0, 1, 33), np.linspace(0, 1, 25))
    return np.stack([gx.ravel(), gy.ravel()], 1)[None] * (wh[:, None, :] - 1.0)


def _distortion_field_px(uv: np.ndarray, intr: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(C, G, 2) displacement (pixel - undistorted pixel) at pixels uv (C, G, 2); NaN where it does not invert."""
    from dome_calib.camera import pixels_to_normalized

    xn = pixels_to_normalized(uv, intr[:, None, :], dist[:, None, :])
    return uv - (xn * intr[:, None, 0:2] + intr[:, None, 2:4])


def observed_region(truth, is_outlier: np.ndarray) -> np.ndarray:
    """(C, G) bool: grid pixels inside the largest true normalised radius observed by each camera."""
    from dome_calib.camera import pixels_to_normalized

    p = truth.camera_params
    wh = np.array([cam.resolution for cam in truth.cameras], dtype=float)
    ok = ~is_outlier
    cam = truth.camera_index[ok]
    xn = pixels_to_normalized(truth.uv_px[ok], p[cam, 6:10], p[cam, 10:15])
    r = np.nan_to_num(np.linalg.norm(xn, axis=1))
    r_max = np.zeros(truth.n_cameras)
    np.maximum.at(r_max, cam, r)
    grid_xn = pixels_to_normalized(_image_grid_px(wh), p[:, None, 6:10], p[:, None, 10:15])
    return np.linalg.norm(grid_xn, axis=2) <= r_max[:, None]


def metrics(sol: dict, truth, is_outlier: np.ndarray, sigma_px: float, region: np.ndarray) -> dict:
    from dome_calib.ba.evaluate import residuals
    from dome_calib.rotation import rotvec_to_matrix

    cp, cp_t = sol["camera_params"], truth.camera_params
    R, R_t = rotvec_to_matrix(cp[:, 0:3]), rotvec_to_matrix(cp_t[:, 0:3])
    c = -np.einsum("cji,cj->ci", R, cp[:, 3:6])
    c_t = -np.einsum("cji,cj->ci", R_t, cp_t[:, 3:6])
    s, Ra, ta = _similarity(c, c_t)
    c_al = s * c @ Ra.T + ta
    cen_mm = 10.0 * np.linalg.norm(c_al - c_t, axis=1)
    R_al = R @ Ra.T
    cos = (np.einsum("cij,cij->c", R_al, R_t) - 1.0) / 2.0
    rot_deg = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    foc = 100.0 * np.abs(cp[:, 6:8] / cp_t[:, 6:8] - 1.0)
    wh = np.array([cam.resolution for cam in truth.cameras], dtype=float)
    grid = _image_grid_px(wh)
    d_all = np.linalg.norm(_distortion_field_px(grid, cp[:, 6:10], cp[:, 10:15])
                           - _distortion_field_px(grid, cp_t[:, 6:10], cp_t[:, 10:15]), axis=2)
    d_err = np.nanmax(np.where(region, d_all, 0.0), axis=1)  # over the observed part of each image
    r = residuals(cp, sol["points_cm"], truth.camera_index, truth.point_index, truth.uv_px)
    used = sol["used"]
    sq = np.sum(r * r, axis=1)
    n_params = int(sol.get("n_params", 0)) or (15 * len(cp) - 7 + 3 * truth.n_points)
    n_res = 2 * int(used.sum())
    rms = float(np.sqrt(np.nansum(sq[used]) / n_res))
    return dict(center_err_mm_median=float(np.median(cen_mm)), center_err_mm_max=float(cen_mm.max()),
                rot_err_deg_median=float(np.median(rot_deg)), rot_err_deg_max=float(rot_deg.max()),
                focal_err_pct_median=float(np.median(foc)), focal_err_pct_max=float(foc.max()),
                distortion_err_px_median=float(np.median(d_err)), distortion_err_px_max=float(np.max(d_err)),
                distortion_err_full_image_px_max=float(np.nanmax(d_all)),
                rms_px=rms, rms_over_sigma=rms / sigma_px,
                rms_over_sigma_expected=float(np.sqrt(1.0 - n_params / n_res)),
                cost_own=0.5 * float(np.nansum(sq[used])),
                cost_true_inliers=0.5 * float(np.nansum(sq[~is_outlier])),
                rms_over_sigma_true_inliers=float(np.sqrt(np.nansum(sq[~is_outlier]) / (2 * (~is_outlier).sum())))
                / sigma_px,
                outliers_rejected=int((~used & is_outlier).sum()), inliers_rejected=int((~used & ~is_outlier).sum()))


# ----------------------------------------------------------------------------------------------- driver
#: ``--double``: each camera's twin is the camera turned about the dome's vertical axis by this much (half the
#: real dome's median angle between neighbouring cameras, 4.3 deg, seen from its centre)
TWIN_TURN_DEG = 2.15


def twin_cameras(cameras: list) -> list:
    """The dome with panels twice as dense: every camera and its twin, the same camera (lens, resolution) turned
    rigidly by :data:`TWIN_TURN_DEG` about the vertical axis through the centroid of the camera centres (the
    Panoptic frame's y axis), so each twin sits between a camera and its neighbour and looks where they look."""
    import dataclasses

    from dome_calib.rotation import rotvec_to_matrix

    centre = np.mean([c.center_cm for c in cameras], axis=0)
    Q = rotvec_to_matrix(np.array([0.0, np.radians(TWIN_TURN_DEG), 0.0]))  # world turned: x' = Q (x - p) + p
    twins = []
    for c in cameras:
        R = c.R @ Q.T
        twins.append(dataclasses.replace(c, name=f"t{c.name}", R=R, t_cm=c.t_cm + c.R @ centre - R @ centre))
    return list(cameras) + twins


#: ``--pair``: the second dome stands this far along the world x axis from the first (one dome diameter: the two
#: spheres touch), each with its own scenes, its tents placed as the first dome's
PAIR_OFFSET_CM = 549.0
PAIR_SCENE_CENTRES_CM = ((0.0, 0.0, 0.0), (30.0, 0.0, -25.0), (-25.0, 0.0, 35.0))


def pair_cameras(cameras: list) -> tuple[list, np.ndarray]:
    """Two domes side by side: every camera, and its copy in a second dome turned 180 deg about the vertical axis
    through the centroid of the camera centres and moved :data:`PAIR_OFFSET_CM` along x (twice the panels at the
    same density; each camera still aimed at its own dome's centre). Also the rigid map (4, 4) of the first
    dome's world onto the second's, for its scenes."""
    import dataclasses

    centre = np.mean([c.center_cm for c in cameras], axis=0)
    Q = np.diag([-1.0, 1.0, -1.0])  # 180 deg about y
    shift = centre - Q @ centre + np.array([PAIR_OFFSET_CM, 0.0, 0.0])  # x' = Q x + shift
    copies = [dataclasses.replace(c, name=f"w{c.name}", R=c.R @ Q.T, t_cm=c.t_cm - c.R @ Q.T @ shift)
              for c in cameras]
    world = np.eye(4)
    world[:3, :3], world[:3, 3] = Q, shift
    return list(cameras) + copies, world


def make_data(small: bool, seed: int, double: bool = False, pair: bool = False) -> dict:
    from dome_calib.synth.ba_problem import SyntheticOptions, make_problem
    from dome_calib.panoptic_io import read_calibration

    cams, _ = read_calibration(CALIBRATION)
    names = sorted(cams)
    opts = SyntheticOptions(seed=seed)
    if small:
        names = names[::4]
        opts = SyntheticOptions(seed=seed, n_points=10_000, target_observations=100_000)
    cameras = [cams[n] for n in names]
    if double:  # the same points seen by twice the cameras: twice the observations
        cameras = twin_cameras(cameras)
        opts = dataclasses.replace(opts, target_observations=2 * opts.target_observations)
    if pair:  # twice the cameras, points and observations: each point seen by about as many cameras as before
        cameras, world = pair_cameras(cameras)
        second = [tuple(world[:3, :3] @ np.array(c) + world[:3, 3] * [1.0, 0.0, 1.0]) for c in PAIR_SCENE_CENTRES_CM]
        opts = dataclasses.replace(opts, n_scenes=6, scene_centres_cm=PAIR_SCENE_CENTRES_CM + tuple(second),
                                   n_points=2 * opts.n_points, target_observations=2 * opts.target_observations)
    sp = make_problem(cameras, opts)
    return dict(truth=sp.truth, start=sp.start, is_outlier=sp.is_outlier, noise_px=sp.noise_px)


def run_worker(kind: str, data_file: Path, out_file: Path, extra: list[str], reuse: bool = False) -> dict:
    info_file = out_file.with_suffix(".json")
    if reuse and out_file.exists() and info_file.exists():
        info = json.loads(info_file.read_text())
    else:
        cmd = [sys.executable, __file__, "--worker", kind, "--data", str(data_file), "--out", str(out_file), *extra]
        if PEER_TIME_LIMIT_S is not None:
            cmd += ["--peer-time-limit-s", str(PEER_TIME_LIMIT_S)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        out_file.with_suffix(".log").write_text(proc.stderr)
        if proc.returncode != 0:
            raise RuntimeError(f"worker {kind} failed:\n{proc.stderr[-3000:]}")
        info = json.loads(proc.stdout.strip().splitlines()[-1])
        info_file.write_text(json.dumps(info))
    sol = dict(np.load(out_file))
    sol.update(info)
    return sol


def _block_jacobi(matrix, groups: list[np.ndarray]):
    """The preconditioner v -> (the inverses of ``matrix``'s diagonal blocks over ``groups``) v."""
    inverses = [np.linalg.inv(matrix[g][:, g].toarray()) for g in groups]

    def precondition(v: np.ndarray) -> np.ndarray:
        out = np.empty_like(v)
        for g, inv in zip(groups, inverses):
            out[g] = inv @ v[g]
        return out
    return precondition


def _pcg(matrix, b: np.ndarray, precondition, rtol: float) -> tuple[np.ndarray, int]:
    """Conjugate gradients on ``matrix`` (sparse, symmetric) preconditioned by ``precondition`` (v -> M^-1 v);
    (solution, iterations) to a relative residual of ``rtol`` (iterations negative if it did not get there)."""
    import scipy.sparse.linalg as spla

    n = len(b)
    count = [0]
    x, info = spla.cg(matrix, b, rtol=rtol, maxiter=20 * n, callback=lambda _: count.__setitem__(0, count[0] + 1),
                      M=spla.LinearOperator((n, n), matvec=precondition))
    return x, count[0] if info == 0 else -count[0]


def _blocked_cholesky32(S: np.ndarray, members: list[np.ndarray], coupled: np.ndarray) -> dict:
    """A right-looking block Cholesky of the symmetric ``S`` (F, F) in single precision over the supernodes
    ``members`` (each an array of unknowns, in elimination order), forming and updating only the blocks that are
    not zero: ``coupled`` (B, B) bool, the supernodes whose unknowns share a point (their block of S is not zero);
    fill-in blocks are made as the elimination creates them. Returns the factor's blocks {(I, J): L_IJ}, I >= J."""
    import scipy.linalg
    from scipy.linalg.blas import strsm

    B = len(members)
    L: dict[tuple[int, int], np.ndarray] = {}
    below: list[set[int]] = [set() for _ in range(B)]  # each block column's rows below the diagonal
    for J in range(B):
        for I in range(J, B):
            if coupled[I, J]:
                L[I, J] = S[np.ix_(members[I], members[J])].astype(np.float32)
                if I > J:
                    below[J].add(I)
    for J in range(B):
        L[J, J] = scipy.linalg.cholesky(L[J, J], lower=True, overwrite_a=True, check_finite=False)
        rows = sorted(below[J])
        for I in rows:  # L_IJ = A_IJ L_JJ^-T
            L[I, J] = strsm(1.0, L[J, J], L[I, J], side=1, lower=1, trans_a=1)
        for a, I in enumerate(rows):
            for K in rows[:a + 1]:  # A_IK -= L_IJ L_KJ^T, K <= I (fill-in made here)
                if (I, K) not in L:
                    L[I, K] = np.zeros((len(members[I]), len(members[K])), dtype=np.float32)
                    below[K].add(I)
                L[I, K] -= L[I, J] @ L[K, J].T
    return L


def _blocked_solve32(L: dict, members: list[np.ndarray], b: np.ndarray) -> np.ndarray:
    """S x = b through the block factor of :func:`_blocked_cholesky32` (forward, then backward by blocks)."""
    from scipy.linalg import solve_triangular

    B = len(members)
    cols: list[list[int]] = [[] for _ in range(B)]
    for I, J in L:
        if I > J:
            cols[J].append(I)
    y = [b[m].astype(np.float32) for m in members]
    for J in range(B):
        y[J] = solve_triangular(L[J, J], y[J], lower=True, check_finite=False)
        for I in cols[J]:
            y[I] -= L[I, J] @ y[J]
    for J in reversed(range(B)):
        for I in cols[J]:
            y[J] -= L[I, J].T @ y[I]
        y[J] = solve_triangular(L[J, J], y[J], lower=True, trans="T", check_finite=False)
    x = np.empty(len(b))
    for m, v in zip(members, y):
        x[m] = v
    return x


def factorisers(sfm_pickle: str, repeat: int, candidates: set[str] | None = None, problem=None) -> None:
    """``--factorisers SFM_PKL``: the reduced camera system of an SfM result's problem (every parameter the problem
    frees, at its start, damping 1e-4) factorised and solved by each candidate, each ``repeat`` times (median):
    LAPACK's dense Cholesky (the dense path: float64; 2 BLAS threads from 1,500 unknowns, as the solver), CHOLMOD supernodal (scikit-sparse) under
    METIS and AMD orderings (the analysis once, the numeric factorisation timed, as the solver reuses it), cholespy
    (CHOLMOD behind a build-and-solve interface: analysis every time) and qdldl (a simplicial LDL^T, AMD); and
    preconditioned conjugate gradients on the sparse system (no factorisation: block-Jacobi over each camera's
    unknowns, or over each panel's, to a relative residual of 1e-10, the mixed-precision path's accuracy class;
    ``pcg_iterations``). ``candidates``: only those (default all). ``dense_float32``: the dense path's own
    single-precision factor (the solver's from 3,000 unknowns, refined by CG in double precision), its threads by
    :func:`dome_calib.ba.blas.cholesky_threads`, and the float64 one on those threads too. ``problem``: a generated
    problem instead of the SfM result's (``--factorisers generated [--pair | --double]``)."""
    import scipy.linalg
    import scipy.sparse as sp

    from dome_calib.ba import sparse
    from dome_calib.ba.blas import blas_threads, cholesky_threads
    from dome_calib.ba.evaluate import residuals_and_jacobians
    from dome_calib.ba.schur import build_structure, free_columns, linearize, sparse_reduced_system
    from dome_calib.ba.yyt import block_pattern

    if problem is None:
        with open(sfm_pickle, "rb") as fh:
            p = pickle.load(fh).problem
    else:
        p = problem
    st = build_structure(p.camera_index, p.point_index, np.ones(p.n_observations, dtype=bool), p.free, p.n_points)
    res, Jc, Jp = residuals_and_jacobians(p.camera_params, p.points_cm, st.cam, st.pt, p.uv_px[st.obs], n_threads=2)
    lin = linearize(st, res, Jc, Jp, np.ones(len(st.obs)), n_threads=2)
    del res, Jc, Jp
    t0 = time.perf_counter()
    layout = sparse._layout(st, free_columns(st), *block_pattern(st))
    t_layout = time.perf_counter() - t0
    blocks, rhs, _, _ = sparse_reduced_system(st, lin, 1e-4, layout, n_threads=2)
    lower = layout.matrix(blocks)
    d = 1.0 / np.sqrt(lower.diagonal())
    lower.data *= d[lower.indices] * d[layout.col]
    b = d * rhs[st.free_flat]
    F, A = layout.n_free, len(st.active_cameras)
    full = (lower + sp.tril(lower, -1).T).tocsc()
    timings: dict[str, list[float]] = {}
    solutions: dict[str, np.ndarray] = {}

    cpu: dict[str, list[float]] = {}

    def timed(name, fn):
        for _ in range(repeat):
            t, c = time.perf_counter(), time.process_time()
            x = fn()
            timings.setdefault(name, []).append(time.perf_counter() - t)
            cpu.setdefault(name, []).append(time.process_time() - c)
        solutions[name] = x

    def wanted(name: str) -> bool:
        return candidates is None or name in candidates or name.split("_")[0] in candidates

    iterations = {}
    threads = 2 if F >= 1500 else 1  # the solver's rule (dome_calib.ba.schur._PARALLEL_CHOLESKY_MIN)
    blocked: dict = {}
    if wanted("dense") or wanted("blocked"):  # the dense reference (float64), the dense path's float32
        dense = full.toarray()
        with blas_threads(cholesky_threads(F, np.float64, threads)):  # the float64 Cholesky's threads (blas.py)
            timed("dense_lapack", lambda: scipy.linalg.cho_solve(
                scipy.linalg.cho_factor(dense, check_finite=False), b, check_finite=False))
        dense32 = dense.astype(np.float32)
        del dense
        with blas_threads(cholesky_threads(F, np.float32, threads)):
            timed("dense_float32", lambda: scipy.linalg.cho_solve(scipy.linalg.cho_factor(
                dense32, check_finite=False), b.astype(np.float32), check_finite=False).astype(float))
            # the same single precision by blocks of cameras under METIS's order of the camera graph, forming only the
            # blocks that are not zero (a supernodal factor in dense storage: what the dome's sparsity saves in flops)
            camera_of_unknown = st.free_flat // 15
            a_of = np.repeat(np.arange(A), np.diff(layout.row_ptr))
            graph = sp.csc_matrix((np.ones(len(layout.cols)), (layout.cols, a_of)), shape=(A, A))  # lower, diagonal in
            order = sparse.cholmod.analyze(graph + sp.identity(A, format="csc") * A, mode="simplicial",
                                           ordering_method="metis").P() if wanted("blocked") else []
            for per in (16, 48) if wanted("blocked") else ():
                group = np.empty(A, dtype=np.int64)
                group[order] = np.arange(A) // per
                members = [np.flatnonzero(group[camera_of_unknown] == g) for g in range(group.max() + 1)]
                coupled = np.zeros((len(members), len(members)), dtype=bool)
                coupled[group[a_of], group[layout.cols]] = True
                coupled |= coupled.T
                factor_blocks = []

                def run_blocked():
                    L = _blocked_cholesky32(dense32, members, coupled)
                    factor_blocks.append(len(L))
                    return _blocked_solve32(L, members, b)

                timed(f"blocked_metis32_{per}", run_blocked)
                blocked[per] = dict(supernodes=len(members), factor_blocks=factor_blocks[-1],
                                    dense_blocks=len(members) * (len(members) + 1) // 2)
        del dense32
    del full
    strong_info: dict[str, dict] = {}
    full = ((lower + sp.tril(lower, -1).T).tocsc()
            if candidates is None or any(c.split("_")[0] in ("pcg", "cholespy", "qdldl") for c in candidates) else None)
    with blas_threads(threads):
        cholmod = sparse.cholmod
        fills = {}
        for ordering in ("metis", "amd") if wanted("cholmod") else ():
            symbolic = cholmod.analyze(lower, mode="supernodal", ordering_method=ordering)
            timed(f"cholmod_{ordering}", lambda: symbolic.cholesky(lower)(b))
            fills[ordering] = int(symbolic.cholesky(lower).L().nnz)
        camera_of = st.active_cameras[st.free_flat // 15]  # each free unknown's camera
        panel_of = np.array([n.split("_")[0] for n in p.camera_names])[camera_of]
        for name, key in (("pcg_camera", camera_of), ("pcg_panel", panel_of)):
            if wanted(name):
                pre = _block_jacobi(full, [np.flatnonzero(key == k) for k in np.unique(key)])
                timed(name, lambda: _pcg(full, b, pre, 1e-10)[0])
                iterations[name] = {f"{r:g}": _pcg(full, b, pre, r)[1] for r in (1e-4, 1e-6, 1e-10)}
        # the strong links only: CHOLMOD's factor of the system without the blocks of camera pairs sharing fewer than
        # k points (a ridge on the scaled diagonal if that is not positive definite), as CG's preconditioner
        shared = None
        for k_min in (20, 50):
            name = f"pcg_strong{k_min}"
            if not wanted(name):
                continue
            if shared is None:
                shared = _camera_graph(p.camera_index, p.point_index, p.n_cameras)[st.active_cameras][:, st.active_cameras].toarray()
            coo = lower.tocoo()
            ci, cj = st.free_flat[coo.row] // 15, st.free_flat[coo.col] // 15  # local cameras
            keep = (ci == cj) | (shared[ci, cj] >= k_min)
            strong = sp.csc_matrix((coo.data[keep], (coo.row[keep], coo.col[keep])), shape=lower.shape)
            del coo, ci, cj, keep
            symbolic = cholmod.analyze(strong, mode="supernodal", ordering_method="amd")
            ridge_used = None
            for ridge in (0.0, 1e-6, 1e-4, 1e-2, 1e-1):
                try:
                    factor = symbolic.cholesky(strong, beta=ridge)
                    ridge_used = ridge
                    break
                except cholmod.CholmodNotPositiveDefiniteError:
                    continue
            if ridge_used is None:
                continue
            counts: list[int] = []

            def run_strong():
                x, n = _pcg(full, b, factor, 1e-10)
                counts.append(n)
                return x

            timed(name, run_strong)
            iterations[name] = {"1e-06": _pcg(full, b, factor, 1e-6)[1], "1e-10": counts[-1]}
            strong_info[name] = dict(kept_nonzeros=int(strong.nnz), factor_nonzeros=int(factor.L().nnz),
                                     ridge=ridge_used)
            t = time.process_time()
            symbolic.cholesky(strong, beta=ridge_used)
            strong_info[name]["factorise_cpu_s"] = round(time.process_time() - t, 2)
            del strong, factor
    if wanted("cholespy"):
        import cholespy

        coo = full.tocoo()
        rows, cols = coo.row.astype(np.int32), coo.col.astype(np.int32)

        def cholespy_solve():
            solver = cholespy.CholeskySolverD(F, rows, cols, coo.data, cholespy.MatrixType.COO)
            x = np.zeros_like(b)
            solver.solve(b.copy(), x)
            return x

        timed("cholespy", cholespy_solve)
    if wanted("qdldl"):
        import qdldl

        upper = sp.triu(full).tocsc()
        timed("qdldl", lambda: qdldl.Solver(upper).solve(b))
    ref = solutions.get("dense_lapack")
    emit({"bench": "ba_factorisers", "problem": sfm_pickle, "n_observations": int(p.n_observations), "cameras": A, "unknowns": F,
          "camera_blocks": len(layout.cols), "camera_blocks_dense": A * (A + 1) // 2,
          "lower_nonzeros": int(lower.nnz), "factor_nonzeros": fills, "blocked": blocked, "strong": strong_info, "layout_s": round(t_layout, 3),
          "seconds_median": {k: round(float(np.median(v)), 4) for k, v in timings.items()},
          "cpu_seconds_median": {k: round(float(np.median(v)), 4) for k, v in cpu.items()},
          "pcg_iterations": iterations,
          "max_rel_diff_from_dense": {k: float(np.abs(x - ref).max() / np.abs(ref).max()) for k, x in solutions.items()}
          if ref is not None else None,
          "load_average_1min": round(os.getloadavg()[0], 1), "peak_rss_gb": round(peak_rss_gb(), 2),
          "commit": _commit()})


def iteration_cost(args) -> None:
    """``--iteration-cost``: one Levenberg-Marquardt iteration of the solver's dense path on the generated problem
    (``--double``: 1,040 cameras), its parts timed in CPU seconds (the Jacobians, the blocks, the reduced system with
    the inner constraints, its solve and the points' step), ``--repeat`` times on the same kept buffers (median),
    per camera; and the process's peak memory. A stage-level measure where a whole solve is too long to run."""
    from dome_calib.ba.blas import blas_threads
    from dome_calib.ba.evaluate import residuals_and_jacobians
    from dome_calib.ba.gauge import inner_constraint_basis
    from dome_calib.ba.schur import Workspace, buffer, build_reduced_system, build_structure, linearize, solve_reduced

    t0 = time.perf_counter()
    problem = make_data(args.small, args.seed, args.double, args.pair)["start"]
    emit(dict(bench="ba", what="problem", cameras=problem.n_cameras, observations=problem.n_observations,
              points=problem.n_points, generate_s=round(time.perf_counter() - t0, 1)))
    st = build_structure(problem.camera_index, problem.point_index, np.ones(problem.n_observations, dtype=bool),
                         problem.free, problem.n_points, Workspace())
    M = len(st.obs)
    parts: dict[str, list[float]] = {}

    walls: dict[str, list[float]] = {}

    def timed(name, fn):
        c, w = time.process_time(), time.perf_counter()
        out = fn()
        parts.setdefault(name, []).append(time.process_time() - c)
        walls.setdefault(name, []).append(time.perf_counter() - w)
        return out

    with blas_threads(1):
        for _ in range(args.repeat):
            res, Jc, Jp = timed("jacobians", lambda: residuals_and_jacobians(
                problem.camera_params, problem.points_cm, st.cam, st.pt, problem.uv_px[st.obs], n_threads=2,
                out=(buffer(st, "res", (2, M)), buffer(st, "Jc", (2, 15, M)), buffer(st, "Jp", (2, 3, M)))))
            lin = timed("blocks", lambda: linearize(st, res, Jc, Jp, np.ones(M), n_threads=2))
            basis = inner_constraint_basis(problem.camera_params[st.active_cameras], st.free, lin.D_c)
            system = timed("reduced_system", lambda: build_reduced_system(st, lin, 1e-4, n_threads=2,
                                                                           gauge_basis=basis))
            timed("solve_and_point_step", lambda: solve_reduced(st, lin, system, 1e-4, n_threads=2))
            del system, lin, res, Jc, Jp
    median = {k: float(np.median(v)) for k, v in parts.items()}
    total = sum(median.values())
    emit(dict(bench="ba", what="iteration_cost", cameras=problem.n_cameras, unknowns=len(st.free_flat),
              observations=M, cpu_s={k: round(v, 2) for k, v in median.items()}, cpu_s_total=round(total, 2),
              cpu_ms_per_camera=round(1e3 * total / problem.n_cameras, 2),
              wall_s={k: round(float(np.median(v)), 2) for k, v in walls.items()}, repeat=args.repeat,
              peak_rss_gb=round(peak_rss_gb(), 2), load_average_1min=round(os.getloadavg()[0], 1)))


class _Phases:
    """CPU seconds, minor page faults and calls of the solver's parts, each wrapped where the solver looks it up
    (inclusive: a part called inside another counts in both)."""

    def __init__(self) -> None:
        self.cpu: dict[str, float] = {}
        self.faults: dict[str, int] = {}
        self.calls: dict[str, int] = {}
        self.faults_per_call: dict[str, list[int]] = {}

    def wrap(self, module, attr: str, name: str) -> None:
        fn = getattr(module, attr)

        def wrapped(*a, **k):
            c, f = time.process_time(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            try:
                return fn(*a, **k)
            finally:
                self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - c
                df = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f
                self.faults[name] = self.faults.get(name, 0) + df
                self.faults_per_call.setdefault(name, []).append(df)
                self.calls[name] = self.calls.get(name, 0) + 1

        setattr(module, attr, wrapped)

    def log(self, file) -> None:
        """The figures so far, one JSON line (a run that cannot finish still tells its cost per reduced system)."""
        print(json.dumps(dict(cpu_s=round(time.process_time(), 1), phases_cpu_s={k: round(v, 1) for k, v in
                                                                                sorted(self.cpu.items())},
                              phases_calls=dict(sorted(self.calls.items())), peak_rss_gb=peak_rss_gb(),
                              minor_faults=resource.getrusage(resource.RUSAGE_SELF).ru_minflt)), file=file, flush=True)


def _thp_faults() -> dict[str, int]:
    """The kernel's transparent-huge-page fault counters (machine-wide: other processes' count too)."""
    with open("/proc/vmstat") as fh:
        return {k: int(v) for k, v in (line.split() for line in fh) if k in ("thp_fault_alloc", "thp_fault_fallback")}


def worker_phases(data: dict, huge_pages: bool = True) -> dict:
    """A whole solve (``bundle_adjust`` from the perturbed start, then the uncertainties) with its parts timed in
    CPU seconds and counted in minor page faults (:class:`_Phases`). ``huge_pages`` False: numpy does not advise
    the kernel to back its large arrays by 2 MB pages (a diagnostic: every fault is then one 4 kB page, so the
    count no longer depends on how many huge pages the machine's memory could give at that moment)."""
    from dome_calib.ba import schur, solver
    from dome_calib.ba import BAOptions, bundle_adjust, solution_uncertainty

    if not huge_pages:
        from numpy._core.multiarray import _set_madvise_hugepage
        _set_madvise_hugepage(False)
    thp0 = _thp_faults()

    ph = _Phases()
    for module, attr, name in ((solver, "residuals_and_jacobians", "jacobians"), (solver, "linearize", "blocks"),
                               (solver, "_cost", "cost"), (solver, "build_structure", "structure"),
                               (solver, "build_reduced_system", "reduced_system"),
                               (schur, "_eliminate", "reduced_system.points_eliminated"),
                               (schur, "subtract_yyt", "reduced_system.yyt"),
                               (schur, "subtract_yyt_blocks", "reduced_system.yyt"),
                               (solver, "solve_reduced", "solve"), (schur, "solve_free", "solve.factorisation"),
                               (schur, "solve_sparse", "solve.factorisation"),
                               (schur, "point_step", "solve.point_step")):
        ph.wrap(module, attr, name)
    solve = solver.solve_reduced

    def solve_and_log(*a, **k):
        out = solve(*a, **k)
        ph.log(sys.stderr)
        return out

    solver.solve_reduced = solve_and_log
    problem = data["start"]
    usage0 = resource.getrusage(resource.RUSAGE_SELF)
    c0 = time.process_time()
    res = bundle_adjust(problem, BAOptions(n_threads=2, compute_uncertainty=False))
    cpu = time.process_time() - c0
    usage1 = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps(dict(solve_cpu_s=round(cpu, 1), iterations=len(res.iterations), peak_rss_gb=peak_rss_gb(),
                          minor_faults=usage1.ru_minflt - usage0.ru_minflt,
                          phases_cpu_s={k: round(v, 1) for k, v in sorted(ph.cpu.items())},
                          phases_calls=dict(sorted(ph.calls.items())))), file=sys.stderr, flush=True)
    c1 = time.process_time()
    solution_uncertainty(res, n_threads=2)
    cpu_unc = time.process_time() - c1
    usage2 = resource.getrusage(resource.RUSAGE_SELF)
    C = problem.n_cameras
    return dict(camera_params=res.problem.camera_params, points_cm=res.problem.points_cm, used=res.used,
                cameras=C, observations=problem.n_observations, iterations=len(res.iterations),
                reduced_systems=ph.calls.get("reduced_system", 0), factorisations=ph.calls.get("solve", 0),
                termination=res.termination, cpu_s=round(cpu, 1), cpu_ms_per_camera=round(1e3 * cpu / C, 1),
                system_s=round(usage1.ru_stime - usage0.ru_stime, 1), minor_faults=usage1.ru_minflt - usage0.ru_minflt,
                uncertainty_cpu_s=round(cpu_unc, 1), uncertainty_minor_faults=usage2.ru_minflt - usage1.ru_minflt,
                phases_cpu_s={k: round(v, 1) for k, v in sorted(ph.cpu.items())},
                phases_minor_faults=dict(sorted(ph.faults.items())), phases_calls=dict(sorted(ph.calls.items())),
                phases_minor_faults_first_call={k: v[0] for k, v in sorted(ph.faults_per_call.items())},
                phases_minor_faults_later_median={k: int(np.median(v[1:])) for k, v in sorted(ph.faults_per_call.items())
                                                  if len(v) > 1},
                huge_pages_advised=huge_pages,
                thp_faults_machine={k: v - thp0[k] for k, v in _thp_faults().items()},
                load_average_1min=round(os.getloadavg()[0], 1))


def solve_phases(args) -> None:
    """``--solve-phases``: :func:`worker_phases` on the generated problem, in a child process (its peak memory is
    the solve's and the problem's only)."""
    t0 = time.perf_counter()
    data = make_data(args.small, args.seed, args.double, args.pair)
    emit(dict(bench="ba", what="problem", cameras=data["start"].n_cameras, observations=data["start"].n_observations,
              points=data["start"].n_points, generate_s=round(time.perf_counter() - t0, 1)))
    with tempfile.TemporaryDirectory(prefix="bench_ba_") as tmp:
        tmp = args.workdir or tmp
        Path(tmp).mkdir(parents=True, exist_ok=True)
        data_file = Path(tmp) / "data.pkl"
        with open(data_file, "wb") as fh:
            pickle.dump(dict(start=data["start"]), fh, protocol=pickle.HIGHEST_PROTOCOL)
        del data
        out_file = Path(tmp) / "phases.npz"
        cmd = [sys.executable, __file__, "--worker", "phases", "--data", str(data_file), "--out", str(out_file)]
        with open(out_file.with_suffix(".log"), "w") as log:  # the solver's iterations, live
            proc = subprocess.run(cmd + (["--no-huge-pages"] if args.no_huge_pages else []), stdout=subprocess.PIPE,
                                  stderr=log, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"worker phases failed: see {out_file.with_suffix('.log')}")
        info = json.loads(proc.stdout.strip().splitlines()[-1])
    emit(dict(bench="ba", what="solve_phases", layout="twin" if args.double else "pair" if args.pair else "dome", commit=_commit(), **info))


def _camera_graph(camera_index: np.ndarray, point_index: np.ndarray, n_cameras: int):
    """Shared points per camera pair: the (C, C) integer matrix K K^T (CSR) of the camera-point incidence K (a
    point seen twice by one camera counts once)."""
    import scipy.sparse as sp

    K = sp.csr_matrix((np.ones(len(camera_index), dtype=np.int64), (camera_index, point_index)),
                      shape=(n_cameras, int(point_index.max()) + 1))
    K.data[:] = 1  # duplicates summed by the constructor: back to incidence
    return (K @ K.T).tocsr()


def sparsity(args) -> None:
    """``--sparsity``: how sparse the reduced camera system is. Per layout (the dome, ``--pair``, ``--double``; or an
    SfM result's problem, ``--sfm SFM_PKL``): the camera pairs that share at least k points (k = 1: the blocks of S
    that are not zero), and the factor's fill under several fill-reducing orderings (natural; reverse Cuthill-McKee,
    scipy; AMD, COLAMD, METIS nested dissection, CHOLMOD's own nested dissection, through CHOLMOD's analysis; gtsam's
    COLAMD and METIS on the camera graph as a symbolic factor graph), counted
    in camera blocks against the dense triangle, with the block factorisation's flops against the dense one's; and
    the same with only the pairs sharing at least k points kept (what a factorisation that dropped the weak links,
    e.g. as a preconditioner, would fill). Symbolic only: no values, seconds per layout."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    from dome_calib.ba.sparse import block_factor_counts

    try:
        import sksparse.cholmod as cholmod
    except ImportError:  # the optional extra `sparse`
        cholmod = None
    try:
        import gtsam
    except ImportError:  # pragma: no cover - a base dependency
        gtsam = None
    if args.sfm:
        with open(args.sfm, "rb") as fh:
            p = pickle.load(fh).problem
        layout = "sfm:" + Path(args.sfm).parent.parent.name
    else:
        p = make_data(args.small, args.seed, args.double, args.pair)["start"]
        layout = "twin" if args.double else "pair" if args.pair else "dome"
    t0 = time.process_time()
    shared = _camera_graph(p.camera_index, p.point_index, p.n_cameras)
    C = p.n_cameras
    dense = C * (C + 1) // 2
    off = sp.triu(shared, 1).tocsr()
    shared_counts = off.data  # shared points of each pair that shares one
    pairs = C * (C - 1) // 2
    for k in (1, 2, 5, 10, 20, 50):
        kept = off.copy()
        kept.data = (kept.data >= k).astype(np.int8)
        kept.eliminate_zeros()
        graph = (kept + kept.T + sp.identity(C, dtype=np.int8, format="csr")).tocsc()
        row = dict(bench="ba", what="sparsity", layout=layout, cameras=C, observations=p.n_observations,
                   min_shared_points=k, pairs_kept=int(kept.nnz), pairs_kept_share=round(kept.nnz / pairs, 4),
                   blocks_share=round((kept.nnz + C) / dense, 4))
        orders = {"natural": np.arange(C), "rcm": reverse_cuthill_mckee(graph.tocsr(), symmetric_mode=True)}
        if cholmod is not None:
            lower = sp.tril(graph.astype(float) * 1.0 + sp.identity(C, format="csc") * C, format="csc")
            for method in ("amd", "colamd", "metis", "nesdis"):
                orders[method] = cholmod.analyze(lower, mode="simplicial", ordering_method=method).P()
        if gtsam is not None:  # gtsam's orderings on the camera graph (a base dependency)
            fg = gtsam.SymbolicFactorGraph()
            for c in range(C):
                fg.push_factor(c)
            for i, j in zip(*kept.nonzero()):
                fg.push_factor(int(i), int(j))
            for method in ("Colamd", "Metis"):
                o = getattr(gtsam.Ordering, f"{method}SymbolicFactorGraph")(fg)
                orders[f"gtsam_{method.lower()}"] = np.array([o.at(i) for i in range(o.size())])
        upper = sp.triu(graph).tocsr()  # the block pattern as dome_calib.ba.sparse reads it (diagonal first)
        dense_flops = float(np.sum(np.arange(C, dtype=float) ** 2))
        for name, order in orders.items():
            counts = block_factor_counts(upper.indptr, upper.indices, np.asarray(order))
            row[f"fill_{name}"] = round(int(counts.sum()) / dense, 4)
            row[f"flops_{name}"] = round(float(np.sum((counts - 1.0) ** 2)) / dense_flops, 4)
        emit(row)
        if k == 1 and args.small:
            break
    q = np.percentile(shared_counts, [10, 25, 50, 75, 90]) if len(shared_counts) else []
    emit(dict(bench="ba", what="sparsity_shared_points", layout=layout, cameras=C,
              shared_points_percentiles_10_25_50_75_90=[float(v) for v in q],
              cpu_s=round(time.process_time() - t0, 1), commit=_commit(),
              load_average_1min=round(os.getloadavg()[0], 1)))


def _commit() -> str:
    return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--small", action="store_true", help="quick run: 130 cameras, 10k points, ~100k observations")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--double", action="store_true", help="the dome with panels twice as dense (1,040 cameras: "
                    "each camera and a twin turned 2.15 deg about the vertical axis), twice the observations of the "
                    "same points")
    ap.add_argument("--pair", action="store_true", help="two domes side by side (1,040 cameras: a copy of the dome "
                    "turned 180 deg and moved one diameter along x), each with its own three scenes: twice the points "
                    "and observations, each point seen by about as many cameras as in one dome")
    ap.add_argument("--skip-peer", action="store_true", help="do not run pycolmap's Ceres BA")
    ap.add_argument("--worker", choices=["ours", "oracle", "colmap", "k1", "phases"], help=argparse.SUPPRESS)
    ap.add_argument("--data", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--workdir", help="keep the problem and solutions in this folder (default: a temp folder)")
    ap.add_argument("--only", help="comma-separated subset of ours,oracle,colmap,k1 (--factorisers: of dense, cholmod, "
                    "pcg_camera, pcg_panel, pcg_strong20, pcg_strong50, blocked, cholespy, qdldl; dense always runs, the reference)")
    ap.add_argument("--ba-options", default="{}", help="ours and oracle: BAOptions fields as JSON, e.g. "
                    "'{\"shorten_rejected_steps\": false}' (the solver's earlier rule, to compare in the same run)")
    ap.add_argument("--tag", default="", help="suffix of the solutions' files in --workdir (runs side by side)")
    ap.add_argument("--reuse", action="store_true", help="reuse solutions already in --workdir (same seed/size)")
    ap.add_argument("--load", action="store_true",
                    help="run two CPU-bound processes beside every solver (a busy 2-core machine)")
    ap.add_argument("--peer-time-limit-s", type=float, default=PEER_TIME_LIMIT_S,
                    help="cap on each of the two Ceres stages (s); default: none")
    ap.add_argument("--factorisers", metavar="SFM_PKL", help="only the candidate factorisations of the reduced camera "
                    "system of an SfM result's problem (a calibrate work folder's sfm.pkl; 'generated': this bench's problem, with "
                    "--pair or --double)")
    ap.add_argument("--repeat", type=int, default=3, help="--factorisers, --iteration-cost: runs of each (median)")
    ap.add_argument("--iteration-cost", action="store_true", help="only one LM iteration's parts on the generated "
                    "problem (CPU seconds per camera, peak memory; with --double: 1,040 cameras)")
    ap.add_argument("--solve-phases", action="store_true", help="only our whole solve and its uncertainties (in a "
                    "child process): iterations, reduced systems, CPU seconds and minor page faults of each part, "
                    "per camera, peak memory")
    ap.add_argument("--no-huge-pages", action="store_true", help="--solve-phases: numpy's large arrays not advised "
                    "to 2 MB pages (every page fault one 4 kB page: counts comparable between runs)")
    ap.add_argument("--sparsity", action="store_true", help="only how sparse the reduced camera system is: camera "
                    "pairs sharing points and the factor's fill under fill-reducing orderings (symbolic; with --pair, "
                    "--double or --sfm)")
    ap.add_argument("--sfm", metavar="SFM_PKL", help="--sparsity: an SfM result's problem instead of the generated one")
    args = ap.parse_args()
    globals()["PEER_TIME_LIMIT_S"] = args.peer_time_limit_s
    if args.sparsity:
        sparsity(args)
        return
    if args.solve_phases:
        solve_phases(args)
        return
    if args.iteration_cost:
        iteration_cost(args)
        return
    if args.factorisers:
        generated = (make_data(args.small, args.seed, args.double, args.pair)["start"]
                     if args.factorisers == "generated" else None)
        factorisers(args.factorisers, args.repeat, set(args.only.split(",")) if args.only else None, generated)
        return
    if args.worker:
        import logging
        logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
        with open(args.data, "rb") as fh:
            data = pickle.load(fh)
        if args.worker == "ours":
            out = worker_ours(data, "start", json.loads(args.ba_options))
        elif args.worker == "oracle":
            out = worker_ours(data, "truth", json.loads(args.ba_options))
        elif args.worker == "k1":
            out = worker_k1(data)
        elif args.worker == "phases":
            out = worker_phases(data, huge_pages=not args.no_huge_pages)
        else:
            out = worker_colmap(data)
        arrays = {k: out.pop(k) for k in ("camera_params", "points_cm", "used")}
        np.savez(args.out, **arrays)
        out["peak_rss_gb"] = peak_rss_gb()
        print(json.dumps(out))
        return
    t0 = time.perf_counter()
    load = start_load(2) if args.load else []
    try:
        run_all(args, t0)
    finally:
        for proc in load:
            proc.kill()


LOAD_SCRIPT = ("import numpy as np\n"
               "a = np.random.default_rng(0).random(1 << 20)\n"
               "while True:\n"
               "    a = np.sqrt(a * a + 1.0) - 0.5\n")


def start_load(n: int) -> list[subprocess.Popen]:
    """``n`` single-threaded CPU-bound processes (numpy element-wise loops), killed when the bench ends."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    procs = [subprocess.Popen([sys.executable, "-c", LOAD_SCRIPT], env=env) for _ in range(n)]
    emit(dict(bench="ba", what="load", processes=n, pids=[p.pid for p in procs]))
    return procs


def run_all(args, t0: float) -> None:
    data = make_data(args.small, args.seed, args.double, args.pair)
    truth, is_outlier, sigma = data["truth"], data["is_outlier"], data["noise_px"]
    emit(dict(bench="ba", what="problem", cameras=truth.n_cameras, scenes=len(truth.scene_names),
              points=truth.n_points, observations=truth.n_observations, outliers=int(is_outlier.sum()),
              noise_px=sigma, generate_s=round(time.perf_counter() - t0, 1)))
    with tempfile.TemporaryDirectory(prefix="bench_ba_") as tmp:
        tmp = args.workdir or tmp
        Path(tmp).mkdir(parents=True, exist_ok=True)
        data_file = Path(tmp) / "data.pkl"
        if not (args.reuse and data_file.exists()):
            with open(data_file, "wb") as fh:
                pickle.dump(data, fh, protocol=pickle.HIGHEST_PROTOCOL)
        runs = {}
        region = observed_region(truth, is_outlier)
        start_m = metrics(dict(camera_params=data["start"].camera_params, points_cm=data["start"].points_cm,
                               used=~is_outlier), truth, is_outlier, sigma, region)
        emit(dict(bench="ba", what="start", **{k: round(v, 4) for k, v in start_m.items()
                                               if k.startswith(("center", "rot", "focal", "distortion"))}))
        kinds = ["ours"] + ([] if args.skip_peer else ["colmap"]) + ["oracle", "k1"]
        if args.only:
            kinds = [k for k in kinds if k in args.only.split(",")]
        for kind in kinds:
            extra = ["--ba-options", args.ba_options] if kind in ("ours", "oracle") else []
            sol = run_worker(kind, data_file, Path(tmp) / f"{kind}{args.tag}.npz", extra, reuse=args.reuse)
            m = metrics(sol, truth, is_outlier, sigma, region)
            runs[kind] = (sol, m)
            info = {k: v for k, v in sol.items() if k not in ("camera_params", "points_cm", "used")}
            line = dict(bench="ba", what=kind, **info, **m, load=args.load,
                        load_average_1min=round(os.getloadavg()[0], 2))
            emit({k: (round(v, 6) if isinstance(v, float) else v) for k, v in line.items()})
    if not {"ours", "oracle", "k1"} <= set(runs):
        return
    ours, oracle = runs["ours"][1], runs["oracle"][1]
    from dome_calib.ba.evaluate import residuals

    common = runs["ours"][0]["used"] & runs["oracle"][0]["used"]

    def common_cost(sol):
        r = residuals(sol["camera_params"], sol["points_cm"], truth.camera_index[common], truth.point_index[common],
                      truth.uv_px[common])
        return 0.5 * float(np.sum(r * r))

    ratios = dict(bench="ba", what="ratios",
                  cost_common_ours_over_oracle=common_cost(runs["ours"][0]) / common_cost(runs["oracle"][0]),
                  cost_own_ours_over_oracle=ours["cost_own"] / oracle["cost_own"],
                  cost_true_inliers_ours_over_oracle=ours["cost_true_inliers"] / oracle["cost_true_inliers"],
                  rms_over_sigma_vs_expected=ours["rms_over_sigma"] / ours["rms_over_sigma_expected"])
    for k in ("center_err_mm_median", "center_err_mm_max", "rot_err_deg_median", "focal_err_pct_median",
              "distortion_err_px_max"):
        ratios[f"{k}_ours_over_oracle"] = ours[k] / oracle[k]
    if "colmap" in runs:
        col_sol, col = runs["colmap"]
        ratios["time_ours_over_colmap"] = runs["ours"][0]["time_s"] / col_sol["time_s"]
        ratios["time_ours_with_uncertainty_over_colmap"] = ((runs["ours"][0]["time_s"] + runs["ours"][0]["uncertainty_s"])
                                                            / col_sol["time_s"])
        ratios["cost_true_inliers_colmap_over_oracle"] = col["cost_true_inliers"] / oracle["cost_true_inliers"]
        ratios["cost_common_colmap_over_oracle"] = common_cost(col_sol) / common_cost(runs["oracle"][0])
        ratios["center_err_mm_median_colmap_over_oracle"] = col["center_err_mm_median"] / oracle["center_err_mm_median"]
    k1 = runs["k1"][1]
    ratios["k1_only_rms_over_sigma"] = k1["rms_over_sigma"]
    ratios["k1_only_rms_over_sigma_true_inliers"] = k1["rms_over_sigma_true_inliers"]
    ratios["ours_rms_over_sigma_true_inliers"] = ours["rms_over_sigma_true_inliers"]
    emit({k: (round(v, 5) if isinstance(v, float) else v) for k, v in ratios.items()})
    emit(dict(bench="ba", what="total", wall_s=round(time.perf_counter() - t0, 1), load=args.load,
              load_average_1min=round(os.getloadavg()[0], 2)))


if __name__ == "__main__":
    main()
