"""Issue 15: every field of the four bundle files (and session.json) is checked before use. Each case below was a
traceback or a silent acceptance before; now it is one line naming file, camera, and the field path (or a stated
warning where a user expects the file to load). Since issue 42 the files are read through their schemas
(dome_calib.bundle_schema, timecode.sync.session), which word the lines."""
from __future__ import annotations

import copy
import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from dome_calib.bundle_io import load_bundle
from dome_calib.errors import BundleFormatError, DomeCalibError
from dome_calib.panoptic_io import read_calibration, read_kcalibration, read_ksynctables, read_synctables

from .conftest import REAL_CALIBRATION, REAL_KCALIBRATION

CAL = json.loads(REAL_CALIBRATION.read_text())
KCAL = json.loads(REAL_KCALIBRATION.read_text())
SYNC = {"vga": {"index": [0, 1, 2], "univ_time": [0.0, 40.0, 80.0]}, "hd": {"index": [5, 6], "univ_time": [1.0, 34.4]}}
KSYNC = {"kinect": {"color": {"KINECTNODE1": {"index": [0, 1], "univ_time": [3.0, 36.3]}},
                    "depth": {"KINECTNODE1": {"index": [0, 1], "univ_time": [4.0, 37.3]}}}}


def _cal(edit) -> dict:
    data = copy.deepcopy(CAL)
    data["cameras"] = data["cameras"][:6]
    edit(data)
    return data


def _kcal(edit) -> dict:
    data = copy.deepcopy(KCAL)
    data["sensors"] = data["sensors"][:3]
    edit(data)
    return data


def _edit(key, value):
    def edit(data):
        target = data
        for k in key[:-1]:
            target = target[k]
        target[key[-1]] = value
    return edit


def _pop(key):
    def edit(data):
        target = data
        for k in key[:-1]:
            target = target[k]
        target.pop(key[-1])
    return edit


def _same_name(data):
    data["sensors"][0]["name"] = data["sensors"][1]["name"] = "KINECTNODE2"


# (reader, file name, content, expected message part); each one was a traceback or silently accepted before
CASES = {
    "type missing": (read_calibration, "calibration", _cal(_pop(["cameras", 2, "type"])),
                     "camera 01_03: cameras[2].type: missing (expected \"vga\" or \"hd\" or \"kinect-color\")"),
    "type a list": (read_calibration, "calibration", _cal(_edit(["cameras", 2, "type"], ["vga"])),
                    "camera 01_03: cameras[2].type: expected \"vga\" or \"hd\" or \"kinect-color\", got [\"vga\"]"),
    "panel a string": (read_calibration, "calibration", _cal(_edit(["cameras", 1, "panel"], "one")),
                       "camera 01_02: cameras[1].panel: expected an integer >= 0 and <= 2^63-1, got \"one\""),
    "panel null": (read_calibration, "calibration", _cal(_edit(["cameras", 1, "panel"], None)),
                   "camera 01_02: cameras[1].panel: expected an integer >= 0 and <= 2^63-1, got null"),
    "node a float": (read_calibration, "calibration", _cal(_edit(["cameras", 1, "node"], 2.5)),
                     "camera 01_02: cameras[1].node: expected an integer >= 0 and <= 2^63-1, got 2.5"),
    "empty cameras": (read_calibration, "calibration", _cal(_edit(["cameras"], [])),
                      "cameras: expected a non-empty list of objects, got []"),
    "camera not an object": (read_calibration, "calibration", _cal(_edit(["cameras", 3], [1, 2])),
                             "cameras[3]: expected an object, got [1, 2]"),
    "K of booleans": (read_calibration, "calibration",
                      _cal(_edit(["cameras", 0, "K"], [[True, False, True], [False, True, True], [False, False, 1]])),
                      "camera 01_01: cameras[0].K[0][0]: expected a finite number >= -1e+06 and <= 1e+06, got true"),
    "K of strings": (read_calibration, "calibration",
                     _cal(_edit(["cameras", 0, "K"], [["745", "0", "320"], ["0", "745", "240"], ["0", "0", "1"]])),
                     "camera 01_01: cameras[0].K[0][0]: expected a finite number >= -1e+06 and <= 1e+06, got \"745\""),
    "t = 1e308": (read_calibration, "calibration", _cal(_edit(["cameras", 4, "t"], [[1e308], [0.0], [0.0]])),
                  "camera 01_05: cameras[4].t[0]: expected a finite number >= -1e+06 and <= 1e+06, got 1e+308"),
    "t an integer beyond float": (read_calibration, "calibration",
                                  _cal(_edit(["cameras", 4, "t"], [[10**400], [0], [0]])),
                                  "camera 01_05: cameras[4].t[0]: expected a finite number >= -1e+06 and <= 1e+06, got <an "
                                  "integer of 1329 bits>"),  # said by its size (schema.show), never spelt out
    "rotation off by 1e-4": (read_calibration, "calibration",
                             _cal(_edit(["cameras", 5, "R"], [[1.0, 1e-4, 0], [0, 1, 0], [0, 0, 1]])),
                             "camera 01_06: cameras[5].R: not a rotation (|R R^T - I| = 0.0001"),
    "calibDataSource a list": (read_calibration, "calibration", _cal(_edit(["calibDataSource"], ["x"])),
                               "calibDataSource: expected a string, got [\"x\"]"),
    "top level a list": (read_calibration, "calibration", [1, 2], "the file: expected an object with calibDataSource, cameras, got [1, 2]"),
    "strings in distCoeffs_depth": (read_kcalibration, "kcalibration",
                                    _kcal(_edit(["sensors", 1, "distCoeffs_depth"], ["0.1"] * 5)),
                                    "sensors[1].distCoeffs_depth[0]: expected a finite number >= -1e+06 and <= 1e+06, got \"0.1\""),
    "color_time_offset a string": (read_kcalibration, "kcalibration",
                                   _kcal(_edit(["sensors", 0, "color_time_offset"], "3 ms")),
                                   "sensors[0].color_time_offset: expected a finite number >= -8.64e+07 and <= 8.64e+07, got \"3 ms\""),
    "depth_time_offset a boolean": (read_kcalibration, "kcalibration",
                                    _kcal(_edit(["sensors", 0, "depth_time_offset"], True)),
                                    "sensors[0].depth_time_offset: expected a finite number >= -8.64e+07 and <= 8.64e+07, got true"),
    "a list as sensor name": (read_kcalibration, "kcalibration", _kcal(_edit(["sensors", 2, "name"], ["KINECTNODE3"])),
                              "sensors[2].name: expected KINECTNODE<n> or null, got [\"KINECTNODE3\"]"),
    "two sensors with one name": (read_kcalibration, "kcalibration", _kcal(_same_name),
                                  "sensor KINECTNODE2: sensors[1].name: duplicate sensor name KINECTNODE2"),
    "empty sensors": (read_kcalibration, "kcalibration", _kcal(_edit(["sensors"], [])),
                      "sensors: expected a non-empty list of objects, got []"),
    "M_world2sensor not rigid": (read_kcalibration, "kcalibration",
                                 _kcal(_edit(["sensors", 0, "M_world2sensor"],
                                             [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])),
                                 "sensors[0].M_world2sensor: not a rotation (|R R^T - I| = 3"),
    "M_world2vga singular": (read_kcalibration, "kcalibration",
                             _kcal(_edit(["M_world2vga"], [[0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])),
                             "M_world2vga: the 3x3 block is not a scaled rotation (det = 0)"),
    "sync univ_time of strings": (read_synctables, "synctables",
                                  {"vga": {"index": [0, 1], "univ_time": ["0.0", "40.0"]}},
                                  "vga.univ_time[0]: expected a finite number, got \"0.0\""),
    "ragged sync list": (read_synctables, "synctables", {"vga": {"index": [0, 1], "univ_time": [[0.0, 1.0], [40.0]]}},
                         "vga.univ_time[0]: expected a finite number, got [0.0, 1.0]"),
    "sync index of booleans": (read_synctables, "synctables",
                               {"vga": {"index": [False, True], "univ_time": [0.0, 4.0]}},
                               "vga.index[0]: expected an integer >= 0 and <= 2^53, got false"),
    "empty sync table": (read_synctables, "synctables", {"vga": {"index": [], "univ_time": []}},
                         "vga.index: expected a non-empty list of integers >= 0 and <= 2^53, got []"),
    "sync stream not an object": (read_synctables, "synctables", {"vga": [0, 1]}, "vga: expected an object with index, univ_time, got [0, 1]"),
    "ksync univ_time of strings": (read_ksynctables, "ksynctables",
                                   {"kinect": {"color": {"KINECTNODE1": {"index": [0], "univ_time": ["x"]}},
                                               "depth": {}}},
                                   "kinect.color.KINECTNODE1.univ_time[0]: expected a finite number, got \"x\""),
    "ksync node misnamed": (read_ksynctables, "ksynctables",
                            {"kinect": {"color": {"node one": {"index": [0], "univ_time": [1.0]}}, "depth": {}}},
                            "kinect.color[\"node one\"]: expected KINECTNODE<n>, got \"node one\""),
    "ksync kinect a list": (read_ksynctables, "ksynctables", {"kinect": [1]}, "kinect: expected an object with color, depth, got [1]"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_file_is_one_line_naming_file_owner_and_field(tmp_path, case):
    reader, kind, content, expected = CASES[case]
    path = tmp_path / f"{kind}_x.json"
    path.write_text(json.dumps(content))
    with pytest.raises(BundleFormatError) as err:
        reader(path)
    message = str(err.value)
    assert isinstance(err.value, DomeCalibError) and "\n" not in message
    assert message.startswith(f"{path}: ") and expected in message, message


def test_binary_file_is_one_line(tmp_path):
    path = tmp_path / "calibration_x.json"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(BundleFormatError, match="not a UTF-8 text file"):
        read_calibration(path)


# --- rotations written with few decimals: accepted, re-orthonormalised, said once --------------------------------


def test_rotations_with_six_decimals_load_with_one_warning(tmp_path, caplog):
    data = copy.deepcopy(CAL)
    for cam in data["cameras"]:
        cam["R"] = [[round(v, 6) for v in row] for row in cam["R"]]
    path = tmp_path / "calibration_six.json"
    path.write_text(json.dumps(data))
    deviation = max(np.abs(np.array(c["R"]) @ np.array(c["R"]).T - np.eye(3)).max() for c in data["cameras"])
    assert 1e-6 < deviation < 1e-5  # accepted up to 1e-5 (ROTATION_REPAIR_TOL); 1e-6 refused this file
    with caplog.at_level(logging.WARNING, logger="dome_calib"):
        cameras, _ = read_calibration(path)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "replaced by the nearest rotation" in warnings[0] and str(path) in warnings[0]
    original, _ = read_calibration(REAL_CALIBRATION)
    for name, cam in cameras.items():
        np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(cam.R) == pytest.approx(1.0, abs=1e-14)
        assert np.abs(cam.R - original[name].R).max() < 1e-6  # the nearest rotation: within the rounding


def test_exact_rotations_are_kept_bit_for_bit_without_warning(caplog):
    with caplog.at_level(logging.WARNING, logger="dome_calib"):
        cameras, _ = read_calibration(REAL_CALIBRATION)
    assert not caplog.records
    by_name = {c["name"]: c for c in CAL["cameras"]}
    assert all(np.array_equal(cam.R, by_name[n]["R"]) for n, cam in cameras.items())


# --- kcalibration without "convention": loads with one stated warning ----------------------------------------------


def test_kcalibration_without_convention_warns_once(caplog):
    assert "convention" not in KCAL  # the Panoptic toolbox writes none
    with caplog.at_level(logging.WARNING, logger="dome_calib"):
        kinect = read_kcalibration(REAL_KCALIBRATION)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert "no 'convention' field" in warnings[0] and "M_color = sensor_from_color" in warnings[0]
    assert len(kinect.sensors) == 10


def test_kcalibration_with_our_convention_loads_quietly(tmp_path, caplog):
    from dome_calib.panoptic_io import format_kcalibration

    path = tmp_path / "kcalibration_x.json"
    path.write_text(format_kcalibration(read_kcalibration(REAL_KCALIBRATION)))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="dome_calib"):
        read_kcalibration(path)
    assert not caplog.records


def test_bad_file_inside_a_bundle_names_it(tmp_path):
    shutil.copy(REAL_CALIBRATION, tmp_path / "calibration_s.json")
    (tmp_path / "synctables_s.json").write_text(json.dumps(SYNC))
    (tmp_path / "ksynctables_s.json").write_text(json.dumps(KSYNC))
    assert load_bundle(tmp_path).sync.kinect_color["KINECTNODE1"].index.tolist() == [0, 1]
    bad = copy.deepcopy(KSYNC)
    bad["kinect"]["depth"]["KINECTNODE1"]["univ_time"] = [4.0, None]
    (tmp_path / "ksynctables_s.json").write_text(json.dumps(bad))
    with pytest.raises(BundleFormatError, match=r"ksynctables_s.json: kinect.depth.KINECTNODE1.univ_time\[1\]: expected a "
                                                "finite number, got null"):
        load_bundle(tmp_path)


# --- session.json: unknown fields fail loudly -------------------------------------------------------------------


@pytest.mark.parametrize("where", ["top", "ltc", "stream", "kinect"])
def test_session_json_typo_key_is_refused(tmp_path, where):
    from timecode.sync.session import SessionError, load_session

    doc = {"format": "dome-sync-session", "version": 1, "seq": "s",
           "ltc": {"file": "ltc.wav", "vga_channel": 0, "hd_channel": 1, "vga_rate": "25", "hd_rate": "29.97df"},
           "streams": {"vga": {"clock": "vga", "index": [1, 2], "ref_index": 1, "ref_timecode": "10:00:00:00"}},
           "kinect": {"KINECTNODE1": {"audio": None, "timestamps": "ts.json"}}}
    (tmp_path / "ts.json").write_text(json.dumps({"color": {"index": [0], "device_time_100ns": [0]},
                                                  "depth": {"index": [0], "device_time_100ns": [0]}}))
    (tmp_path / "session.json").write_text(json.dumps(doc))
    assert load_session(tmp_path).seq == "s"
    typo = {"top": (doc, "kinnect", "kinnect"), "ltc": (doc["ltc"], "hd_chanel", "ltc.hd_chanel"),
            "stream": (doc["streams"]["vga"], "ref_timecod", "streams.vga.ref_timecod"),
            "kinect": (doc["kinect"]["KINECTNODE1"], "audio_chanel", "kinect.KINECTNODE1.audio_chanel")}
    obj, key, field = typo[where]
    obj[key] = 1
    (tmp_path / "session.json").write_text(json.dumps(doc))
    with pytest.raises(SessionError, match=rf"session.json: {field}: unknown field \(known fields: ") as err:
        load_session(tmp_path)
    assert "\n" not in str(err.value)


def test_unmodified_fixtures_load(tmp_path):
    """The base of every case above loads: each failure comes from its one edit."""
    for reader, kind, content in ((read_calibration, "calibration", _cal(lambda d: None)),
                                  (read_kcalibration, "kcalibration", _kcal(lambda d: None)),
                                  (read_synctables, "synctables", SYNC), (read_ksynctables, "ksynctables", KSYNC)):
        path = Path(tmp_path / f"{kind}_ok.json")
        path.write_text(json.dumps(content))
        reader(path)
