"""Detections JSON in, Panoptic body3DScene out: validation messages, default times, round trip."""
from __future__ import annotations

import json

import numpy as np
import pytest

from dome_calib.recon.errors import ReconError
from dome_calib.recon.formats import default_times, read_detections, write_skeletons
from dome_calib.recon.streams import SkeletonSequence, group_by_stream

from .recon_helpers import read_skeleton, real_bundle


def _write(tmp_path, obj) -> str:
    path = tmp_path / "d.json"
    path.write_text(json.dumps(obj))
    return str(path)


def test_detections_are_validated_with_file_camera_and_field(tmp_path):
    good = {"cameras": {"00_01": {"frames": [1, 2], "joints": [[[1, 2, 0.5]] * 19] * 2}}}
    parsed = read_detections(_write(tmp_path, good))
    frames, uv, conf = parsed["cameras"]["00_01"]
    assert frames.tolist() == [1, 2] and uv.shape == (2, 19, 2) and conf.shape == (2, 19)
    assert parsed["joints"] == 19 and parsed["body_id"] == 0 and parsed["times_ms"] is None
    cases = [  # one line naming the field path, through the file's schema (recon.formats.DetectionsFile)
        ({**good, "colour": 1}, "colour: unknown field"),
        ({"cameras": {}}, "cameras: expected an object mapping names to objects with frames, joints, got {}"),
        ({"cameras": {"00_01": {"frames": [2, 1], "joints": [[[1, 2, 1]]] * 2}}}, r"cameras.00_01.frames\[1\]"),
        ({"cameras": {"00_01": {"frames": [1], "joints": [[[1, 2]]]}}}, r"cameras.00_01.joints\[0\]\[0\]: expected"),
        ({**good, "joints": 15}, "19 joints but expected 15"),
        ({**good, "times_ms": [1.0, None]}, r"times_ms\[1\]: expected a finite number"),
        ({**good, "times_ms": ["soon"]}, r"times_ms\[0\]: expected a finite number"),
        ({**good, "body_id": "a"}, "body_id: expected an integer"),
    ]
    for obj, message in cases:
        with pytest.raises(ReconError, match=message):
            read_detections(_write(tmp_path, obj))


def test_default_times_follow_the_reference_stream():
    bundle = real_bundle(n_vga=4)
    vga, hd = bundle.sync.streams["vga"], bundle.sync.streams["hd"]
    det = {"01_01": (vga.index[3:6], np.zeros((3, 19, 2)), np.ones((3, 19))),
           "00_02": (hd.index[2:4], np.zeros((2, 19, 2)), np.ones((2, 19)))}
    streams = group_by_stream(bundle, det)
    times, frames, name = default_times(streams, None)
    assert name == "vga" and frames.tolist() == vga.index[3:6].tolist()
    np.testing.assert_array_equal(times, vga.univ_time_ms[3:6])
    times, frames, name = default_times(streams, "hd")
    assert name == "hd" and frames.tolist() == hd.index[2:4].tolist()
    with pytest.raises(ReconError, match="reference stream 'KINECTNODE1' has no detections"):
        default_times(streams, "KINECTNODE1")


def test_skeleton_files_round_trip(tmp_path):
    X = np.arange(2 * 19 * 3, dtype=float).reshape(2, 19, 3) - 50.0
    conf = np.full((2, 19), 0.75)
    X[1, 4], conf[1, 4] = np.nan, -1.0
    seq = SkeletonSequence(times_ms=np.array([10.0, 50.0]), X_cm=X, confidence=conf,
                           n_inliers=np.full((2, 19), 7), rms_px=np.ones((2, 19)))
    paths = write_skeletons(tmp_path, seq, np.array([100, 101]), body_id=2, fps_type="vga_25")
    assert [p.name for p in paths] == ["body3DScene_00000100.json", "body3DScene_00000101.json"]
    t_ms, X1, c1 = read_skeleton(paths[1])
    assert t_ms == 50.0 and c1[4] == -1.0 and np.isnan(X1[4]).all()
    np.testing.assert_allclose(np.delete(X1, 4, axis=0), np.delete(X[1], 4, axis=0))
    body = json.loads(paths[0].read_text())["bodies"][0]
    assert body["id"] == 2 and body["joints19"][:4] == [-50.0, -49.0, -48.0, 0.75]
    assert json.loads(paths[1].read_text())["bodies"][0]["joints19"][16:20] == [0.0, 0.0, 0.0, -1.0]
