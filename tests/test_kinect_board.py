"""Kinect calibration maths without files: board model, renderer + detector accuracy, canonical corner order,
and the joint stereo refinement against the truth and against OpenCV's stereoCalibrate on the same corners."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from dome_calib.bundle_io import load_bundle
from dome_calib.camera import K_to_intr, pixels_to_normalized, project
from dome_calib.kinect.board import Checkerboard, RayGrid, render_board
from dome_calib.kinect.detect import canonical_order, detect_board, read_gray
from dome_calib.kinect.stereo import calibrate_stereo, opencv_stereo_calibrate, rotation_error_deg
from dome_calib.synth.kinect_boards import (IR_SIZE, KinectBoardsOptions, color_scene, draw_sensor_truth,
                                            render_color, render_ir, sample_board_pose)
from tests.conftest import DATA

BOARD = Checkerboard()


@pytest.fixture(scope="module")
def dome():
    return load_bundle(DATA / "panoptic")


def test_object_points_grid_in_mm_and_order():
    obj = BOARD.object_points_mm()
    assert obj.shape == (54, 3)
    np.testing.assert_allclose(obj[1] - obj[0], [60.0, 0, 0])  # index r * cols + c
    np.testing.assert_allclose(obj[9] - obj[0], [0, 60.0, 0])
    np.testing.assert_allclose(obj[-1], [8 * 60.0, 5 * 60.0, 0])


def test_board_cell_colours_fix_the_orientation():
    value, on = BOARD.reflectance(np.array([[30.0, 30.0], [90.0, 30.0], [-30.0, -30.0], [-70.0, 0.0]]), 1e-3)
    np.testing.assert_allclose(value, [0.0, 1.0, 0.0, 1.0])  # cell (0,0) black, (1,0) white, (-1,-1) black, border
    assert on.all()


def test_ray_grid_matches_the_exact_undistortion():
    intr, dist = np.array([365.0, 365.0, 252.6, 205.1]), np.array([0.0949, -0.27, 1e-4, -2e-4, 0.0889])
    rays = RayGrid.build(intr, dist, IR_SIZE)
    rng = np.random.default_rng(0)
    uv = np.c_[rng.integers(0, 512, 2000), rng.integers(0, 424, 2000)]
    exact = pixels_to_normalized(uv.astype(float), intr, dist)
    assert np.abs(rays.xn[uv[:, 1], uv[:, 0]] - exact).max() * 365.0 < 1e-4  # px


def test_rendered_corners_are_detected_to_a_tenth_of_a_pixel(dome, tmp_path):
    opts = KinectBoardsOptions()
    rng = np.random.default_rng(5)
    truth = draw_sensor_truth("KINECTNODE2", dome, opts, rng)
    R, t = sample_board_pose(truth, opts, rng)
    T = truth.color_from_depth_mm
    obj = BOARD.object_points_mm()
    ir_rays = RayGrid.build(K_to_intr(truth.K_depth), truth.dist_depth, IR_SIZE)
    col_rays = RayGrid.build(K_to_intr(truth.K_color), truth.dist_color, truth.color_size)
    ir = render_ir(render_board(BOARD, ir_rays, R, t, supersample=4), truth, opts, rng)
    col = render_color(render_board(BOARD, col_rays, T[:3, :3] @ R, T[:3, :3] @ t + T[:3, 3], supersample=2),
                       color_scene(truth, rng), opts, rng)
    det_ir = detect_board(ir, BOARD, what="IR")
    det_col = detect_board(col.mean(axis=2).astype(np.uint8), BOARD, what="colour")
    true_ir = project(obj, R, t, K_to_intr(truth.K_depth), truth.dist_depth).uv_px
    true_col = project(obj, T[:3, :3] @ R, T[:3, :3] @ t + T[:3, 3], K_to_intr(truth.K_color), truth.dist_color).uv_px
    assert det_ir.ok and det_col.ok
    assert np.sqrt(np.mean(np.sum((det_ir.corners_px - true_ir) ** 2, axis=1))) < 0.15  # px, canonical order
    assert np.sqrt(np.mean(np.sum((det_col.corners_px - true_col) ** 2, axis=1))) < 0.10
    # a 16-bit IR frame (as the Kinect SDK stores them) reads and detects the same
    cv2.imwrite(str(tmp_path / "ir16.png"), ir.astype(np.uint16) * 180)
    det16 = detect_board(read_gray(tmp_path / "ir16.png", IR_SIZE, "IR"), BOARD, what="IR")
    assert det16.ok and np.abs(det16.corners_px - det_ir.corners_px).max() < 0.05


def test_canonical_order_undoes_half_turns_and_mirrored_rows():
    img = np.full((200, 300), 200, np.uint8)
    g = np.stack(np.meshgrid(np.arange(9), np.arange(6)), axis=-1).reshape(-1, 2) * 20.0 + 40.0
    for j in range(-1, 6):
        for i in range(-1, 9):
            if (i + j) % 2 == 0:
                img[40 + 20 * j:60 + 20 * j, 40 + 20 * i:60 + 20 * i] = 20
    grid = g.reshape(6, 9, 2)
    for shuffled in (g, g[::-1], grid[::-1].reshape(-1, 2), grid[:, ::-1].reshape(-1, 2)):
        ordered, contrast = canonical_order(shuffled - 0.5, img, BOARD)
        np.testing.assert_allclose(ordered, g - 0.5)
        assert contrast > 150


def _synthetic_corners(dome, seed: int, frames: int, sigma_ir: float, sigma_col: float):
    opts = KinectBoardsOptions()
    rng = np.random.default_rng(seed)
    truth = draw_sensor_truth("KINECTNODE1", dome, opts, rng)
    obj, T = BOARD.object_points_mm(), truth.color_from_depth_mm
    ir, col = [], []
    for _ in range(frames):
        R, t = sample_board_pose(truth, opts, rng)
        ir.append(project(obj, R, t, K_to_intr(truth.K_depth), truth.dist_depth).uv_px)
        col.append(project(obj, T[:3, :3] @ R, T[:3, :3] @ t + T[:3, 3], K_to_intr(truth.K_color), truth.dist_color).uv_px)
    ir = np.array(ir) + rng.normal(0, sigma_ir, (frames, 54, 2))
    col = np.array(col) + rng.normal(0, sigma_col, (frames, 54, 2))
    return truth, obj, ir, col


def test_joint_refinement_recovers_truth_and_is_no_worse_than_opencv(dome):
    ours_t, ours_r, cv_fix_t, cv_fix_r, cv_guess_t = [], [], [], [], []
    for seed in range(3):
        truth, obj, ir, col = _synthetic_corners(dome, seed, frames=12, sigma_ir=0.07, sigma_col=0.04)
        T = truth.color_from_depth_mm
        args = (obj, ir, col, IR_SIZE, K_to_intr(truth.K_color), truth.dist_color)
        res = calibrate_stereo(*args)
        fix, guess = opencv_stereo_calibrate(*args), opencv_stereo_calibrate(*args, fix_color=False)
        ours_t.append(np.linalg.norm(res.t_mm - T[:3, 3]))
        ours_r.append(rotation_error_deg(res.R, T[:3, :3]))
        cv_fix_t.append(np.linalg.norm(fix["t_mm"] - T[:3, 3]))
        cv_fix_r.append(rotation_error_deg(fix["R"], T[:3, :3]))
        cv_guess_t.append(np.linalg.norm(guess["t_mm"] - T[:3, 3]))
        assert abs(res.ir_intr[0] / truth.K_depth[0, 0] - 1) < 2e-3
        assert res.sigma_ir_px == pytest.approx(0.07, rel=0.15)  # noise recovered from the residuals
        assert res.sigma_color_px == pytest.approx(0.04, rel=0.15)
        assert np.allclose(res.R @ res.R.T, np.eye(3), atol=1e-12)
    assert max(ours_t) < 1.0 and max(ours_r) < 0.1  # mm, deg with 12 poses
    assert sum(ours_t) < sum(cv_fix_t) and sum(ours_r) < sum(cv_fix_r)
    assert sum(ours_t) < 1.1 * sum(cv_guess_t)
