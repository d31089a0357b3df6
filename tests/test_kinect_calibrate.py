"""Kinect calibration end to end on a small synthetic capture (one sensor): rejected frames, stereo and depth
bias against the ground truth, depth pixels landing on the true board in the world, the kcalibration file, and
the `dome-calib kinect` command including its bad inputs."""
from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.camera import K_to_intr, pixels_to_normalized
from dome_calib.kinect.calibrate import calibrate_kinect_folder
from dome_calib.kinect.stereo import rotation_error_deg
from dome_calib.kinect.world import M_WORLD2VGA, depth_from_world_cm, depth_pixels_to_world_cm
from dome_calib.synth.kinect_boards import KinectBoardsOptions, generate_kinect_boards
from tests.conftest import REAL_CALIBRATION

SENSOR = "KINECTNODE4"
NOISE = (1.0, 0.5)  # depth noise sigma_mm = a + b * z_m^2


@pytest.fixture(scope="module")
def dome_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("dome")
    shutil.copy(REAL_CALIBRATION, folder)
    return folder


@pytest.fixture(scope="module")
def capture(tmp_path_factory, dome_folder):
    """(folder, ground truth): 9 good board poses, one blurred frame, one cut-off frame."""
    folder = tmp_path_factory.mktemp("kinect")
    opts = KinectBoardsOptions(sensors=[SENSOR], good_frames=9, blurred_frames=1, cut_off_frames=1, seed=11,
                               depth_noise_mm=NOISE)
    return folder, generate_kinect_boards(load_bundle(dome_folder), folder, opts)


@pytest.fixture(scope="module")
def calibrated(capture, dome_folder):
    folder, _ = capture
    results, bundle = calibrate_kinect_folder(folder, load_bundle(dome_folder))
    return results[0], bundle


def test_blurred_and_cut_off_frames_are_rejected_with_a_reason(capture, calibrated):
    _, truth = capture
    result, _ = calibrated
    kinds = {f["index"]: f["kind"] for f in truth["sensors"][SENSOR]["frames"]}
    status = {f.index: f for f in result.frames}
    assert sorted(status) == sorted(kinds)
    for k, kind in kinds.items():
        assert status[k].used == (kind == "good"), (k, kind, status[k].reason)
        if kind == "blurred":
            assert "blurred" in status[k].reason
        if kind == "cut_off":
            assert "cut off" in status[k].reason
    assert result.frames_used == 9 and result.summary()["frames_rejected"] == 2


def test_depth_to_colour_transform_and_ir_intrinsics_match_the_truth(capture, calibrated):
    _, truth = capture
    result, _ = calibrated
    s = truth["sensors"][SENSOR]
    T = s["color_from_depth_mm"]
    st = result.stereo
    assert np.linalg.norm(st.t_mm - T[:3, 3]) < 1.5  # mm, 9 poses
    assert rotation_error_deg(st.R, T[:3, :3]) < 0.15
    assert abs(st.ir_intr[0] / s["K_depth"][0, 0] - 1) < 3e-3
    assert result.baseline_mm == pytest.approx(np.linalg.norm(T[:3, 3]), abs=1.5)
    assert st.rms_ir_px < 0.2 and st.rms_color_px < 0.1  # px: the corner noise, no model error left


def test_depth_bias_matches_the_truth(capture, calibrated):
    _, truth = capture
    result, _ = calibrated
    s = truth["sensors"][SENSOR]
    z = np.linspace(800.0, 1800.0, 11)
    model = lambda b, sc: z * sc + b  # noqa: E731  (measured - true at depth z)
    err = model(result.depth_bias.depth_bias_mm, result.depth_bias.depth_scale) - model(s["depth_bias_mm"], s["depth_scale"])
    assert np.abs(err).max() < 1.5  # mm over the board's range


def test_depth_pixels_land_on_the_true_board_in_the_world(capture, calibrated):
    folder, truth = capture
    result, bundle = calibrated
    s = truth["sensors"][SENSOR]
    frame = next(f for f in s["frames"] if f["kind"] == "good")
    depth = cv2.imread(str(folder / SENSOR / f"depth_{frame['index']:04d}.png"), cv2.IMREAD_UNCHANGED)
    v, u = np.nonzero(depth > 0)
    pick = np.random.default_rng(0).choice(len(u), 300, replace=False)
    uv = np.stack([u[pick], v[pick]], axis=1).astype(float)
    X_world_cm = depth_pixels_to_world_cm(uv, depth[v[pick], u[pick]], bundle.kinect.sensors[SENSOR], M_WORLD2VGA)
    # truth: the true pixel ray meets the true board plane; both moved to the world with the true depth pose
    P = frame["depth_from_board_mm"]
    xn = pixels_to_normalized(uv, K_to_intr(s["K_depth"]), s["dist_depth"])
    rays = np.c_[xn, np.ones(len(xn))]
    z_mm = (P[:3, 2] @ P[:3, 3]) / (rays @ P[:3, 2])
    world_from_depth = np.linalg.inv(s["depth_from_world_cm"])
    X_true_cm = (rays * z_mm[:, None] / 10.0) @ world_from_depth[:3, :3].T + world_from_depth[:3, 3]
    err_mm = 10.0 * np.linalg.norm(X_world_cm - X_true_cm, axis=1)
    sigma_mm = 1.4 * (NOISE[0] + NOISE[1] * (z_mm / 1e3) ** 2) * np.linalg.norm(rays, axis=1)
    assert np.all(err_mm < 2.0 + 4.5 * sigma_mm)
    along = 10.0 * np.sum((X_world_cm - X_true_cm) * (rays @ world_from_depth[:3, :3].T), axis=1) / np.linalg.norm(rays, axis=1)
    assert abs(np.mean(along)) < 1.0  # mm: the bias is removed, only noise is left
    assert np.median(err_mm) < 2.0 + sigma_mm.mean()


def test_kcalibration_file_round_trip_and_world_pose(capture, calibrated, tmp_path):
    _, truth = capture
    result, bundle = calibrated
    write_bundle(bundle, tmp_path)
    loaded = load_bundle(tmp_path)
    assert loaded.kinect is not None and list(loaded.kinect.sensors) == [SENSOR]
    sensor = loaded.kinect.sensors[SENSOR]
    np.testing.assert_allclose(loaded.kinect.M_world2vga, np.diag([100.0, 100, 100, 1]))
    np.testing.assert_allclose(sensor.M_depth, np.diag([-1.0, -1, 1, 1]))
    cfd = sensor.color_from_depth  # stated convention: inv(M_color) @ M_depth, metres
    np.testing.assert_allclose(cfd[:3, 3] * 1e3, result.stereo.t_mm, atol=1e-9)
    np.testing.assert_allclose(sensor.K_color, bundle.cameras["50_04"].K)  # held fixed from the dome
    D = depth_from_world_cm(sensor, loaded.kinect.M_world2vga)
    D_true = truth["sensors"][SENSOR]["depth_from_world_cm"]
    assert rotation_error_deg(D[:3, :3], D_true[:3, :3]) < 0.15
    centre = lambda T: -T[:3, :3].T @ T[:3, 3]  # noqa: E731
    assert 10.0 * np.linalg.norm(centre(D) - centre(D_true)) < 1.5  # mm
    # M_world2sensor maps the colour camera's world centre (m) to the sensor frame's colour-camera position
    c_color_m = loaded.cameras["50_04"].center_cm / 100.0
    np.testing.assert_allclose((sensor.M_world2sensor @ np.r_[c_color_m, 1])[:3], sensor.M_color[:3, 3], atol=1e-9)


def test_cli_calibrates_and_prints_a_summary(capture, calibrated, dome_folder, tmp_path, dome_calib_cli,
                                             monkeypatch):
    """The command's calibration is the library's: it is handed the folder, the dome bundle and the default
    options, and given the module's one run (``calibrated``) back instead of calibrating again; what it prints and
    writes is checked."""
    import dome_calib.kinect.calibrate as kcal

    folder, _ = capture
    result, bundle = calibrated
    calls = []

    def one_run(kinect_folder, dome, opts=None, on_frame=None):
        calls.append(1)
        assert Path(kinect_folder) == folder and opts == kcal.KinectCalibOptions()
        assert dome.seq == bundle.seq and dome.cameras.keys() == bundle.cameras.keys()
        assert dome.kinect is None and on_frame is not None
        return [result], bundle

    monkeypatch.setattr(kcal, "calibrate_kinect_folder", one_run)
    proc = dome_calib_cli("kinect", str(folder), "--bundle", str(dome_folder), "-o", str(tmp_path / "out"))
    assert calls == [1]
    assert proc.returncode == 0, proc.stderr
    assert f"{SENSOR}" in proc.stdout and "frames used   9, rejected  2" in proc.stdout
    assert "baseline 52." in proc.stdout or "baseline 53." in proc.stdout
    assert (tmp_path / "out" / "kcalibration_160906_band1.json").exists()
    assert not (dome_folder / "kcalibration_160906_band1.json").exists()  # -o: the input bundle is untouched


def _fake_capture(root: Path, ir_shapes: list[tuple[int, int]], n_color: int) -> Path:
    node = root / "KINECTNODE1"
    node.mkdir(parents=True)
    for k, (h, w) in enumerate(ir_shapes):
        cv2.imwrite(str(node / f"ir_{k:04d}.png"), np.full((h, w), 20, np.uint8))
    for k in range(n_color):
        cv2.imwrite(str(node / f"color_{k:04d}.png"), np.full((1080, 1920, 3), 90, np.uint8))
    return root


@pytest.mark.parametrize("case, message", [
    ("no_board", "no board found in any of 2 frames"),
    ("mismatch", "2 IR frames but 1 colour frames"),
    ("size", "IR image is 640x480, expected 512x424"),
])
def test_cli_bad_input_one_line_and_nothing_written(case, message, dome_folder, tmp_path, dome_calib_cli):
    shapes = {"no_board": [(424, 512)] * 2, "mismatch": [(424, 512)] * 2, "size": [(480, 640)] * 2}[case]
    folder = _fake_capture(tmp_path / "kinect", shapes, 1 if case == "mismatch" else 2)
    out = tmp_path / "out"
    proc = dome_calib_cli("kinect", str(folder), "--bundle", str(dome_folder), "-o", str(out))
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dome-calib: error:") and message in lines[0], proc.stderr
    assert not out.exists() or not any(out.iterdir())


def test_depth_to_world_agrees_with_the_reconstruction_stage(capture, calibrated):
    """Our M_world2sensor route and recon's colour-camera route (color_from_depth, then 50_<n>) give one point."""
    from dome_calib.kinect.world import depth_map_to_world_cm
    from dome_calib.recon.depth import depth_to_world

    folder, truth = capture
    _, bundle = calibrated
    k = next(f["index"] for f in truth["sensors"][SENSOR]["frames"] if f["kind"] == "good")
    depth = cv2.imread(str(folder / SENSOR / f"depth_{k:04d}.png"), cv2.IMREAD_UNCHANGED)
    ours, _ = depth_map_to_world_cm(depth, bundle.kinect.sensors[SENSOR], bundle.kinect.M_world2vga)
    assert len(ours) > 1000
    np.testing.assert_allclose(ours, depth_to_world(bundle, SENSOR, depth), atol=1e-6)  # cm


def test_truth_kcalibration_has_the_true_depth_pose(capture):
    from dome_calib.synth.kinect_boards import truth_kcalibration

    _, truth = capture
    kcal = truth_kcalibration(truth)
    D = depth_from_world_cm(kcal.sensors[SENSOR], kcal.M_world2vga)
    np.testing.assert_allclose(D, truth["sensors"][SENSOR]["depth_from_world_cm"], atol=1e-9)


def test_kinect_synth_command_writes_a_capture_and_refuses_unknown_sensors(dome_folder, tmp_path, dome_calib_cli):
    from typer.testing import CliRunner

    from dome_calib.cli import app
    from dome_calib.synth.kinect_boards import load_ground_truth

    result = CliRunner().invoke(app, ["kinect-synth", str(tmp_path / "k"), "--bundle", str(dome_folder),
                                      "--sensors", "2", "--frames", "1", "--seed", "3"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "k" / "KINECTNODE2").iterdir())[:3] == [
        "color_0000.png", "color_0001.png", "color_0002.png"]
    assert len(load_ground_truth(tmp_path / "k")["sensors"]["KINECTNODE2"]["frames"]) == 5
    proc = dome_calib_cli("kinect-synth", tmp_path / "k2", "--bundle", dome_folder, "--sensors", "11")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "KINECTNODE11" in proc.stderr, proc.stderr
