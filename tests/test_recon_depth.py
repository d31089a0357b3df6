"""Kinect depth to world: bias correction, the point cloud of a synthetic tent on the true surface, PLY, folders."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from dome_calib.ownership import RECORD
from dome_calib.recon.depth import (
    PLY_DTYPE,
    PointCloud,
    correct_depth_mm,
    depth_folder_reader,
    depth_to_world,
    pointcloud_at,
    read_ply,
    write_ply,
)
from dome_calib.recon.errors import ReconError
from dome_calib.synth.depth import distance_to_triangles, render_depth_mm, tent_triangles

from .recon_helpers import real_bundle

NOISE_MM = 2.0
NODES = ["KINECTNODE1", "KINECTNODE4", "KINECTNODE8"]


@pytest.fixture(scope="module")
def scene():
    bundle = real_bundle(n_vga=5, start_ms=0.0, duration_ms=1000.0, seed=5)
    for i, sensor in enumerate(bundle.kinect.sensors.values()):  # a different bias per sensor
        sensor.depth_bias_mm, sensor.depth_scale = 12.0 - 0.5 * i, 0.003
    tris = tent_triangles()
    rng = np.random.default_rng(11)
    frames = {node: render_depth_mm(bundle, node, tris, noise_mm=NOISE_MM, rng=rng) for node in NODES}
    return bundle, tris, frames


def test_bias_correction_inverts_the_sensor_model(scene):
    bundle, _, _ = scene
    sensor = bundle.kinect.sensors["KINECTNODE2"]
    true_mm = np.array([500.0, 1234.5, 4000.0])
    measured = true_mm * (1 + sensor.depth_scale) + sensor.depth_bias_mm
    np.testing.assert_allclose(correct_depth_mm(sensor, measured), true_mm, atol=1e-9)


def test_tent_point_cloud_lies_on_the_true_surface(scene):
    bundle, tris, frames = scene
    t_ms = 500.0
    cloud = pointcloud_at(bundle, t_ms, lambda node, k: frames.get(node), nodes=NODES)
    assert cloud.sensors == NODES
    rng = np.random.default_rng(0)
    for i, node in enumerate(NODES):
        pts = cloud.xyz_cm[cloud.sensor == i]
        assert len(pts) > 40_000  # the tent and floor fill a good part of the 512 x 424 frame
        sample = pts[rng.choice(len(pts), 4000, replace=False)]
        median_mm = np.median(distance_to_triangles(sample, tris)) * 10.0
        assert median_mm < 5.0 + NOISE_MM, node
        # Without the bias correction the same frames are off the surface by millimetres more.
        raw = depth_to_world(bundle, node, frames[node], correct_bias=False)
        raw_mm = np.median(distance_to_triangles(raw[rng.choice(len(raw), 4000, replace=False)], tris)) * 10.0
        assert raw_mm > median_mm + 3.0, node
        # Tags: the sensor's nearest depth frame and its offset from the requested time.
        k, dt = bundle.sync.kinect_depth[node].nearest(t_ms)
        np.testing.assert_allclose(cloud.time_offset_ms[cloud.sensor == i], dt, atol=1e-4)
        assert abs(dt) <= 0.5 * 1000 / 30 * 2.5


def test_ply_round_trip_and_layout(tmp_path):
    rng = np.random.default_rng(1)
    cloud = PointCloud(xyz_cm=rng.normal(size=(1000, 3)) * 100, sensor=rng.integers(0, 3, 1000).astype(np.uint8),
                       time_offset_ms=rng.normal(size=1000).astype(np.float32) * 10,
                       sensors=["KINECTNODE1", "KINECTNODE2", "KINECTNODE10"])
    path = write_ply(tmp_path / "c.ply", cloud)
    raw = path.read_bytes()
    header = raw[: raw.index(b"end_header\n") + len(b"end_header\n")]
    assert b"format binary_little_endian 1.0" in header and b"element vertex 1000" in header
    assert len(raw) == len(header) + 1000 * PLY_DTYPE.itemsize == len(header) + 17000
    back = read_ply(path)
    np.testing.assert_allclose(back.xyz_cm, cloud.xyz_cm, rtol=1e-6, atol=1e-4)
    np.testing.assert_array_equal(back.sensor, cloud.sensor)
    np.testing.assert_array_equal(back.time_offset_ms, cloud.time_offset_ms)
    assert back.sensors == cloud.sensors
    assert sorted(p.name for p in tmp_path.iterdir()) == [RECORD, "c.ply"]  # no temp file left


def test_depth_folder_and_errors(tmp_path, scene):
    bundle, _, frames = scene
    folder = tmp_path / "kinect"
    (folder / "KINECTNODE1").mkdir(parents=True)
    k, _ = bundle.sync.kinect_depth["KINECTNODE1"].nearest(500.0)
    cv2.imwrite(str(folder / "KINECTNODE1" / f"depth_{int(k):04d}.png"), frames["KINECTNODE1"])
    cv2.imwrite(str(folder / "KINECTNODE1" / f"depth_{int(k) + 1:04d}.png"), np.zeros((424, 512), np.uint8))
    read = depth_folder_reader(folder)
    np.testing.assert_array_equal(read("KINECTNODE1", int(k)), frames["KINECTNODE1"])
    assert read("KINECTNODE2", int(k)) is None
    with pytest.raises(ReconError, match="16-bit"):
        read("KINECTNODE1", int(k) + 1)
    cloud = pointcloud_at(bundle, 500.0, read)  # sensors without frames are skipped
    assert cloud.sensors == ["KINECTNODE1"]
    with pytest.raises(ReconError, match="no Kinect depth frame near"):
        pointcloud_at(bundle, 1e7, read)
    with pytest.raises(ReconError, match="rows x cols"):
        depth_to_world(bundle, "KINECTNODE1", np.zeros((10, 10), np.uint16))
    with pytest.raises(ReconError, match="depth folder not found"):
        depth_folder_reader(tmp_path / "missing")
