"""Projection into VGA, HD, Kinect colour and Kinect depth views, with visibility."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from dome_calib.camera import project
from dome_calib.recon.depth import depth_to_world
from dome_calib.recon.errors import ReconError
from dome_calib.recon.project import kinect_color_name, project_bundle, project_points, project_view, project_view_rows, view_set

from .recon_helpers import dome_points, real_bundle


@pytest.fixture(scope="module")
def bundle():
    return real_bundle(sync=False)


def test_matches_foundation_camera_model_for_every_dome_camera(bundle):
    X = dome_points(50)
    names = ["01_01", "14_17", "00_00", "00_30", "50_01", "50_10"]
    p = project_bundle(bundle, X, names)
    for i, name in enumerate(names):
        cam = bundle.cameras[name]
        ref = project(X, cam.R, cam.t_cm, cam.intr, cam.dist)
        np.testing.assert_allclose(p.uv_px[i], ref.uv_px, atol=1e-9)
        np.testing.assert_allclose(p.depth_cm[i], ref.depth, atol=1e-9)
        np.testing.assert_array_equal(p.visible[i], ref.in_image(np.array(cam.resolution)))


def test_kinect_depth_view_matches_the_chain_world_color_depth(bundle):
    node = "KINECTNODE3"
    sensor = bundle.kinect.sensors[node]
    color = bundle.cameras["50_03"]
    X = dome_points(40, seed=1)
    p = project_bundle(bundle, X, [node])
    # By hand: world -> colour camera (cm) -> metres -> depth camera (inverse of color_from_depth) -> OpenCV.
    X_color_m = (X @ color.R.T + color.t_cm) / 100.0
    depth_from_color = np.linalg.inv(sensor.color_from_depth)
    X_depth_m = X_color_m @ depth_from_color[:3, :3].T + depth_from_color[:3, 3]
    ref, _ = cv2.projectPoints(X_depth_m, np.zeros(3), np.zeros(3), sensor.K_depth, sensor.dist_depth)
    front = X_depth_m[:, 2] > 0
    np.testing.assert_allclose(p.uv_px[0][front], ref.reshape(-1, 2)[front], atol=1e-7)
    np.testing.assert_allclose(p.depth_cm[0], X_depth_m[:, 2] * 100.0, atol=1e-9)


def test_depth_projection_and_depth_unprojection_round_trip(bundle):
    node = "KINECTNODE5"
    sensor = bundle.kinect.sensors[node]
    sensor.depth_bias_mm, sensor.depth_scale = 0.0, 0.0
    vs = view_set(bundle, [node])
    w, h = sensor.depth_size
    # Points that land exactly on pixel centres at known depths: unproject them back and compare.
    rng = np.random.default_rng(2)
    uv = np.column_stack([rng.integers(20, w - 20, 30), rng.integers(20, h - 20, 30)])
    z_mm = rng.integers(800, 3000, 30)
    frame = np.zeros((h, w), np.uint16)
    frame[uv[:, 1], uv[:, 0]] = z_mm
    X = depth_to_world(bundle, node, frame)
    p = project_points(vs, X)
    order = np.lexsort((uv[:, 0], uv[:, 1]))  # depth_to_world returns points in row-major pixel order
    np.testing.assert_allclose(p.uv_px[0], uv[order], atol=1e-6)
    np.testing.assert_allclose(p.depth_cm[0] * 10.0, z_mm[order], atol=1e-6)
    assert p.visible.all()


def test_visibility_behind_outside_and_inside(bundle):
    cam = bundle.cameras["00_10"]
    ahead = cam.center_cm + 300.0 * cam.R[2]  # on the optical axis, 3 m in front
    behind = cam.center_cm - 300.0 * cam.R[2]
    aside = cam.center_cm + 300.0 * cam.R[2] + 1000.0 * cam.R[0]  # far to the side: in front, off the image
    p = project_bundle(bundle, np.array([ahead, behind, aside]), ["00_10"])
    assert p.in_front[0].tolist() == [True, False, True]
    assert p.visible[0].tolist() == [True, False, False]
    assert np.all(np.isnan(p.uv_px[0, 1]))
    assert p.depth_cm[0, 0] == pytest.approx(300.0)


def test_names_and_errors(bundle):
    assert kinect_color_name("KINECTNODE10") == "50_10"
    assert view_set(bundle, kinect_depth=True).names[-1] == "KINECTNODE10"
    with pytest.raises(ReconError, match="no camera named 'XX_01'"):
        view_set(bundle, ["01_01", "XX_01"])
    no_kinect = real_bundle(kinect=False, sync=False)
    with pytest.raises(ReconError, match="kcalibration"):
        view_set(no_kinect, ["KINECTNODE1"])
    with pytest.raises(ReconError, match=r"expected \(P, 3\)"):
        project_bundle(bundle, np.zeros((3, 2)))


def test_project_view_gives_project_points_bits_in_every_view(bundle):
    """The compiled one-view projection (the patch stage's loops) is project_points' uv and visibility to the last
    bit: points in front, behind, outside the lens and the image, and a camera's own centre."""
    views = view_set(bundle, kinect_depth=True)
    rng = np.random.default_rng(3)
    X = np.concatenate([rng.normal(0.0, 250.0, (400, 3)), views.center_cm[:3], [[np.nan, 0.0, 0.0]]])
    for v in range(len(views.names)):
        p = project_points(views.at([v]), X)
        uv, visible = project_view(views, v, X)
        assert np.array_equal(uv, p.uv_px[0], equal_nan=True), views.names[v]
        assert np.array_equal(visible, p.visible[0]), views.names[v]
    assert visible.any() and not visible.all()
    with pytest.raises(ReconError, match="expected"):
        project_view(views, 0, X[:, :2])


def test_project_view_rows_is_the_projection_of_whole_groups(bundle):
    """Groups of points (a patch's square) projected row by row: the pixels of project_points (to ~1e-13 px: the
    transform is not BLAS's) and whether every point of the group is visible."""
    views = view_set(bundle)
    rng = np.random.default_rng(4)
    X = rng.normal(0.0, 150.0, (300, 1, 3)) + rng.normal(0.0, 20.0, (300, 9, 3))
    rows = np.arange(0, 300, 2)
    for v in (0, 100, len(views.names) - 1):
        p = project_points(views.at([v]), X[rows].reshape(-1, 3))
        uv, whole = project_view_rows(views, v, X, rows)
        vis = p.visible[0].reshape(len(rows), 9)
        assert np.array_equal(whole, vis.all(axis=1)) and whole.any() and not whole.all()
        np.testing.assert_allclose(uv[whole], p.uv_px[0].reshape(len(rows), 9, 2)[whole], rtol=0, atol=1e-9)
