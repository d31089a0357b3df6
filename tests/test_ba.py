"""Bundle adjustment (dome_calib.ba): exactness, gauge, fixed parameters, outliers, Jacobian assembly."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pycolmap
import pytest

from dome_calib.align import sim3_apply
from dome_calib.ba import BAOptions, BAProblem, BAProblemError, GaugeMode, ParamGroup, bundle_adjust
from dome_calib.ba.evaluate import residuals, residuals_and_jacobians
from dome_calib.ba.gauge import choose_gauge
from dome_calib.ba.schur import build_structure, linearize, solve_step
from dome_calib.synth.ba_problem import SyntheticOptions, make_problem
from dome_calib.bundle import Bundle
from dome_calib.camera import project_with_jacobians
from dome_calib.panoptic_io import read_calibration

CALIBRATION = Path(__file__).parent / "data/panoptic/calibration_160906_band1.json"
#: 12 real cameras: VGA from several panels, HD and one Kinect colour camera.
NAMES = ["01_01", "03_05", "05_12", "07_20", "09_03", "11_08", "13_15", "16_02", "18_10", "00_03", "00_17", "50_02"]


@pytest.fixture(scope="module")
def cameras():
    cams, _ = read_calibration(CALIBRATION)
    return [cams[n] for n in NAMES]


def small(cameras, **kw) -> "object":
    opts = dict(n_points=600, target_observations=5000, noise_px=0.0, outlier_fraction=0.0, seed=3)
    opts.update(kw)
    return make_problem(cameras, SyntheticOptions(**opts))


def quick(**kw) -> BAOptions:
    return BAOptions(**{"n_threads": 1, "compute_uncertainty": False, **kw})


def test_noise_free_problem_is_solved_exactly(cameras):
    sp = small(cameras)
    res = bundle_adjust(sp.start, quick(outlier_rounds=0, loss="trivial", function_tolerance=1e-14,
                                        max_iterations=100))
    assert res.rms_px < 1e-6
    assert np.all(res.used)


def test_gauge_is_held_and_solution_does_not_move_when_rerun(cameras):
    sp = small(cameras, noise_px=0.5)
    res = bundle_adjust(sp.start, quick(outlier_rounds=0, loss="trivial", function_tolerance=1e-12,
                                        gauge="two_cameras"))
    gauge = res.gauge
    assert not gauge.inner
    a = sp.start.camera_position(gauge.reference_camera)
    b = sp.start.camera_position(gauge.scale_camera)
    assert np.array_equal(res.problem.camera_params[a, 0:6], sp.start.camera_params[a, 0:6])
    assert res.problem.camera_params[b, 3 + gauge.scale_component] == sp.start.camera_params[b, 3 + gauge.scale_component]
    again = bundle_adjust(res.problem, quick(outlier_rounds=0, loss="trivial", function_tolerance=1e-12,
                                             gauge_reference_camera=gauge.reference_camera,
                                             gauge_scale_camera=gauge.scale_camera))
    centers = lambda p: np.array([p.camera(n).center_cm for n in p.camera_names])  # noqa: E731
    assert np.abs(centers(again.problem) - centers(res.problem)).max() < 1e-5  # cm (0.1 micrometre)
    assert np.abs(again.problem.points_cm - res.problem.points_cm).max() < 1e-5  # cm
    assert again.cost <= res.cost * (1 + 1e-9)


def _centers(p):
    return np.array([p.camera(n).center_cm for n in p.camera_names])


def test_inner_constraint_gauge_reaches_the_held_gauge_solution(cameras):
    """Mode auto without held poses: the 7 similarity directions are constrained in the solve, no camera is held.
    Same minimum as the two-camera gauge, a similarity apart (same cost, aligned centres and points, the same
    centre uncertainties in the centroid gauge up to the scale), in no more iterations."""
    sp = small(cameras, noise_px=0.5)
    p = sp.start
    opts = dict(outlier_rounds=0, loss="trivial", function_tolerance=1e-12, compute_uncertainty=True)
    inner = bundle_adjust(p, quick(**opts))
    held = bundle_adjust(p, quick(**opts, gauge="two_cameras"))
    assert inner.gauge.inner and "inner constraints" in inner.gauge.describe() and not held.gauge.inner
    assert abs(inner.cost - held.cost) <= 1e-9 * held.cost
    sim = pycolmap.estimate_sim3d(_centers(inner.problem), _centers(held.problem))  # least squares, held <- inner
    assert np.abs(sim3_apply(sim, _centers(inner.problem)) - _centers(held.problem)).max() < 1e-4  # cm (1 um)
    live = np.bincount(p.point_index, minlength=p.n_points) >= 2  # points seen once are not refined
    pts = sim3_apply(sim, inner.problem.points_cm[live])
    assert np.abs(pts - held.problem.points_cm[live]).max() < 1e-4  # cm
    spread = lambda r: np.linalg.norm(r.uncertainty.sigma_center_centroid_cm, axis=1)  # noqa: E731  (frame-free)
    np.testing.assert_allclose(sim.scale * spread(inner), spread(held), rtol=1e-3)
    assert len(inner.iterations) <= len(held.iterations)


def test_fixed_parameters_stay_bit_identical(cameras):
    sp = small(cameras, noise_px=0.3)
    p = sp.start
    p.fix(ParamGroup.DISTORTION)  # a first pass without distortion on every camera ...
    p.unfix(ParamGroup.K1, cameras=["01_01", "00_03"])  # ... except k1 of two cameras
    p.fix(ParamGroup.POSE, cameras=["05_12", "09_03"])  # two held poses fix the gauge (mode auto -> user)
    p.fix(ParamGroup.INTRINSICS, cameras="50_02")
    before = p.camera_params.copy()
    res = bundle_adjust(p, quick(outlier_rounds=0, loss="trivial"))
    assert res.gauge.mode is GaugeMode.AUTO and res.gauge.reference_camera is None
    after = res.problem.camera_params
    held = ~p.free
    assert np.array_equal(after[held].view(np.int64), before[held].view(np.int64))  # bit-identical
    assert np.all(after[p.free] != before[p.free])  # and everything free moved
    assert np.array_equal(p.camera_params, before)  # input untouched


def test_only_replaced_cameras_free(cameras):
    """The common re-calibration: every camera held except two replaced ones, which are found again."""
    sp = small(cameras, noise_px=0.2)
    p = sp.truth.copy()
    replaced = ["07_20", "00_17"]
    for n in replaced:
        p.camera_params[p.camera_position(n)] = sp.start.camera_params[p.camera_position(n)]
    p.fix(ParamGroup.ALL)
    p.unfix(ParamGroup.ALL, cameras=replaced)
    res = bundle_adjust(p, quick())
    for n in replaced:
        i = p.camera_position(n)
        err_cm = np.linalg.norm(res.problem.camera(n).center_cm - sp.truth.camera(n).center_cm)
        assert err_cm < 0.5, n
        assert abs(res.problem.camera_params[i, 6] / sp.truth.camera_params[i, 6] - 1) < 2e-3
    others = [i for i, n in enumerate(p.camera_names) if n not in replaced]
    assert np.array_equal(res.problem.camera_params[others], p.camera_params[others])


def test_outliers_rejected_and_cost_matches_oracle(cameras):
    sp = small(cameras, n_points=2500, target_observations=20000, noise_px=0.5, outlier_fraction=0.03, seed=5)
    res = bundle_adjust(sp.start, quick())
    oracle = bundle_adjust(sp.truth, quick())
    # a 2- or 3-view track cannot expose its outlier (an outlier can outvote or be fitted by the point);
    # with >= 4 inlier views every outlier must go and every inlier must stay
    pt = sp.start.point_index
    judged = (np.bincount(pt[~sp.is_outlier], minlength=sp.start.n_points) >= 4)[pt]
    assert judged.sum() > 0.5 * len(pt)
    assert not np.any(res.used & sp.is_outlier & judged)
    # inliers lost with a track's outlier (seeds 1-7: 9-36 of ~6,700 with either gauge; here 14 with the inner
    # constraints, 4 with the two-camera gauge)
    assert np.sum(~res.inlier & ~sp.is_outlier & judged) <= 0.003 * np.sum(judged)
    assert np.all(res.used <= res.inlier)  # used = inliers of points still seen twice
    common = res.used & oracle.used
    cost = lambda r: 0.5 * np.sum(r.residuals_px[common] ** 2)  # noqa: E731
    assert cost(res) <= cost(oracle) * (1 + 5e-3)  # the inlier sets differ by a few borderline observations
    assert res.sigma_px == pytest.approx(0.5, rel=0.05)
    # on the oracle's observation set, the perturbed start reaches the oracle's minimum (judged by the cost)
    s, m = sp.start, oracle.used
    same = BAProblem.from_cameras(s.cameras, {"all": s.points_cm}, camera_index=s.camera_index[m],
                                  point_index=s.point_index[m], uv_px=s.uv_px[m])
    same.camera_params = s.camera_params.copy()
    again = bundle_adjust(same, quick(outlier_rounds=0, loss="trivial", function_tolerance=1e-10))
    assert again.cost <= oracle.cost * (1 + 1e-6)


@pytest.mark.parametrize("variant", ["k3 held on one camera", "one camera held, no distortion, 2 threads"])
def test_reduced_system_step_matches_dense_normal_equations(cameras, variant):
    """Schur-complement step == dense solve of (J^T W J + lambda D) d = -J^T W r with a finite-difference J.
    Second variant: a camera with nothing free (its observations constrain the points only) and fewer than 15
    free columns (the compact Y Y^T), the blocks computed in threads."""
    sp = small(cameras[:6], n_points=40, target_observations=300, noise_px=0.5, seed=1)
    p = sp.start
    threads = 1
    if variant.startswith("k3"):
        p.fix(ParamGroup.K3, cameras=[p.camera_names[2]])
    else:
        p.fix(ParamGroup.DISTORTION)
        threads = 2
    gauge = choose_gauge(p)
    free = p.free & ~gauge.held
    if threads == 2:
        free[3] = False
    st = build_structure(p.camera_index, p.point_index, np.ones(p.n_observations, bool), free, p.n_points)
    assert st.act.all() == (threads == 1)
    res, Jc, Jp = residuals_and_jacobians(p.camera_params, p.points_cm, st.cam, st.pt, p.uv_px[st.obs])
    w = np.random.default_rng(0).uniform(0.2, 1.0, len(st.obs))
    lin = linearize(st, res, Jc.copy(), Jp, w, n_threads=threads)
    lam = 1e-3
    step = solve_step(st, lin, lam, n_threads=threads)
    # dense finite-difference Jacobian over (free camera params, live points)
    cam_cols = [(c, k) for c in range(p.n_cameras) for k in range(15) if free[c, k]]
    pts = np.flatnonzero(st.live_points)

    def r_of(cp, X):
        return residuals(cp, X, st.cam, st.pt, p.uv_px[st.obs]).ravel()

    cols = []
    for c, k in cam_cols:
        h = 1e-6 * max(1.0, abs(p.camera_params[c, k]))
        cp1, cp2 = p.camera_params.copy(), p.camera_params.copy()
        cp1[c, k] += h
        cp2[c, k] -= h
        cols.append((r_of(cp1, p.points_cm) - r_of(cp2, p.points_cm)) / (2 * h))
    for q in pts:
        for k in range(3):
            X1, X2 = p.points_cm.copy(), p.points_cm.copy()
            X1[q, k] += 1e-5
            X2[q, k] -= 1e-5
            cols.append((r_of(p.camera_params, X1) - r_of(p.camera_params, X2)) / 2e-5)
    J = np.stack(cols, axis=1)
    # the analytic per-observation Jacobians agree with the finite differences ...
    J_an = np.zeros_like(J)
    rows = np.arange(len(st.obs))
    for j, (c, k) in enumerate(cam_cols):
        m = st.cam == c
        J_an[2 * rows[m], j], J_an[2 * rows[m] + 1, j] = Jc[0, k, m], Jc[1, k, m]
    for j, q in enumerate(pts):
        m = st.pt == q
        for k in range(3):
            col = len(cam_cols) + 3 * j + k
            J_an[2 * rows[m], col], J_an[2 * rows[m] + 1, col] = Jp[0, k, m], Jp[1, k, m]
    assert np.abs(J_an - J).max() < 1e-5 * np.abs(J).max()
    # ... and the Schur-complement step equals the dense LM step
    W = np.repeat(w, 2)
    H = J_an.T @ (W[:, None] * J_an)
    g = J_an.T @ (W * res.T.ravel())
    D = np.clip(np.diag(H), 1e-6, 1e32)
    d = np.linalg.solve(H + lam * np.diag(D), -g)
    dc = np.array([step.dc[st.cam_local[np.flatnonzero(st.cam == c)[0]], k] for c, k in cam_cols])
    dp = step.dp[pts].ravel()
    assert np.allclose(np.concatenate([dc, dp]), d, rtol=1e-6, atol=1e-9 * np.abs(d).max())


def test_uncertainty_matches_dense_covariance(cameras):
    sp = small(cameras[:8], n_points=300, target_observations=3000, noise_px=0.5, seed=2)
    res = bundle_adjust(sp.start, BAOptions(n_threads=1, outlier_rounds=0, loss="trivial", function_tolerance=1e-12))
    p = res.problem
    free = p.free & ~res.gauge.held
    st = build_structure(p.camera_index, p.point_index, np.ones(p.n_observations, bool), free, p.n_points)
    r, Jc, Jp = residuals_and_jacobians(p.camera_params, p.points_cm, st.cam, st.pt, p.uv_px[st.obs])
    M = len(st.obs)
    cam_cols = [(c, k) for c in range(p.n_cameras) for k in range(15) if free[c, k]]
    J = np.zeros((2 * M, len(cam_cols) + 3 * p.n_points))
    for j, (c, k) in enumerate(cam_cols):
        m = np.flatnonzero(st.cam == c)
        J[2 * m, j], J[2 * m + 1, j] = Jc[0, k, m], Jc[1, k, m]
    for k in range(3):
        J[2 * np.arange(M), len(cam_cols) + 3 * st.pt + k] = Jp[0, k]
        J[2 * np.arange(M) + 1, len(cam_cols) + 3 * st.pt + k] = Jp[1, k]
    J = J[:, np.any(J != 0, axis=0)]  # points seen by nobody have no column
    cov = res.sigma_px ** 2 * np.linalg.inv(J.T @ J)
    sd = np.sqrt(np.diag(cov))
    for j, (c, k) in enumerate(cam_cols):
        if 6 <= k < 10:
            assert res.uncertainty.sigma_intr_px[c, k - 6] == pytest.approx(sd[j], rel=1e-6)
    a = p.camera_position(res.gauge.reference_camera)
    assert np.all(res.uncertainty.sigma_center_cm[a] == 0.0)  # the reference camera defines the frame
    assert np.all(res.uncertainty.sigma_center_centroid_cm[a] > 0.0)


def test_component_major_jacobians_equal_foundation(cameras):
    sp = small(cameras, n_points=100, target_observations=600, noise_px=0.5)
    p = sp.start
    p.camera_params[:, 10:15] = sp.truth.camera_params[:, 10:15]
    res, Jc, Jp = residuals_and_jacobians(p.camera_params, p.points_cm, p.camera_index, p.point_index, p.uv_px)
    q = p.camera_params[p.camera_index]
    ref = project_with_jacobians(p.points_cm[p.point_index], q[:, 0:3], q[:, 3:6], q[:, 6:10], q[:, 10:15])
    assert np.allclose(res.T, ref.uv_px - p.uv_px, atol=1e-9)
    parts = [ref.d_rotvec, ref.d_t, ref.d_intr, ref.d_dist]
    assert np.allclose(Jc.transpose(2, 0, 1), np.concatenate(parts, axis=2), rtol=1e-9, atol=1e-9)
    assert np.allclose(Jp.transpose(2, 0, 1), ref.d_point, rtol=1e-9, atol=1e-12)


def test_evaluation_works_in_small_chunks_with_the_same_bits(cameras, monkeypatch):
    """The residuals and Jacobians are evaluated a chunk of observations at a time, so their elementwise temporaries
    stay small (reused from the heap; one slice per thread made each of them half the observations long, a fresh
    mapping on the full dome on every call); every observation alone, so the chunking changes no bit."""
    import tracemalloc

    from dome_calib.ba import evaluate

    p = small(cameras, n_points=100, target_observations=600, noise_px=0.5).start
    rep = np.tile(np.arange(p.n_observations), 200_000 // p.n_observations + 1)[:200_000]
    args = (p.camera_params, p.points_cm, p.camera_index[rep], p.point_index[rep], p.uv_px[rep])
    M = len(rep)
    out = (np.empty((2, M)), np.empty((2, 15, M)), np.empty((2, 3, M)))
    tracemalloc.start()
    chunked = [a.copy() for a in residuals_and_jacobians(*args, n_threads=2, out=out)]
    peak = tracemalloc.get_traced_memory()[1] - sum(a.nbytes for a in chunked)
    tracemalloc.stop()
    assert peak < 2 * 100 * evaluate.CHUNK_OBSERVATIONS * 8, peak  # ~70 live temporaries of a chunk per thread
    r_chunked = residuals(*args, n_threads=2)
    monkeypatch.setattr(evaluate, "CHUNK_OBSERVATIONS", M)  # one slice: what a thread evaluated before
    whole = residuals_and_jacobians(*args, n_threads=1)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(chunked, whole))
    assert np.array_equal(r_chunked, residuals(*args, n_threads=1))


def test_scenes_stand_where_they_are_placed(cameras):
    """SyntheticOptions.scene_centres_cm: each scene's tent at its own place (bench/ba.py --pair puts three in a
    second dome); one place per scene."""
    centres = ((0.0, 0.0, 0.0), (60.0, 0.0, -50.0))
    p = small(cameras, n_points=400, target_observations=2000, n_scenes=2, scene_centres_cm=centres).truth
    for name, centre in zip(p.scene_names, centres):
        mid = p.scene_points(name).mean(axis=0)
        assert np.hypot(mid[0] - centre[0], mid[2] - centre[2]) < 30.0, (name, mid)
    with pytest.raises(ValueError, match="scene_centres_cm has 1 places for 2 scenes"):
        small(cameras, n_scenes=2, scene_centres_cm=centres[:1])


def test_output_is_a_bundle_keyed_by_name(cameras):
    sp = small(cameras, noise_px=0.3)
    res = bundle_adjust(sp.start, quick(outlier_rounds=0, loss="trivial"))
    bundle = res.to_bundle(seq="test")
    assert isinstance(bundle, Bundle) and list(bundle.cameras) == NAMES
    cam = bundle.cameras["00_03"]
    assert cam.type == "hd" and cam.resolution == (1920, 1080)
    assert np.allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12) and np.linalg.det(cam.R) == pytest.approx(1.0)
    report = res.camera_report()
    assert set(report) == set(NAMES) and all(v["n_obs"] > 0 for v in report.values())
    assert report["01_01"]["rms_px"] == pytest.approx(res.camera_rms_px[0])


def test_bad_input_raises_with_field_named(cameras):
    sp = small(cameras, n_points=60, target_observations=300)
    p = sp.truth
    with pytest.raises(BAProblemError, match="point_index"):
        BAProblem.from_cameras(p.cameras, {"s": p.points_cm}, camera_index=p.camera_index,
                               point_index=p.point_index[:-1], uv_px=p.uv_px)
    with pytest.raises(BAProblemError, match="camera_index out of range"):
        BAProblem.from_cameras(p.cameras, {"s": p.points_cm}, camera_index=p.camera_index + 100,
                               point_index=p.point_index, uv_px=p.uv_px)
    with pytest.raises(BAProblemError, match="unknown parameter group 'zoom'"):
        p.fix("zoom")
    with pytest.raises(BAProblemError, match="no camera named '99_99'"):
        p.fix(ParamGroup.POSE, cameras=["99_99"])
    with pytest.raises(BAProblemError, match="gauge mode 'user'"):
        bundle_adjust(p, quick(gauge="user"))


def test_blas_thread_control_restores_previous_counts():
    from dome_calib.ba.blas import blas_threads, get_blas_threads

    before = get_blas_threads()
    with blas_threads(1):
        assert all(n == 1 for n in get_blas_threads())
    assert get_blas_threads() == before


def test_robust_weights_give_the_robust_gradient():
    from dome_calib.ba.robust import robust_cost_and_weight

    z = np.array([0.0, 0.5, 3.9, 4.1, 100.0])  # px^2; scale 2 px -> z = 4 is the Huber knee
    for kind in ("trivial", "huber", "cauchy"):
        rho, w = robust_cost_and_weight(z, kind, 2.0)
        h = 1e-6
        d = (robust_cost_and_weight(z + h, kind, 2.0)[0] - robust_cost_and_weight(np.maximum(z - h, 0), kind, 2.0)[0])
        d /= (z + h) - np.maximum(z - h, 0)
        assert np.allclose(w, d, rtol=1e-5, atol=1e-7), kind
    assert robust_cost_and_weight(z, "huber", 2.0)[1][-1] == pytest.approx(0.2)  # s / |r| = 2 / 10


def test_warm_start_skips_the_robust_stage_and_reaches_the_cold_solution(cameras):
    sp = small(cameras, n_points=2500, target_observations=20000, noise_px=0.5, outlier_fraction=0.03, seed=5)
    cold = bundle_adjust(sp.start, quick())
    # from its own solution and inliers: already converged; one more round re-judges the few observations the
    # cold run's last round left pending (at most 0.1 %)
    again = bundle_adjust(cold.problem, quick(), start_inlier=cold.inlier)
    assert len(again.iterations) <= 5
    assert again.cost == pytest.approx(cold.cost, rel=1e-3)
    assert np.sum(again.inlier != cold.inlier) <= 1e-3 * len(cold.inlier)
    # from the perturbed start with the cold run's inliers: the least-squares minimum of that set, gross outliers
    # never enter (the robust stage is skipped, so a wrong start set would show here)
    warm = bundle_adjust(sp.start, quick(), start_inlier=cold.inlier)
    common = warm.used & cold.used
    assert common.sum() >= 0.99 * cold.used.sum()
    cost = lambda r: 0.5 * np.sum(r.residuals_px[common] ** 2)  # noqa: E731
    # each is the minimum of its own set; the few observations only one of them uses (each up to 0.5 x 2.3^2 px^2
    # at the threshold) move the other's cost on the common set by ~1e-3; re-converged on the common set, both
    # reach one minimum
    assert cost(warm) == pytest.approx(cost(cold), rel=2e-3)
    strict = quick(outlier_rounds=0, loss="trivial", function_tolerance=1e-12)
    on_common = [bundle_adjust(r.problem, strict, start_inlier=common).cost for r in (warm, cold)]
    assert on_common[0] == pytest.approx(on_common[1], rel=1e-6)
    assert not np.any(warm.used & sp.is_outlier & ~cold.inlier)
    with pytest.raises(ValueError, match="start_inlier"):
        bundle_adjust(sp.start, quick(), start_inlier=cold.inlier[:-1])


def test_outlier_rounds_stop_when_rejudging_changes_almost_nothing(cameras):
    sp = small(cameras, n_points=2500, target_observations=20000, noise_px=0.5, outlier_fraction=0.03, seed=5)
    strict = bundle_adjust(sp.start, quick(outlier_change_tolerance=0.0, intermediate_round_iterations=0))
    loose = bundle_adjust(sp.start, quick(outlier_change_tolerance=1e-3, intermediate_round_iterations=0))
    assert len(loose.termination) <= len(strict.termination)
    assert np.sum(loose.inlier != strict.inlier) <= 1e-3 * len(strict.inlier) * len(strict.termination)
    # px: the same solution within a small fraction of the 0.5 px noise; only points whose track gained or lost
    # an observation move by more, so the largest move is checked on the others
    pt = sp.start.point_index
    regained = np.isin(pt, pt[loose.inlier != strict.inlier])
    common = loose.used & strict.used
    moved = np.linalg.norm(loose.residuals_px - strict.residuals_px, axis=1)
    assert np.percentile(moved[common], 99) < 0.02 and moved[common & ~regained].max() < 0.5


def test_superlinear_stop_saves_an_iteration_and_ends_at_the_same_minimum(cameras):
    """Once a step gains less than 1e-5 of the cost and less than 1e-3 of the step before, the solve stops: the
    next step would gain ~1e-3 as little again. Against the strict tolerance alone: same inliers, cost within
    1e-6 (relative), residuals within 0.01 px of the 0.5 px noise, fewer iterations."""
    for seed in (5, 6):
        sp = small(cameras, n_points=2500, target_observations=20000, noise_px=0.5, outlier_fraction=0.03, seed=seed)
        strict = bundle_adjust(sp.start, quick(superlinear_tolerance=0.0, intermediate_round_iterations=0))
        fast = bundle_adjust(sp.start, quick(intermediate_round_iterations=0))
        assert "superlinear" in fast.termination and "superlinear" not in strict.termination
        assert len(fast.iterations) < len(strict.iterations)
        assert np.array_equal(fast.inlier, strict.inlier)
        assert fast.cost == pytest.approx(strict.cost, rel=1e-6)
        assert np.abs(fast.residuals_px - strict.residuals_px)[strict.used].max() < 0.01


def test_intermediate_rounds_take_one_step_and_the_solve_ends_converged(cameras):
    """A round that is not the last takes one Gauss-Newton step (it only hands its residuals to the next
    re-judging); when the re-judging settles after such a step, that round is converged and judged again, so the
    solve ends converged (settled, or with the rounds used up, as without the cap). Against converging every
    round: the same gross outliers rejected, verdicts within 0.5 % of the observations (a settled re-judging is a fixed point up to 0.1 % per round and its
    5-sigma threshold follows its own verdicts: measured 0 to 0.23 %), the same minimum on the common inliers
    (re-converged, within 1e-6), residuals within a tenth of the 0.5 px noise (99th percentile). The iterations
    it saves are measured on the full dome (README, Bundle adjustment): on these small problems a round's first
    step is still far from its minimum and the count comes out about the same."""
    for seed in (5, 6, 7):
        sp = small(cameras, n_points=2500, target_observations=20000, noise_px=0.5, outlier_fraction=0.03, seed=seed)
        every = bundle_adjust(sp.start, quick(intermediate_round_iterations=0))
        fast = bundle_adjust(sp.start, quick())
        assert "capped" in fast.termination and "capped" not in every.termination
        assert fast.termination[-1] != "capped"  # the solve never ends on a capped round
        assert np.sum(fast.used & sp.is_outlier) <= np.sum(every.used & sp.is_outlier)
        assert np.sum(fast.inlier != every.inlier) <= 5e-3 * len(every.inlier)
        common = fast.used & every.used
        moved = np.linalg.norm(fast.residuals_px - every.residuals_px, axis=1)
        assert np.percentile(moved[common], 99) < 0.05
        strict = quick(outlier_rounds=0, loss="trivial", function_tolerance=1e-12)
        on_common = [bundle_adjust(r.problem, strict, start_inlier=common).cost for r in (fast, every)]
        assert on_common[0] == pytest.approx(on_common[1], rel=1e-6)
