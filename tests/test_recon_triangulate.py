"""Robust weighted triangulation: kernel against the foundation camera model, DLT, LM, RANSAC, weighting."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from dome_calib.camera import pixels_to_normalized, project, project_with_jacobians
from dome_calib.errors import OptionsError
from dome_calib.recon.errors import ReconError
from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.project import project_points, view_set
from dome_calib.recon.triangulate import (
    TriangulationOptions,
    point_jacobian,
    refine_lm,
    triangulate,
    triangulate_dlt,
)
from dome_calib.rotation import matrix_to_rotvec

from .recon_helpers import dome_points, real_bundle


@pytest.fixture(scope="module")
def views():
    return view_set(real_bundle(kinect=False, sync=False))


def _observe(views, X, *, noise_px=0.0, wrong=0.0, seed=0):
    """(P, V, 2) detections, (P, V) confidences and the (P, V) mask of wrong detections."""
    rng = np.random.default_rng(seed)
    p = project_points(views, X)
    uv = p.uv_px.transpose(1, 0, 2) + rng.normal(scale=noise_px, size=(len(X), len(views.names), 2))
    vis = p.visible.T
    bad = vis & (rng.random(vis.shape) < wrong)
    uv[bad] = rng.random((bad.sum(), 2)) * views.resolution[np.nonzero(bad)[1]]
    conf = np.where(vis, rng.uniform(0.5, 1.0, vis.shape), 0.0)
    return uv, conf, bad


def test_kernel_pixels_and_point_jacobian_match_the_foundation(views):
    X = dome_points(7, seed=3)
    uv, J = point_jacobian(views, X)
    P, V = len(X), len(views.names)
    ref = project(X, views.R, views.t_cm, views.intr, views.dist)
    np.testing.assert_allclose(uv, ref.uv_px.transpose(1, 0, 2), atol=2e-3)  # float32 kernel: ~1e-4 px
    rep = lambda a: np.broadcast_to(a[None], (P, *a.shape)).reshape(P * V, *a.shape[1:])  # noqa: E731
    jac = project_with_jacobians(np.repeat(X, V, axis=0), rep(matrix_to_rotvec(views.R)), rep(views.t_cm),
                                 rep(views.intr), rep(views.dist), R=rep(views.R))
    np.testing.assert_allclose(J.reshape(P * V, 2, 3), jac.d_point, rtol=1e-4, atol=1e-4 * np.abs(jac.d_point).max())


def test_kernel_undistort_matches_pixels_to_normalized(views):
    rng = np.random.default_rng(4)
    uv = rng.random((60, len(views.names), 2)) * views.resolution
    ref = pixels_to_normalized(uv, views.intr, views.dist)
    for iterations, tol_px in ((2, 0.05), (4, 2e-3)):
        x, y = CameraKernel(views).undistort(uv[..., 0], uv[..., 1], iterations=iterations)
        err_px = np.hypot(x - ref[..., 0], y - ref[..., 1]) * views.intr[:, 0]
        assert np.nanmax(err_px) < tol_px
    # the compiled pass is the numpy expression of the Newton steps (CameraKernel.distort), to the last bit
    k = CameraKernel(views)
    xd0 = (uv[..., 0].astype(np.float32) - k.cx) / k.fx
    yd0 = (uv[..., 1].astype(np.float32) - k.cy) / k.fy
    xs, ys = xd0, yd0
    for _ in range(2):
        xd, yd, a, b, d, _ = k.distort(xs, ys)
        inv_det = np.float32(1.0) / (a * d - b * b)
        xs, ys = xs - (d * (xd - xd0) - b * (yd - yd0)) * inv_det, ys - (a * (yd - yd0) - b * (xd - xd0)) * inv_det
    x, y = k.undistort(uv[..., 0], uv[..., 1])
    np.testing.assert_array_equal(x, xs)
    np.testing.assert_array_equal(y, ys)


def test_dlt_is_exact_on_noise_free_rays(views):
    X = dome_points(20, seed=5)
    uv, conf, _ = _observe(views, X)
    xn = np.nan_to_num(pixels_to_normalized(uv, views.intr, views.dist))
    X_dlt = triangulate_dlt(views, xn, conf)
    assert np.abs(X_dlt - X).max() < 1e-6  # cm
    conf[:, 1:] = 0.0  # one view only: no point
    assert np.isnan(triangulate_dlt(views, xn, conf)).all()


def test_lm_minimises_the_confidence_weighted_reprojection_error(views):
    """Same minimum as scipy's least_squares on sum_v c_v |pi_v(X) - u_v|^2, from a start 5 cm away."""
    sub = views.subset(views.names[::40])
    X = dome_points(4, seed=6)
    uv, conf, _ = _observe(sub, X, noise_px=3.0, seed=6)
    X0 = X + 5.0
    X_lm, _ = refine_lm(sub, X0, uv, conf, iterations=8)
    for p in range(len(X)):
        ok = conf[p] > 0

        def residual(x, p=p, ok=ok):
            proj = project(x[None], sub.R[ok], sub.t_cm[ok], sub.intr[ok], sub.dist[ok]).uv_px[:, 0]
            return ((proj - uv[p, ok]) * np.sqrt(conf[p, ok])[:, None]).ravel()

        ref = least_squares(residual, X0[p], xtol=1e-12, ftol=1e-12).x
        assert np.abs(X_lm[p] - ref).max() < 1e-3  # cm (float32 residuals)


def test_robust_to_ten_percent_wrong_detections(views):
    X = dome_points(60, seed=7)
    uv, conf, bad = _observe(views, X, noise_px=2.0, wrong=0.10, seed=7)
    tri = triangulate(views, uv, conf)
    err_mm = np.linalg.norm(tri.X_cm - X, axis=1) * 10.0
    assert err_mm.max() < 3.0
    # Wrong detections far from the truth are rejected, good ones kept.
    far = bad & (np.linalg.norm(uv - project_points(views, X).uv_px.transpose(1, 0, 2), axis=-1) > 10.0)
    assert (far & tri.inliers).sum() == 0
    good = (conf > 0) & ~bad
    assert (good & tri.inliers).sum() > 0.97 * good.sum()
    assert np.all(tri.rms_px < 3.5) and np.all(tri.confidence > 0.5)
    # Without rejection (weighted DLT over every detection) the same data gives centimetre errors.
    xn = np.nan_to_num(pixels_to_normalized(uv, views.intr, views.dist))
    naive_mm = np.linalg.norm(triangulate_dlt(views, xn, conf) - X, axis=1) * 10.0
    assert np.median(naive_mm) > 10 * np.median(err_mm)


def test_confidence_weights_pull(views):
    """A biased detection with low confidence moves the point less than the same detection with high confidence."""
    sub = views.subset(views.names[::60])
    X = dome_points(1, seed=8)
    uv, conf, _ = _observe(sub, X, seed=8)
    v = int(np.flatnonzero(conf[0])[0])
    uv[0, v] += 6.0  # inside the inlier threshold
    errs = []
    for c in (1.0, 0.02):
        conf[0, v] = c
        errs.append(np.linalg.norm(triangulate(sub, uv, conf).X_cm[0] - X[0]))
    assert errs[1] < 0.2 * errs[0]


def test_unreconstructable_points_and_bad_input(views):
    X = dome_points(3, seed=9)
    uv, conf, _ = _observe(views, X, noise_px=1.0, seed=9)
    conf[1] = 0.0
    conf[2, np.flatnonzero(conf[2])[1:]] = 0.0  # a single view
    tri = triangulate(views, uv, conf)
    assert np.isfinite(tri.X_cm[0]).all() and np.isnan(tri.X_cm[1:]).all()
    assert tri.confidence[1:].tolist() == [-1.0, -1.0] and tri.n_inliers[1:].tolist() == [0, 0]
    with pytest.raises(ReconError, match="expected"):
        triangulate(views, uv[:, :10], conf)
    with pytest.raises(OptionsError, match="min_views 1: expected an integer >= 2"):
        TriangulationOptions(min_views=1)


def test_a_point_does_not_depend_on_the_batch_it_is_triangulated_in(views):
    """Issue 42: the RANSAC draws were taken for the whole batch, so a point's result changed with the points
    triangulated beside it (chunked and unchunked reconstructions differed by up to 42 cm). Now each point's draws
    are a function of its own detections: any batch, order or split gives the same points."""
    sub = views.subset(views.names[::40])  # 13 views: RANSAC draws, not every pair
    X = dome_points(120, seed=11)
    uv, conf, _ = _observe(sub, X, noise_px=3.0, wrong=0.3, seed=11)
    conf[:40, 5:] = 0.0  # a third of the points seen by at most 5 views: every pair is tried
    whole = triangulate(sub, uv, conf)
    order = np.random.default_rng(1).permutation(len(X))
    parts = [triangulate(sub, uv[order[k: k + 7]], conf[order[k: k + 7]]) for k in range(0, len(X), 7)]
    X_parts = np.full_like(whole.X_cm, np.nan)
    inl_parts = np.zeros_like(whole.inliers)
    for k, part in zip(range(0, len(X), 7), parts):
        X_parts[order[k: k + 7]], inl_parts[order[k: k + 7]] = part.X_cm, part.inliers
    np.testing.assert_array_equal(np.isnan(X_parts), np.isnan(whole.X_cm))
    np.testing.assert_allclose(X_parts, whole.X_cm, atol=1e-6)  # cm
    np.testing.assert_array_equal(inl_parts, whole.inliers)
    assert np.nanmedian(np.linalg.norm(whole.X_cm - X, axis=1)) < 1.0  # and still right (30 % wrong detections)


def _balancing_left_hip(frames):
    """The real Pose2Sim balancing trial (tests/data/pose2sim_balancing: 4 phones, BODY_25B): per frame and camera
    the participant's left hip (BODY_25B joint 11; the detected person with the most confident left hip: the
    onlooker of cameras 01-02 is partial, 0.3-0.4) -> views, (F, 4, 2) px, (F, 4) confidences."""
    import json
    from pathlib import Path

    from dome_calib.interop.common import ImportOptions
    from dome_calib.interop.convert import read_foreign

    data = Path(__file__).parent / "data" / "pose2sim_balancing"
    bundle, _ = read_foreign(data / "calibration" / "Calib_qualisys.toml", "pose2sim",
                             ImportOptions(world_up="-y", seq="pose2sim"))
    cams = sorted(bundle.cameras)
    uv, conf = np.full((len(frames), 4, 2), np.nan), np.zeros((len(frames), 4))
    for k, f in enumerate(frames):
        for v, cam in enumerate(cams):
            n = cam[-2:]
            doc = json.loads((data / "pose" / f"cam{n}_json" / f"cam{n}.{f:04d}.json").read_text())
            kp = np.array([p["pose_keypoints_2d"] for p in doc["people"]], dtype=float).reshape(-1, 25, 3)[:, 11]
            best = kp[np.argmax(kp[:, 2])]
            uv[k, v], conf[k, v] = best[:2], min(best[2], 1.0)
    return view_set(bundle, cams), uv, conf


def test_three_views_that_agree_beat_two_that_meet():
    """Real detections: in frames 42-51 of the balancing trial cameras 02-04 put the left hip where one point lands
    within 15 px of each (Pose2Sim's triangulation keeps those three), camera 01's lies 50-55 px away; two views
    always meet, and the two-view midpoint hypotheses of the three missed their third view by more than 15 px, so
    cameras 01 + 02, fitted exactly, won in 9 of the 10 frames (the per-frame hip flipped between the two, and the
    pelvis angles of OpenSim's kinematics with it). Each hypothesis is now refitted to the views it explains and the
    most views win."""
    views, uv, conf = _balancing_left_hip(range(42, 52))
    tri = triangulate(views, uv, conf, TriangulationOptions(inlier_threshold_px=15.0))
    assert tri.inliers.tolist() == [[False, True, True, True]] * 10
    err = np.linalg.norm(project_points(views, tri.X_cm).uv_px.transpose(1, 0, 2) - uv, axis=-1)
    assert (err[:, 1:] < 15.0).all() and (err[:, 0] > 40.0).all()


def test_the_most_views_within_the_threshold_win(views):
    """The class: three views with detector noise (5 px, the real phones' 3.5-7) and a fourth whose detection is
    the projection of a point 5-15 % nearer or farther along view 1's ray (so that pair meets exactly). Whenever
    the three meet within the threshold (their own least-squares point within it in each) they are the answer, not
    the pair."""
    rng = np.random.default_rng(3)
    sub = view_set(real_bundle(kinect=False, sync=False), [views.names[k] for k in (0, 4, 8, 12)])
    X = dome_points(200, seed=5)
    p = project_points(sub, X)
    keep = p.visible.all(axis=0)
    X, uv = X[keep], p.uv_px.transpose(1, 0, 2)[keep]
    uv[:, 1:] += rng.normal(scale=5.0, size=uv[:, 1:].shape)
    # the far view's detection: the projection of a point moved along view 1's ray (the pair 0-1 meets exactly)
    ray = X - sub.center_cm[1]
    scale = 1.0 + rng.choice([-1, 1], len(X))[:, None] * rng.uniform(0.05, 0.15, (len(X), 1))
    uv[:, 0] = project_points(sub, sub.center_cm[1] + ray * scale).uv_px[0]
    conf = np.ones(uv.shape[:2])
    opt = TriangulationOptions(inlier_threshold_px=15.0)
    three = conf.copy()
    three[:, 0] = 0.0
    X3 = triangulate(sub, uv, three, TriangulationOptions(inlier_threshold_px=1e6)).X_cm
    r3 = np.linalg.norm(project_points(sub, X3).uv_px.transpose(1, 0, 2) - uv, axis=-1)
    meet = (r3[:, 1:] < 14.0).all(axis=1) & (r3[:, 0] > 20.0)
    tri = triangulate(sub, uv, conf, opt)
    assert meet.sum() > 50
    assert (tri.n_inliers[meet] == 3).all() and not tri.inliers[meet, 0].any()


def test_few_views_solves_each_point_in_its_own_views(views):
    """``few_views``: points seen in a few of the dome's 480 views are solved in K columns (their own views) with
    the draws of the full columns: the same inliers and points to the last float32 bits (sums over K columns, not
    480), in any batch (K is the caller's), and more detected views than K is an error."""
    X = dome_points(90, seed=12)
    uv, conf, _ = _observe(views, X, noise_px=2.0, wrong=0.2, seed=12)
    rng = np.random.default_rng(12)
    for p in range(len(X)):  # each point keeps 2..8 of its views (few: every pair; more: RANSAC draws)
        seen = np.flatnonzero(conf[p])
        conf[p, np.setdiff1d(seen, rng.choice(seen, rng.integers(2, 9), replace=False))] = 0.0
    full = triangulate(views, uv, conf)
    few = triangulate(views, uv, conf, few_views=8)
    np.testing.assert_array_equal(few.inliers, full.inliers)
    np.testing.assert_array_equal(np.isnan(few.X_cm), np.isnan(full.X_cm))
    np.testing.assert_allclose(few.X_cm, full.X_cm, atol=1e-4)  # cm
    assert np.isfinite(full.X_cm).all(axis=1).mean() > 0.8
    half = triangulate(views, uv[::2], conf[::2], few_views=8)
    np.testing.assert_array_equal(half.X_cm, few.X_cm[::2])
    with pytest.raises(ReconError, match="more than few_views=4"):
        triangulate(views, uv, conf, few_views=4)
