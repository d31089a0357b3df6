"""Reading OpenPose folders: file names, camera maps, body models, and every refusal naming file, camera, frame."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dome_calib.recon.body_models import JOINT_NAMES, JOINTS19
from dome_calib.recon.errors import ReconError
from dome_calib.recon.openpose_io import frame_of_file, parse_camera_map, read_openpose_folder


def _write(path: Path, people: list[list[float]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"version": 1.3, "people": [{"pose_keypoints_2d": p} for p in people]}))


def test_frame_numbers_and_camera_maps(tmp_path):
    assert frame_of_file(Path("00_03_000000000042_keypoints.json")) == 42
    assert frame_of_file(Path("cam01.0042.json")) == 42
    assert frame_of_file(Path("cam7_run2_17.json")) == 17
    with pytest.raises(ReconError, match="no frame number"):
        frame_of_file(Path("camera.json"))
    assert parse_camera_map("cam01=00_01, cam02=00_02") == {"cam01": "00_01", "cam02": "00_02"}
    (tmp_path / "map.json").write_text(json.dumps({"cam01": "00_01"}))
    assert parse_camera_map(str(tmp_path / "map.json")) == {"cam01": "00_01"}
    with pytest.raises(ReconError, match="FOLDER=CAMERA"):
        parse_camera_map("cam01")
    (tmp_path / "bad.json").write_text("[1, 2]")
    with pytest.raises(ReconError, match=r"bad.json: the file: expected an object mapping names to non-empty strings, got \[1, 2\]"):
        parse_camera_map(str(tmp_path / "bad.json"))


def test_reads_body25b_into_joints19(tmp_path):
    names = JOINT_NAMES["BODY_25B"]
    kp = np.zeros((25, 3))
    for k, n in enumerate(names):
        kp[k] = [10.0 * k, 5.0 * k, 0.5]
    _write(tmp_path / "det" / "cam01_json" / "cam01.0007.json", [kp.ravel().tolist(), []])
    _write(tmp_path / "det" / "cam01_json" / "cam01.0008.json", [])
    det = read_openpose_folder(tmp_path / "det", body_model="BODY_25B", camera_map={"cam01_json": "00_01"},
                               cameras={"00_01"})
    assert sorted(det.people["00_01"]) == [7, 8] and det.people["00_01"][8].shape == (0, 19, 3)
    j19 = det.people["00_01"][7]
    assert j19.shape == (1, 19, 3)  # the empty person (body network off) is skipped
    lh, rh = names.index("l_hip"), names.index("r_hip")
    np.testing.assert_allclose(j19[0, JOINTS19.index("body_center")], [5.0 * (lh + rh), 2.5 * (lh + rh), 0.5])
    np.testing.assert_allclose(j19[0, JOINTS19.index("l_wrist")], kp[names.index("l_wrist")])


@pytest.mark.parametrize("case, message", [
    ("model_mismatch", "18 joints per person but body model BODY_25 has 25"),
    ("confidence", "people[0].pose_keypoints_2d: joint 0: confidence -0.5 is negative"),
    ("not_multiple", "not a multiple of 3"),
    ("no_people_key", "people: missing (expected a list of objects)"),
    ("mixed_counts", "different joint counts"),
    ("second_file", "a second file for this frame"),
    ("map_unknown", "camera map names folder 'cam09'"),
])
def test_refusals_name_file_camera_frame(tmp_path, case, message):
    folder = tmp_path / "det" / "00_01"
    path = folder / "00_01_000000000003_keypoints.json"
    good = [1.0, 2.0, 0.5] * 25
    model, cmap = "BODY_25", None
    if case == "model_mismatch":
        _write(path, [[1.0, 2.0, 0.5] * 18])
    elif case == "confidence":
        _write(path, [[1.0, 2.0, -0.5] * 25])
    elif case == "not_multiple":
        _write(path, [good[:-1]])
    elif case == "no_people_key":
        folder.mkdir(parents=True)
        path.write_text(json.dumps({"persons": []}))
    elif case == "mixed_counts":
        _write(path, [good, [1.0, 2.0, 0.5] * 18])
    elif case == "second_file":
        _write(path, [good])
        path = folder / "00_01.0003.json"
        _write(path, [good])
    else:
        _write(path, [good])
        cmap = {"cam09": "00_09"}
    with pytest.raises(ReconError) as err:
        read_openpose_folder(tmp_path / "det", body_model=model, camera_map=cmap, cameras={"00_01"})
    text = str(err.value)
    assert message in text and "\n" not in text
    if case == "second_file":
        assert "00_01.0003.json" in text and "00_01_000000000003_keypoints.json" in text
    elif case != "map_unknown":
        assert str(path) in text and "camera 00_01" in text and "frame 3" in text


def test_what_real_openpose_writes_is_read(tmp_path):
    """Confidences a little above 1 (heatmap peaks: 1.004-1.037 in real output), ``version``, ``person_id``,
    ``part_candidates``, face/hand/3D arrays present or empty, joints not detected as 0, 0, 0, a person with every
    joint zero, OpenPose 1.0's ``pose_keypoints`` name: all read; the confidences kept as written."""
    folder = tmp_path / "det" / "00_01"
    folder.mkdir(parents=True)
    body = [100.0, 200.0, 0.9] * 25
    body[2], body[5] = 1.037, 1.004
    body[9:12] = [0, 0, 0]
    files = {
        "00_01_000000000000_keypoints.json": {
            "version": 1.3, "part_candidates": [{"0": [1.0, 2.0, 0.3], "1": []}],
            "people": [{"person_id": [-1], "pose_keypoints_2d": body, "face_keypoints_2d": [1.0, 2.0, 0.1] * 70,
                        "hand_left_keypoints_2d": [], "hand_right_keypoints_2d": [], "pose_keypoints_3d": [],
                        "face_keypoints_3d": [], "hand_left_keypoints_3d": [], "hand_right_keypoints_3d": []},
                       {"person_id": [-1], "pose_keypoints_2d": [0] * 75}]},
        "00_01_000000000001_keypoints.json": {"version": "1.0", "people": [{"pose_keypoints": body,
                                                                          "face_keypoints": [], "hand_left_keypoints": []}]},
        "00_01_000000000002_keypoints.json": {"version": 1.7, "people": [{"pose_keypoints_2d": []}]},
    }
    for name, data in files.items():
        (folder / name).write_text(json.dumps(data))
    det = read_openpose_folder(tmp_path / "det", body_model="BODY_25", cameras={"00_01"})
    frame0 = det.people["00_01"][0]
    assert frame0.shape == (2, 19, 3)
    assert np.nanmax(frame0[..., 2]) == pytest.approx(1.037)
    assert det.people["00_01"][1].shape == (1, 19, 3)
    assert det.people["00_01"][2].shape == (0, 19, 3)


@pytest.mark.parametrize("person, message", [
    ({"pose_keypoints_2d": [1.0, 2.0, True] * 25}, "people[0].pose_keypoints_2d[2]: expected a finite number, got true"),
    ({"pose_keypoints_2d": [1.0, None, 0.5] * 25}, "people[0].pose_keypoints_2d[1]: expected a finite number, got null"),
    ({"pose_keypoints_2d": [1.0, 2.0, 0.5] * 25, "pose_keypoint_2d": []}, "people[0].pose_keypoint_2d: unknown field"),
    ({"pose_keypoints_2d": [float("nan"), 2.0, 0.5] * 25}, "people[0].pose_keypoints_2d[0]: expected a finite number, got NaN"),
    ({"pose_keypoints_2d": [1e400, 2.0, 0.5] * 25}, "people[0].pose_keypoints_2d[0]: expected a finite number"),
])
def test_broken_values_name_the_field(tmp_path, person, message):
    folder = tmp_path / "det" / "00_01"
    folder.mkdir(parents=True)
    path = folder / "00_01_000000000003_keypoints.json"
    path.write_text(json.dumps({"people": [person]}).replace("Infinity", "1" + "0" * 400))
    with pytest.raises(ReconError) as err:
        read_openpose_folder(tmp_path / "det", body_model="BODY_25", cameras={"00_01"})
    assert message in str(err.value) and f"{path}: camera 00_01: frame 3" in str(err.value)
