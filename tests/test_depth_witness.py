"""The Kinects' depth as a witness (dome_calib.recon.people.depth_witness) and the synthetic depth frames of people
(dome_calib.synth.depth_people): the margin against known depths, what gives no verdict, the rendered depth
against the geometry, ghosts removed and right joints kept on a rendered group, `reconstruct --depth`."""
from __future__ import annotations

import pickle
from dataclasses import replace

import cv2
import numpy as np
import pytest

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.recon.depth import depth_folder_reader, depth_rays
from dome_calib.recon.errors import ReconError
from dome_calib.recon.people.depth_witness import DepthSensors, DepthWitness, DepthWitnessOptions, judge_joints
from dome_calib.body3d_scene import read_scene
from dome_calib.recon.project import depth_from_world, kinect_sensor
from dome_calib.synth.depth_people import ray_capsules, render_people_depth_mm, write_group_depth
from dome_calib.synth.detector import DetectorModel, synth_detections, write_openpose_folder
from dome_calib.synth.group import GroupOptions, make_group

from .recon_helpers import real_bundle

NODE = "KINECTNODE1"


@pytest.fixture(scope="module")
def dome():
    return real_bundle(n_vga=24, start_ms=0.0, duration_ms=3000.0, seed=2)


def _points_on_pixels(bundle: Bundle, node: str, uv: np.ndarray, z_cm: np.ndarray) -> np.ndarray:
    """World points (N, 3) on the rays of depth pixels ``uv`` (N, 2) at camera depth ``z_cm`` (N,)."""
    rays = depth_rays(kinect_sensor(bundle, node))
    xy = rays[uv[:, 1], uv[:, 0]]
    X_cam = np.column_stack([xy * z_cm[:, None], z_cm])
    R, t = depth_from_world(bundle, node)
    return (X_cam - t) @ R


def test_the_margin_against_a_wall_of_known_depth(dome):
    """A flat reading of 2 m (the sensor's bias model applied): joints nearer than 2 m - margin are seen through,
    joints within the margin or behind the wall are not; no reading and outside the image give no verdict."""
    sensor = kinect_sensor(dome, NODE)
    w, h = sensor.depth_size
    o = DepthWitnessOptions()
    true_mm = 2000.0
    frame = np.full((h, w), round(true_mm * (1 + sensor.depth_scale) + sensor.depth_bias_mm), dtype=np.uint16)
    frame[:, :40] = 0  # no reading on the left
    margin_cm = o.n_sigma * o.sigma_mm(true_mm) / 10 + o.joint_cm
    rng = np.random.default_rng(0)
    uv = np.column_stack([rng.integers(60, w - 20, 19 * 4), rng.integers(20, h - 20, 19 * 4)])
    z = np.repeat([200.0 - margin_cm - 1.0, 200.0 - margin_cm + 1.0, 230.0, 100.0], 19)
    X = _points_on_pixels(dome, NODE, uv, z).reshape(4, 19, 3)
    sensors = DepthSensors.of(dome, [NODE])
    v = judge_joints(X, {NODE: frame}, sensors, o)
    assert v.reject[0].all() and not v.reject[1:3].any() and v.reject[3].all()
    assert np.all(v.judged == 1) and np.allclose(v.gap_cm[0], margin_cm + 1.0, atol=0.2)
    # the margin moves with the options
    assert not judge_joints(X, {NODE: frame}, sensors, replace(o, joint_cm=o.joint_cm + 2.0)).reject[0].any()
    # no reading near the joint, outside the image, missing joints, no frame: no verdict
    X2 = X.copy()
    X2[0, :3] = _points_on_pixels(dome, NODE, np.array([[10, 100], [20, 200], [5, 300]]), np.full(3, 100.0))
    X2[0, 3] = [0.0, -5000.0, 0.0]
    X2[0, 4] = np.nan
    v2 = judge_joints(X2, {NODE: frame}, sensors, o)
    assert np.all(v2.judged[0, :5] == 0) and not v2.reject[0, :5].any() and v2.reject[0, 5:].all()
    assert not judge_joints(X, {}, sensors, o).judged.any()
    with pytest.raises(ReconError, match="KINECTNODE1: depth frame has shape"):
        judge_joints(X, {NODE: frame[:-1]}, sensors, o)


def test_a_thin_limb_missed_by_a_pixel_still_finds_its_surface(dome):
    """The reading is searched within joint_cm of the joint's ray: a right wrist 2 cm beside its 4 cm-wide
    forearm's silhouette, in front of a far wall, is kept; 20 cm beside it, it is in free space."""
    sensor = kinect_sensor(dome, NODE)
    w, h = sensor.depth_size
    frame = np.full((h, w), 4000, dtype=np.uint16)
    frame[:, 250:254] = 2000  # a vertical limb 2 m away, ~4 px (4 cm) wide
    z = np.full(19, 202.0)
    fx = sensor.K_depth[0, 0]
    for offset_cm, expect in ((2.0, False), (20.0, True)):
        u = 252 + int(round(fx * offset_cm / 202.0))
        X = _points_on_pixels(dome, NODE, np.column_stack([np.full(19, u), np.arange(100, 290, 10)]), z)
        v = judge_joints(X[None], {NODE: frame}, DepthSensors.of(dome, [NODE]))
        assert v.reject.all() == expect and v.reject.any() == expect


def test_ray_capsules_against_sampling():
    rng = np.random.default_rng(1)
    A, B = rng.normal(0, 30, (4, 3)) + [0, 0, 300], rng.normal(0, 30, (4, 3)) + [0, 0, 300]
    r = rng.uniform(4, 15, 4)
    dirs = rng.normal(0, 0.1, (3000, 3)) + [0, 0, 1]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    s = ray_capsules(np.zeros(3), dirs, A, B, r)
    hit = np.isfinite(s)
    assert 0.05 < hit.mean() < 0.9
    # the hit point is on a capsule's surface; rays that miss pass every capsule farther than its radius
    P = dirs[hit] * s[hit, None]
    t = np.clip(np.einsum("nkc,kc->nk", P[:, None] - A, B - A) / np.sum((B - A) ** 2, 1), 0, 1)
    d = np.linalg.norm(P[:, None] - (A + t[..., None] * (B - A)), axis=-1) - r
    assert np.allclose(np.min(d, axis=1), 0.0, atol=1e-6)
    steps = np.linspace(0, 500, 5001)
    for k in np.flatnonzero(~hit)[:50]:
        Q = steps[:, None] * dirs[k]
        tq = np.clip(np.einsum("nkc,kc->nk", Q[:, None] - A, B - A) / np.sum((B - A) ** 2, 1), 0, 1)
        assert np.all(np.linalg.norm(Q[:, None] - (A + tq[..., None] * (B - A)), axis=-1) > r - 0.2)


@pytest.fixture(scope="module")
def rendered(dome, tmp_path_factory):
    """8 people, the depth frames of five Kinects round the dome over 0.25 s, written and read back."""
    truth = make_group(GroupOptions(n_people=8, scenario="mixed", start_ms=1200.0, duration_ms=1000.0, seed=2))
    folder = write_group_depth(tmp_path_factory.mktemp("depth") / "depth", dome, truth, (1290.0, 1540.0),
                               nodes=[f"KINECTNODE{k}" for k in (1, 3, 5, 7, 9)], seed=1)
    return truth, folder


def test_rendered_depth_is_the_bodies_and_the_room(dome, rendered):
    truth, folder = rendered
    reader = depth_folder_reader(folder)
    assert reader.nodes == [f"KINECTNODE{k}" for k in (1, 3, 5, 7, 9)]
    assert pickle.loads(pickle.dumps(reader)).nodes == reader.nodes
    table = dome.sync.kinect_depth[NODE]
    k = int(table.index[np.argmin(np.abs(table.univ_time_ms - 1400.0))])
    frame = reader(NODE, k)
    assert frame.dtype == np.uint16 and frame.shape == (424, 512)
    X, present = truth.joints_cm(table.times_of(np.array([k])))
    again = render_people_depth_mm(dome, NODE, X[0], present[0], rng=np.random.default_rng([1, 0, 0]))
    assert np.mean(np.abs(again.astype(float) - frame) < 30) > 0.99  # the same scene (other noise)
    # every visible true joint lies behind (or on) the surface the sensor measured at its pixel
    v = judge_joints(X[0][present[0]], {NODE: frame}, DepthSensors.of(dome, [NODE]))
    assert v.judged.sum() > 50 and not v.reject.any() and np.nanmax(v.gap_cm) < 3.0
    empty = render_people_depth_mm(dome, NODE, X[0], np.zeros(len(X[0]), bool))
    assert (frame.astype(float) < empty - 100).mean() > 0.05  # the people stand in front of the room


def test_ghosts_are_removed_and_right_joints_kept(dome, rendered):
    """Points in the air between people (where two-view ghosts form) are rejected by five Kinects; the true joints,
    moved by 1.5 cm, are kept."""
    truth, folder = rendered
    witness = DepthWitness.of(dome, depth_folder_reader(folder))
    assert len(witness.tables) == 5
    rng = np.random.default_rng(3)
    kept_right, ghost_removed = [], []
    for t in (1320.0, 1420.0, 1510.0):
        X, present = truth.joints_cm(np.array([t]))
        Xp = X[0][present[0]]
        right = Xp + rng.normal(0, 1.5, Xp.shape)
        kept_right.append(witness.keep(right, t))
        ghosts = 0.5 * (Xp + Xp[np.roll(np.arange(len(Xp)), 1)])  # between two people
        far = np.min(np.linalg.norm(ghosts.reshape(-1, 1, 3) - Xp.reshape(1, -1, 3), axis=-1), axis=1) > 15.0
        v = judge_joints(ghosts, witness.frames_at(t), witness.sensors, witness.options)
        assert np.array_equal(v.reject, ~witness.keep(ghosts, t))
        ghost_removed.append(v.reject.reshape(-1)[far & (v.judged.reshape(-1) > 0)])
    assert np.mean(np.concatenate([k.ravel() for k in kept_right])) > 0.99
    assert np.mean(np.concatenate(ghost_removed)) > 0.7, np.mean(np.concatenate(ghost_removed))  # (10 Kinects: 93 %)
    assert len(witness.frames_at(1400.0)) == 5
    assert witness.frames_at(99_000.0) == {}  # no frame near that time
    with pytest.raises(ReconError, match="no Kinect has both a depth calibration and its colour camera"):
        DepthWitness.of(replace(dome, kinect=replace(dome.kinect, sensors={})), depth_folder_reader(folder))
    with pytest.raises(ReconError, match="no Kinect has a depth calibration, a depth sync table and frames"):
        DepthWitness.of(replace(dome, sync=replace(dome.sync, kinect_depth={"KINECTNODE99": None})),
                        depth_folder_reader(folder))


def test_reconstruct_with_depth(dome, rendered, tmp_path, dome_calib_cli):
    truth, folder = rendered
    cams = sorted(dome.of_type("vga"))[::2] + sorted(dome.of_type("hd"))[::4]
    bundle = Bundle(seq=dome.seq, cameras={n: dome.cameras[n] for n in cams + ["50_01", "50_05"]},
                    calib_data_source=dome.calib_data_source, kinect=dome.kinect, sync=dome.sync)
    write_bundle(bundle, tmp_path / "bundle")
    det = synth_detections(bundle, truth, cameras=cams, univ_time_ms=(1300.0, 1530.0), model=DetectorModel(seed=1))
    write_openpose_folder(tmp_path / "det", det)
    args = ["reconstruct", str(tmp_path / "det"), "--bundle", str(tmp_path / "bundle"), "--body-model", "BODY_25"]
    plain = dome_calib_cli(*args, "-o", str(tmp_path / "plain"))
    witnessed = dome_calib_cli(*args, "-o", str(tmp_path / "witnessed"), "--depth", str(folder))
    assert plain.returncode == 0 and witnessed.returncode == 0, witnessed.stderr
    a, b = (sorted((tmp_path / name).glob("body3DScene_*.json")) for name in ("plain", "witnessed"))
    assert [f.name for f in a] == [f.name for f in b] and len(a) >= 5
    joints = [sum(int((body[:, 3] >= 0).sum()) for body in read_scene(f)[1].values()) for f in b]
    assert sum(joints) > 0.9 * sum(sum(int((body[:, 3] >= 0).sum()) for body in read_scene(f)[1].values())
                                   for f in a)
    bad = dome_calib_cli(*args, "-o", str(tmp_path / "bad"), "--depth", str(tmp_path / "nowhere"))
    assert bad.returncode == 1 and "depth folder not found" in bad.stderr and not (tmp_path / "bad").exists()
    broken = tmp_path / "broken" / "KINECTNODE1"
    broken.mkdir(parents=True)
    table = bundle.sync.kinect_depth[NODE]
    for k in table.index[(table.univ_time_ms > 1250.0) & (table.univ_time_ms < 1600.0)]:
        cv2.imwrite(str(broken / f"depth_{int(k):04d}.png"), np.zeros((4, 4, 3), np.uint8))  # 8-bit colour
    out = dome_calib_cli(*args, "-o", str(tmp_path / "bad2"), "--depth", str(tmp_path / "broken"))
    assert out.returncode == 1 and "not a 16-bit single-channel depth PNG" in out.stderr
    assert not (tmp_path / "bad2").exists()
