"""The camera model against OpenCV, its inverse, and its Jacobians against finite differences (real cameras)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from dome_calib.camera import (
    K_to_intr,
    colmap_to_opencv_px,
    distort,
    intr_to_K,
    max_valid_radius2,
    opencv_to_colmap_px,
    pixels_to_normalized,
    project,
    project_with_jacobians,
)
from dome_calib.rotation import matrix_to_rotvec, rotvec_to_matrix

PROJECTION_TOL_PX = 1e-9
ROUNDTRIP_TOL_PX = 1e-6
JACOBIAN_REL_TOL = 1e-6


def _stack(cameras):
    names = sorted(cameras)
    cams = [cameras[n] for n in names]
    # Re-orthonormalise through the rotation vector so that OpenCV (which takes a rotation vector) and we use
    # the same matrix; the file's R is orthonormal only to ~1e-10 (10 significant digits).
    rotvec = np.array([cv2.Rodrigues(c.R)[0][:, 0] for c in cams])
    R = np.array([cv2.Rodrigues(r)[0] for r in rotvec])
    return names, rotvec, R, np.array([c.t_cm for c in cams]), np.array([c.K for c in cams]), np.array([c.dist for c in cams])


def _points_in_front(R, t, n, rng):
    """(C, n, 3) world points inside each camera's view cone, 50-600 cm in front."""
    xy = rng.uniform(-0.45, 0.45, (len(R), n, 2))
    z = rng.uniform(50, 600, (len(R), n))
    X_cam = np.concatenate([xy * z[..., None], z[..., None]], axis=-1)
    return np.einsum("cji,cnj->cni", R, X_cam - t[:, None, :])


def test_projection_equals_opencv_on_all_real_cameras(real_cameras):
    names, rotvec, R, t, K, dist = _stack(real_cameras)
    X = _points_in_front(R, t, 300, np.random.default_rng(0))
    ours = project(X, R, t, K_to_intr(K), dist)
    assert ours.in_front.all()
    for i in range(len(names)):
        ref, _ = cv2.projectPoints(X[i], rotvec[i], t[i], K[i], dist[i])
        err = np.abs(ours.uv_px[i] - ref[:, 0]).max()
        assert err < PROJECTION_TOL_PX, f"{names[i]}: {err} px"


def test_shared_points_broadcast_over_cameras(real_cameras):
    _, _, R, t, K, dist = _stack(real_cameras)
    X = np.random.default_rng(1).normal([0, -120, 0], 30, (50, 3))
    all_at_once = project(X, R, t, K_to_intr(K), dist)
    one = project(X, R[7], t[7], K_to_intr(K[7]), dist[7])
    assert all_at_once.uv_px.shape == (len(R), 50, 2)
    np.testing.assert_array_equal(all_at_once.uv_px[7], one.uv_px)


def test_undistort_inverts_distort_over_every_pixel_of_every_camera(real_cameras):
    worst = 0.0
    for name, cam in real_cameras.items():
        w, h = cam.resolution
        step = 8  # a dense grid over the whole image, borders and corners included
        us = np.unique(np.r_[np.arange(0, w, step), w - 1])
        vs = np.unique(np.r_[np.arange(0, h, step), h - 1])
        uv = np.stack(np.meshgrid(us, vs), axis=-1).reshape(-1, 2).astype(float)
        xn = pixels_to_normalized(uv, cam.intr, cam.dist)
        assert np.isfinite(xn).all(), name
        back = distort(xn, cam.dist) * cam.intr[:2] + cam.intr[2:]
        worst = max(worst, np.abs(back - uv).max())
    assert worst < ROUNDTRIP_TOL_PX


def test_undistort_every_pixel_of_the_most_distorted_vga_camera(real_cameras):
    cam = min((c for c in real_cameras.values() if c.type == "vga"), key=lambda c: c.dist[0])
    uv = np.stack(np.meshgrid(np.arange(640.0), np.arange(480.0)), axis=-1).reshape(-1, 2)
    back = distort(pixels_to_normalized(uv, cam.intr, cam.dist), cam.dist) * cam.intr[:2] + cam.intr[2:]
    assert np.abs(back - uv).max() < ROUNDTRIP_TOL_PX


def test_undistort_corner_of_strong_vga_distortion_converges():
    intr = np.array([745.0, 745.0, 320.0, 240.0])
    dist = np.array([-0.379, 0.2, 0.001, -0.001, -0.1])
    corners = np.array([[0.0, 0.0], [639.0, 0.0], [0.0, 479.0], [639.0, 479.0]])
    xn = pixels_to_normalized(corners, intr, dist)
    back = distort(xn, dist) * intr[:2] + intr[2:]
    assert np.abs(back - corners).max() < ROUNDTRIP_TOL_PX


def test_points_behind_camera_are_reported_not_projected():
    R, t = np.eye(3)[None], np.zeros((1, 3))
    X = np.array([[0.0, 0.0, -100.0], [10.0, 0.0, 0.0], [0.0, 5.0, 100.0]])
    p = project(X, R, t, np.array([[500.0, 500, 320, 240]]), np.zeros((1, 5)))
    np.testing.assert_array_equal(p.in_front[0], [False, False, True])
    assert np.isnan(p.uv_px[0, :2]).all() and np.isfinite(p.uv_px[0, 2]).all()
    assert not p.in_image(np.array([[640, 480]]))[0, :2].any()


def test_points_beyond_the_lens_fold_are_not_physical():
    dist = np.array([-0.32, 0.05, 0.0, 0.0, -0.1])
    r2_max = max_valid_radius2(dist[None])[0]
    slope = lambda r2: 1 + 3 * dist[0] * r2 + 5 * dist[1] * r2**2 + 7 * dist[4] * r2**3  # noqa: E731
    assert slope(r2_max) > 0 and slope(r2_max + 2e-3) <= 0
    X = np.array([[0.5, 0, 1.0], [np.sqrt(r2_max) * 1.5, 0, 1.0]])
    p = project(X, np.eye(3)[None], np.zeros((1, 3)), np.array([[745.0, 745, 320, 240]]), dist[None])
    np.testing.assert_array_equal(p.in_lens[0], [True, False])


def test_jacobians_equal_central_differences_on_all_real_cameras(real_cameras):
    _, rotvec, R, t, K, dist = _stack(real_cameras)
    rng = np.random.default_rng(2)
    X = _points_in_front(R, t, 1, rng)[:, 0]
    intr = K_to_intr(K)
    args = [X, rotvec, t, intr, dist]
    J = project_with_jacobians(*args)
    analytic = {0: J.d_point, 1: J.d_rotvec, 2: J.d_t, 3: J.d_intr, 4: J.d_dist}
    for which, Ja in analytic.items():
        numeric = np.zeros_like(Ja)
        for j in range(Ja.shape[2]):
            h = 1e-6 * np.maximum(1.0, np.abs(args[which][:, j]))
            plus = [a.copy() for a in args]
            minus = [a.copy() for a in args]
            plus[which][:, j] += h
            minus[which][:, j] -= h
            diff = project_with_jacobians(*plus).uv_px - project_with_jacobians(*minus).uv_px
            numeric[:, :, j] = diff / (2 * h[:, None])
        scale = np.abs(Ja).max(axis=(1, 2), keepdims=True)
        rel = np.abs(Ja - numeric) / scale
        assert rel.max() < JACOBIAN_REL_TOL, f"parameter group {which}: {rel.max():.2e}"


def test_jacobian_rotation_near_zero_angle():
    rng = np.random.default_rng(3)
    rotvec = rng.normal(0, 1e-8, (5, 3))
    X = rng.normal(0, 50, (5, 3)) + [0, 0, 300]
    base = [X, rotvec, np.zeros((5, 3)), np.tile([700.0, 700, 320, 240], (5, 1)), np.tile([-0.3, 0.1, 0, 0, 0], (5, 1))]
    J = project_with_jacobians(*base).d_rotvec
    h = 1e-6
    for j in range(3):
        plus, minus = [a.copy() for a in base], [a.copy() for a in base]
        plus[1][:, j] += h
        minus[1][:, j] -= h
        num = (project_with_jacobians(*plus).uv_px - project_with_jacobians(*minus).uv_px) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], num, rtol=1e-6, atol=1e-6)


def test_rotation_helpers_round_trip_and_are_rotations():
    rng = np.random.default_rng(4)
    rv = rng.normal(0, 1.0, (100, 3))
    R = rotvec_to_matrix(rv)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(R)), R, atol=1e-12)


def test_pixel_convention_helpers_and_K_packing():
    uv = np.array([[0.0, 0.0], [639.0, 479.0]])
    np.testing.assert_array_equal(opencv_to_colmap_px(uv), uv + 0.5)
    np.testing.assert_array_equal(colmap_to_opencv_px(opencv_to_colmap_px(uv)), uv)
    K = np.array([[745.7, 0, 375.5], [0, 745.9, 226.0], [0, 0, 1]])
    np.testing.assert_array_equal(intr_to_K(K_to_intr(K)), K)


@pytest.mark.parametrize("shape", [(7, 2), (3, 7, 2)])
def test_distort_broadcasts(shape):
    xn = np.random.default_rng(5).uniform(-0.4, 0.4, shape)
    d = np.array([-0.3, 0.05, 1e-3, -1e-3, 0.08])
    out = distort(xn, d)
    assert out.shape == shape
    np.testing.assert_allclose(distort(xn.reshape(-1, 2), d).reshape(shape), out)
