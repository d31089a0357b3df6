"""`dome-calib triangulate` and `dome-calib pointcloud`, run as a technician would (subprocess, real exit codes)."""
from __future__ import annotations

import json
import subprocess

import cv2
import numpy as np
import pytest

from dome_calib.bundle_io import write_bundle
from dome_calib.recon.depth import read_ply
from dome_calib.synth.skeleton import skeleton_cm, synthetic_tracks
from dome_calib.synth.depth import distance_to_triangles, render_depth_mm, tent_triangles

from .recon_helpers import read_skeleton, real_bundle



def _one_line_error(out: subprocess.CompletedProcess) -> str:
    assert out.returncode == 1, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dome-calib: error:"), out.stderr
    assert "Traceback" not in out.stderr
    return lines[0]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A bundle folder (40 VGA + 31 HD + 10 Kinect, sync tables) and a detections file of the synthetic body."""
    root = tmp_path_factory.mktemp("recon_cli")
    bundle = real_bundle(n_vga=40, start_ms=1000.0, duration_ms=800.0, seed=7)
    write_bundle(bundle, root / "bundle")
    cams = {}
    for s in synthetic_tracks(bundle, sorted(bundle.cameras), seed=8):
        for v, name in enumerate(s.cameras):
            uv = np.nan_to_num(s.uv_px[:, v], nan=0.0)
            joints = np.concatenate([uv, s.conf[:, v, :, None]], axis=-1)
            cams[name] = {"frames": s.frame_index.tolist(), "joints": np.round(joints, 3).tolist()}
    # One joint (left ear) undetected everywhere: it must come out with confidence -1.
    for entry in cams.values():
        for frame in entry["joints"]:
            frame[16] = [0.0, 0.0, 0.0]
    (root / "detections.json").write_text(json.dumps({"joints": 19, "body_id": 3, "cameras": cams}))
    return root, bundle


def test_triangulate_writes_panoptic_skeletons(session, dome_calib_cli):
    root, bundle = session
    out = dome_calib_cli("triangulate", str(root / "detections.json"), "--bundle", str(root / "bundle"), "-o", str(root / "sk"))
    assert out.returncode == 0, out.stderr
    assert "joints reconstructed" in out.stdout
    files = sorted((root / "sk").glob("body3DScene_*.json"))
    vga = bundle.sync.streams["vga"]
    assert [int(f.stem.split("_")[1]) for f in files] == vga.index.tolist()  # default: every VGA frame
    data = json.loads(files[5].read_text())
    assert data["version"] == 0.7 and data["fpsType"] == "vga_25" and data["bodies"][0]["id"] == 3
    assert len(data["bodies"][0]["joints19"]) == 76
    errors = []
    for f in files:
        t_ms, X, c = read_skeleton(f)
        assert t_ms == pytest.approx(vga.time_of(int(f.stem.split("_")[1])), abs=1e-3)
        assert c[16] == -1 and np.isnan(X[16]).all()
        ok = c >= 0
        assert ok.sum() >= 17  # frames at the ends of the short Kinect/HD spans may lose a joint, not more
        errors.append(np.linalg.norm(X[ok] - skeleton_cm(np.array([t_ms]))[0][ok], axis=-1))
    assert np.concatenate(errors).mean() * 10.0 < 3.0  # mm


def test_triangulate_at_explicit_times(session, tmp_path, dome_calib_cli):
    root, _ = session
    det = json.loads((root / "detections.json").read_text())
    det["times_ms"] = [1200.0, 1234.5]
    (tmp_path / "d.json").write_text(json.dumps(det))
    out = dome_calib_cli("triangulate", str(tmp_path / "d.json"), "--bundle", str(root / "bundle"))
    assert out.returncode == 0, out.stderr
    files = sorted((tmp_path / "d_skeletons").glob("body3DScene_*.json"))
    assert [f.name for f in files] == ["body3DScene_00000000.json", "body3DScene_00000001.json"]
    t_ms, X, c = read_skeleton(files[1])
    assert t_ms == 1234.5 and json.loads(files[1].read_text())["fpsType"] == "custom"
    assert np.nanmean(np.linalg.norm(X - skeleton_cm(np.array([t_ms]))[0], axis=-1)) * 10.0 < 3.0


def test_triangulate_bad_input_is_one_line(session, tmp_path, dome_calib_cli):
    root, _ = session
    det = json.loads((root / "detections.json").read_text())
    det["cameras"]["99_99"] = det["cameras"]["01_01"]
    (tmp_path / "d.json").write_text(json.dumps(det))
    line = _one_line_error(dome_calib_cli("triangulate", str(tmp_path / "d.json"), "--bundle", str(root / "bundle")))
    assert "camera 99_99 is not in the bundle" in line
    (tmp_path / "bad.json").write_text('{"cameras": {"01_01": {"frames": [1, 2], "joints": [[[1, 2]]]}}}')
    line = _one_line_error(dome_calib_cli("triangulate", str(tmp_path / "bad.json"), "--bundle", str(root / "bundle")))
    assert "cameras.01_01.joints[0][0]: expected a list of 3 items" in line
    (tmp_path / "x.json").write_text("{nope")
    assert "not valid JSON" in _one_line_error(dome_calib_cli("triangulate", str(tmp_path / "x.json"), "--bundle",
                                                    str(root / "bundle")))
    assert not (tmp_path / "d_skeletons").exists()


def test_pointcloud_command(session, tmp_path, dome_calib_cli):
    root, bundle = session
    tris = tent_triangles()
    t_ms = 1400.0
    for node in ("KINECTNODE2", "KINECTNODE7"):
        k, _ = bundle.sync.kinect_depth[node].nearest(t_ms)
        (tmp_path / "depth" / node).mkdir(parents=True)
        frame = render_depth_mm(bundle, node, tris, noise_mm=1.0)
        cv2.imwrite(str(tmp_path / "depth" / node / f"depth_{int(k):04d}.png"), frame)
    out = dome_calib_cli("pointcloud", "--bundle", str(root / "bundle"), "--time-ms", str(t_ms), "--depth",
               str(tmp_path / "depth"), "-o", str(tmp_path / "cloud.ply"))
    assert out.returncode == 0, out.stderr
    assert "from 2 Kinects" in out.stdout
    cloud = read_ply(tmp_path / "cloud.ply")
    assert cloud.sensors == ["KINECTNODE2", "KINECTNODE7"]
    sample = cloud.xyz_cm[:: max(len(cloud.xyz_cm) // 3000, 1)]
    assert np.median(distance_to_triangles(sample, tris)) * 10.0 < 5.0 + 1.0
    line = _one_line_error(dome_calib_cli("pointcloud", "--bundle", str(root / "bundle"), "--time-ms", "1e7", "--depth",
                                str(tmp_path / "depth"), "-o", str(tmp_path / "far.ply")))
    assert "no Kinect depth frame near" in line and not (tmp_path / "far.ply").exists()
    line = _one_line_error(dome_calib_cli("pointcloud", "--bundle", str(root / "bundle"), "--time-ms", "0", "--depth",
                                str(tmp_path / "nowhere")))
    assert "depth folder not found" in line
