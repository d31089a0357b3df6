"""Issue 15, triangulate: NaN confidence = not detected for that joint (never a dropped time step), confidences
outside [0, 1] refused in one line naming file, camera, frame and joint, times outside the detections' sync span
an error (all) or a warning with counts (some), and the skeleton folder replaced as a whole."""
from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from dome_calib.ownership import RECORD
from dome_calib.bundle_io import write_bundle
from dome_calib.errors import DomeCalibError
from dome_calib.recon.commands import triangulate_file
from dome_calib.recon.errors import ReconError
from dome_calib.recon.project import view_set
from dome_calib.synth.skeleton import skeleton_cm, synthetic_tracks
from dome_calib.recon.triangulate import triangulate

from .recon_helpers import read_skeleton, real_bundle

MEAN_TOL_CM = 1.0  # mean joint error: 2 px detection noise, 10 % wrong detections, 12 VGA cameras


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 12-VGA bundle with sync tables (1000..1400 ms) and detections of the synthetic body in its VGA cameras."""
    root = tmp_path_factory.mktemp("recon_hardening")
    bundle = real_bundle(n_vga=12, kinect=False, start_ms=1000.0, duration_ms=400.0, seed=3)
    write_bundle(bundle, root / "bundle")
    vga = sorted(bundle.of_type("vga"))
    cams = {}
    for s in synthetic_tracks(bundle, vga, seed=4):
        for v, name in enumerate(s.cameras):
            joints = np.concatenate([np.nan_to_num(s.uv_px[:, v], nan=0.0), s.conf[:, v, :, None]], axis=-1)
            cams[name] = {"frames": s.frame_index.tolist(), "joints": np.round(joints, 3).tolist()}
    return root, bundle, {"joints": 19, "cameras": cams}


def _write(tmp_path, det) -> str:
    path = tmp_path / "det.json"
    path.write_text(json.dumps(det))
    return str(path)


def _copy(det):
    return json.loads(json.dumps(det))


def test_one_null_confidence_drops_only_that_detection(session, tmp_path):
    """null: not detected (NaN, which JSON lacks, is refused naming its place: the detections file's schema)."""
    root, bundle, det = session
    det = _copy(det)
    vga = bundle.sync.streams["vga"]
    first = det["cameras"]["01_01"]["frames"][0]
    det["cameras"]["01_01"]["joints"][0][4][2] = None  # camera 01_01, its first frame, joint 4
    summary = triangulate_file(root / "bundle", _write(tmp_path, det), tmp_path / "sk")
    files = sorted((tmp_path / "sk").glob("body3DScene_*.json"))
    numbers = [int(f.stem.split("_")[1]) for f in files]
    assert first in numbers and summary.times == len(vga.index)  # the time step is kept
    t_ms, X, c = read_skeleton(tmp_path / "sk" / f"body3DScene_{first:08d}.json")
    ok = c >= 0
    assert ok[4] and ok.sum() >= 17
    assert np.linalg.norm(X[ok] - skeleton_cm(np.array([t_ms]))[0][ok], axis=-1).mean() < MEAN_TOL_CM


@pytest.mark.parametrize(("value", "shown"), [(10.72, "confidence 10.72 outside [0, 1]"),
                                              (-0.3, "confidence -0.3 outside [0, 1]"),
                                              (float("inf"), "expected a finite number or null, got Infinity")])
def test_confidence_outside_0_1_is_one_line_naming_camera_frame_joint(session, tmp_path, value, shown):
    root, _, det = session
    det = _copy(det)
    frame = det["cameras"]["09_04"]["frames"][2]
    det["cameras"]["09_04"]["joints"][2][7][2] = value
    path = _write(tmp_path, det)
    with pytest.raises(ReconError) as err:
        triangulate_file(root / "bundle", path, tmp_path / "sk")
    message = str(err.value)
    assert "\n" not in message and message.startswith(path)
    assert f"cameras.09_04.joints[2][7][2]: {shown}" in message and frame == det["cameras"]["09_04"]["frames"][2]
    assert not (tmp_path / "sk").exists()


def test_triangulate_refuses_confidence_above_one():
    bundle = real_bundle(n_vga=6, kinect=False, sync=False)
    views = view_set(bundle)
    uv = np.full((3, len(views.names), 2), 100.0)  # any pixels: refused before use
    conf = np.full((3, len(views.names)), 0.9)
    conf[1, 2] = 1.5
    with pytest.raises(ReconError, match=rf"confidence 1.5 of point 1 in view {views.names[2]} is outside \[0, 1\]"):
        triangulate(views, uv, conf)


def test_all_times_outside_the_sync_span_is_an_error(session, tmp_path):
    root, _, det = session
    det = {**_copy(det), "times_ms": [5000.0, 5040.0, 9000.0]}
    path = _write(tmp_path, det)
    with pytest.raises(ReconError, match=r"times_ms: none of the 3 times lies within") as err:
        triangulate_file(root / "bundle", path, tmp_path / "sk")
    assert "(vga " in str(err.value) and "\n" not in str(err.value)
    assert not (tmp_path / "sk").exists()


def test_some_times_outside_the_sync_span_warn_with_counts(session, tmp_path, caplog):
    root, _, det = session
    det = {**_copy(det), "times_ms": [500.0, 1200.0, 1250.0, 8000.0]}
    with caplog.at_level(logging.WARNING, logger="dome_calib"):
        summary = triangulate_file(root / "bundle", _write(tmp_path, det), tmp_path / "sk")
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "2 of 4 times lie outside" in warnings[0]
    assert summary.times == 4 and summary.reconstructed >= 2 * 17
    confidence = [read_skeleton(tmp_path / "sk" / f"body3DScene_{k:08d}.json")[2] for k in range(4)]
    assert np.all(confidence[0] == -1) and np.all(confidence[3] == -1)
    assert (confidence[1] >= 0).sum() >= 17 and (confidence[2] >= 0).sum() >= 17


def test_rerun_replaces_the_skeleton_folder_whole(session, tmp_path):
    root, _, det = session
    triangulate_file(root / "bundle", _write(tmp_path, det), tmp_path / "sk")
    assert len(list((tmp_path / "sk").iterdir())) > 3
    few = {**_copy(det), "times_ms": [1200.0, 1250.0]}
    triangulate_file(root / "bundle", _write(tmp_path, few), tmp_path / "sk")
    assert sorted(p.name for p in (tmp_path / "sk").iterdir()) == [RECORD, "body3DScene_00000000.json",
                                                                   "body3DScene_00000001.json"]  # nothing stale
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".sk.")]  # no staging left behind
    (tmp_path / "sk" / "notes.txt").write_text("mine")
    with pytest.raises(DomeCalibError, match=r"sk: holds notes.txt \(the record .* does not list it\)"):
        triangulate_file(root / "bundle", _write(tmp_path, few), tmp_path / "sk")
    assert (tmp_path / "sk" / "notes.txt").read_text() == "mine"


def test_kinect_colour_camera_not_named_50_n_is_one_line():
    from dataclasses import replace

    from dome_calib.recon.streams import stream_of_camera

    bundle = real_bundle(n_vga=2, kinect=False)
    bundle.cameras["kinect_a"] = replace(bundle.cameras["50_01"], name="kinect_a")
    assert stream_of_camera(bundle, "50_01")[0] == "KINECTNODE1"
    with pytest.raises(ReconError, match=r"Kinect colour camera 'kinect_a' is not named 50_<n>"):
        stream_of_camera(bundle, "kinect_a")


def test_detected_frames_missing_from_the_sync_table_are_named(session, tmp_path, caplog):
    root, bundle, det = session
    det = {**_copy(det), "times_ms": [1200.0]}
    entry = det["cameras"]["01_01"]
    missing = int(bundle.sync.streams["vga"].index[-1]) + 50
    entry["frames"].append(missing)
    entry["joints"].append(entry["joints"][-1])
    with caplog.at_level(logging.WARNING, logger="dome_calib"):
        triangulate_file(root / "bundle", _write(tmp_path, det), tmp_path / "sk")
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert f"stream vga: 1 of {len(entry['frames'])} frames with detections are not in the sync table" in warnings[0]
    assert f"(first: frame {missing})" in warnings[0]
