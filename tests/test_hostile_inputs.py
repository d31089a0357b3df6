"""Issue 15, the hostile table: bad inputs a careless or hostile user gives the bundle loaders (through
`dome-calib info`) and `dome-calib triangulate` / `pointcloud`. Each bad input gives exit != 0, at most two lines
on stderr, no traceback and no output written; each input a user expects to work gives the right result.

Most rows run the CLI in-process (the same `run_cli` shell, fast); a few run it as a subprocess to see the real
stderr, logging included."""
from __future__ import annotations

import copy
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dome_calib.ownership import RECORD
from dome_calib.bundle_io import write_bundle
from dome_calib.synth.skeleton import synthetic_tracks

from .conftest import REAL_CALIBRATION, REAL_KCALIBRATION
from .recon_helpers import read_skeleton, real_bundle

CAL = json.loads(REAL_CALIBRATION.read_text())
KCAL = json.loads(REAL_KCALIBRATION.read_text())


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A bundle (12 VGA + 31 HD + 10 Kinect colour cameras, sync tables 1000..1400 ms) and detections of the
    synthetic body in its VGA cameras."""
    root = tmp_path_factory.mktemp("hostile")
    bundle = real_bundle(n_vga=12, kinect=True, start_ms=1000.0, duration_ms=400.0, seed=3)
    write_bundle(bundle, root / "bundle")
    cams = {}
    for s in synthetic_tracks(bundle, sorted(bundle.of_type("vga")), seed=4):
        for v, name in enumerate(s.cameras):
            joints = np.concatenate([np.nan_to_num(s.uv_px[:, v], nan=0.0), s.conf[:, v, :, None]], axis=-1)
            cams[name] = {"frames": s.frame_index.tolist(), "joints": np.round(joints, 3).tolist()}
    return root, {"joints": 19, "cameras": cams}


def _in_process(args: list[str], monkeypatch, capsys) -> tuple[int, str, str]:
    from dome_calib.cli import app
    from dome_calib.errors import run_cli

    monkeypatch.setattr(sys, "argv", ["dome-calib", *args])
    with pytest.raises(SystemExit) as exit_:  # any other exception escapes: a traceback, and the test fails
        run_cli(app, prog="dome-calib")
    out = capsys.readouterr()
    return int(exit_.value.code or 0), out.out, out.err


def _subprocess(args: list[str]) -> tuple[int, str, str]:
    code = "from dome_calib.cli import main; main()"
    run = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120)
    return run.returncode, run.stdout, run.stderr


def _refused(code: int, err: str, expected: str) -> None:
    lines = err.strip().splitlines()
    assert code != 0 and "Traceback" not in err, err
    assert 1 <= len(lines) <= 2 and lines[-1].startswith("dome-calib: error:"), err
    assert expected in lines[-1], err


def _files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# --- bundle files: (file kind, edit of the real content, expected message part) ----------------------------------


def _cam(i, field, value):
    def edit(cal, kcal):
        cal["cameras"][i][field] = value
    return edit


def _sensor(i, field, value):
    def edit(cal, kcal):
        kcal["sensors"][i][field] = value
    return edit


def _sync(content):
    def edit(cal, kcal):
        return {"synctables": content}
    return edit


def _ksync(content):
    def edit(cal, kcal):
        return {"ksynctables": content}
    return edit


def _raw(kind, text):
    def edit(cal, kcal):
        return {kind: text}
    return edit


def _dup_sensor(cal, kcal):
    kcal["sensors"][1]["name"] = kcal["sensors"][0]["name"] = "KINECTNODE1"


def _del(i, field):
    def edit(cal, kcal):
        del cal["cameras"][i][field]
    return edit


BAD_BUNDLES = {
    "type missing": (_del(0, "type"), "calibration_h.json: camera 01_01: cameras[0].type: missing"),
    "panel a string": (_cam(1, "panel", "left"), "camera 01_02: cameras[1].panel: expected an integer >= 0"),
    "panel null": (_cam(1, "panel", None), "camera 01_02: cameras[1].panel: expected an integer >= 0 and <= 2^63-1, got null"),
    "K of booleans": (_cam(2, "K", [[True, False, True]] * 3), "camera 01_03: cameras[2].K[0][0]: expected a finite number"),
    "t = 1e308": (_cam(3, "t", [[1e308], [0], [0]]), "camera 01_04: cameras[3].t[0]: expected a finite number >= -1e+06 and <= 1e+06, got 1e+308"),
    "t NaN": (_cam(3, "t", [[float("nan")], [0], [0]]), "camera 01_04: cameras[3].t[0]: expected a finite number >= -1e+06 and <= 1e+06, got NaN"),
    "R a reflection": (_cam(4, "R", [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]), "camera 01_05: cameras[4].R: not a rotation"),
    "R off by 1e-3": (_cam(4, "R", [[1, 1e-3, 0], [0, 1, 0], [0, 0, 1]]), "camera 01_05: cameras[4].R: not a rotation (|R R^T - I| = 0.001"),
    "resolution a string": (_cam(5, "resolution", "640x480"), "camera 01_06: cameras[5].resolution: expected a list of 2 integers"),
    "name a list": (_cam(6, "name", ["01_07"]), "cameras[6].name: expected a plain name (no '/'), got [\"01_07\"]"),
    "empty cameras": (lambda cal, kcal: cal.update(cameras=[]), "cameras: expected a non-empty list of objects, got []"),
    "strings in distCoeffs_depth": (_sensor(0, "distCoeffs_depth", ["a"] * 5),
                                    "kcalibration_h.json: sensors[0].distCoeffs_depth[0]: expected a finite number"),
    "color_time_offset a string": (_sensor(1, "color_time_offset", "2ms"),
                                   "sensors[1].color_time_offset: expected a finite number"),
    "sensor name a list": (_sensor(2, "name", [1, 2]), "sensors[2].name: expected KINECTNODE<n> or null, got [1, 2]"),
    "two sensors one name": (_dup_sensor, "sensor KINECTNODE1: sensors[1].name: duplicate sensor name"),
    "M_color not 4x4": (_sensor(0, "M_color", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]), "sensors[0].M_color[0]: expected a list of 4 finite numbers"),
    "sync univ_time strings": (_sync({"vga": {"index": [0, 1], "univ_time": ["a", "b"]}}),
                               "synctables_h.json: vga.univ_time[0]: expected a finite number"),
    "sync ragged": (_sync({"vga": {"index": [0, 1], "univ_time": [[0.0], [1.0, 2.0]]}}), "vga.univ_time[0]: expected a finite number, got [0.0]"),
    "sync time backwards": (_sync({"vga": {"index": [0, 1], "univ_time": [5.0, 1.0]}}), "time does not increase"),
    "sync index 1e30": (_sync({"vga": {"index": [0, 1e30], "univ_time": [5.0, 6.0]}}), "vga.index[1]: expected an integer >= 0 and <= 2^53, got 1e+30"),
    "ksync univ_time strings": (_ksync({"kinect": {"color": {"KINECTNODE1": {"index": [0], "univ_time": ["a"]}},
                                                   "depth": {}}}), "ksynctables_h.json: kinect.color.KINECTNODE1.univ_time[0]: expected a finite number"),
    "ksync no depth": (_ksync({"kinect": {"color": {}}}), "kinect.depth: missing"),
    "calibration not JSON": (_raw("calibration", "{\"cameras\": ["), "calibration_h.json: not valid JSON"),
    "calibration binary": (_raw("calibration", b"\x89PNG\r\n\x1a\n\x00\x00"), "calibration_h.json: not a UTF-8"),
    "calibration a list": (_raw("calibration", "[1, 2, 3]"), "calibration_h.json: the file: expected an object with calibDataSource, cameras, got [1, 2, 3]"),
    "calibration nested 100000 deep": (_raw("calibration", "[" * 100000 + "]" * 100000), "calibration_h.json:"),
    "kcalibration empty": (_raw("kcalibration", ""), "kcalibration_h.json: not valid JSON"),
}


def _bundle(tmp_path: Path, edit) -> Path:
    cal, kcal = copy.deepcopy(CAL), copy.deepcopy(KCAL)
    cal["cameras"] = cal["cameras"][:8]
    raw = edit(cal, kcal) or {}
    folder = tmp_path / "b"
    folder.mkdir()
    texts = {"calibration": json.dumps(cal), "kcalibration": json.dumps(kcal),
             "synctables": json.dumps({"vga": {"index": [0, 1], "univ_time": [0.0, 40.0]}}),
             "ksynctables": json.dumps({"kinect": {"color": {}, "depth": {}}})}
    texts.update({k: v if isinstance(v, (str, bytes)) else json.dumps(v) for k, v in raw.items()})
    for kind, content in texts.items():
        path = folder / f"{kind}_h.json"
        path.write_bytes(content) if isinstance(content, bytes) else path.write_text(content)
    return folder


@pytest.mark.parametrize("case", sorted(BAD_BUNDLES))
def test_bad_bundle_file(tmp_path, monkeypatch, capsys, case):
    edit, expected = BAD_BUNDLES[case]
    folder = _bundle(tmp_path, edit)
    before = _files(folder)
    code, _, err = _in_process(["info", str(folder)], monkeypatch, capsys)
    _refused(code, err, expected)
    assert _files(folder) == before


def test_unedited_table_bundle_loads(tmp_path, monkeypatch, capsys):
    code, out, err = _in_process(["info", str(_bundle(tmp_path, lambda cal, kcal: None))], monkeypatch, capsys)
    assert code == 0 and "bundle h (" in out and ": 8 cameras" in out, out + err


def test_lenient_files_load_with_one_warning_each(tmp_path):
    """Rotations written with 6 decimals and a kcalibration without 'convention' (the Panoptic toolbox's) load;
    stderr carries exactly one warning per file (subprocess: the real logging)."""
    def six_decimals(cal, kcal):
        for cam in cal["cameras"]:
            cam["R"] = [[round(v, 6) for v in row] for row in cam["R"]]
    folder = _bundle(tmp_path, six_decimals)
    code, out, err = _subprocess(["info", str(folder)])
    lines = err.strip().splitlines()
    assert code == 0 and "Traceback" not in err and len(lines) == 2, err
    assert "calibration_h.json" in lines[0] and "replaced by the nearest rotation" in lines[0]
    assert "kcalibration_h.json" in lines[1] and "no 'convention' field" in lines[1]
    assert ": 8 cameras" in out and "kinect depth calibration: 10 sensors" in out


# --- triangulate: (edit of the detections, expected message part) ------------------------------------------------


def _joint(cam, frame, joint, value):
    def edit(det):
        det["cameras"][cam]["joints"][frame][joint] = value
    return edit


def _key(key, value):
    def edit(det):
        det[key] = value
    return edit


def _camera(cam, field, value):
    def edit(det):
        det["cameras"][cam][field] = value
    return edit


BAD_DETECTIONS = {  # the field path of the schema's one line (recon.formats.DetectionsFile)
    "confidence 10.72": (_joint("01_01", 3, 5, [300.0, 200.0, 10.72]), "cameras.01_01.joints[3][5][2]: confidence"),
    "confidence -0.5": (_joint("02_16", 0, 0, [300.0, 200.0, -0.5]), "confidence -0.5 outside [0, 1]"),
    "confidence a string": (_joint("01_01", 3, 5, [300.0, 200.0, "high"]), "cameras.01_01.joints[3][5][2]"),
    "pixel infinite": (_joint("01_01", 3, 5, [float("inf"), 200.0, 0.9]), "cameras.01_01.joints[3][5][0]: expected a "
                       "finite number or null, got Infinity"),
    "pixel NaN": (_joint("01_01", 3, 5, [float("nan"), 200.0, 0.9]), "cameras.01_01.joints[3][5][0]: expected a "
                  "finite number or null, got NaN"),
    "joint of two numbers": (_joint("01_01", 3, 5, [300.0, 200.0]), "cameras.01_01.joints[3][5]"),
    "joints of booleans": (_camera("01_01", "joints", [[[True, True, True]] * 19]), "cameras.01_01.joints"),
    "frames as floats": (_camera("01_01", "frames", [0.5]), "cameras.01_01.frames[0]"),
    "frames NaN": (_camera("01_01", "frames", [float("nan")]), "cameras.01_01.frames[0]"),
    "cameras a list": (_key("cameras", [1, 2]), "cameras: expected"),
    "unknown camera": (lambda det: det["cameras"].update({"99_99": det["cameras"]["01_01"]}),
                       "camera 99_99 is not in the bundle"),
    "times_ms strings": (_key("times_ms", ["noon"]), "times_ms[0]"),
    "times_ms all outside": (_key("times_ms", [1e7, 2e7]), "none of the 2 times lies within"),
    "times_ms empty": (_key("times_ms", []), "times_ms: expected"),
    "reference a list": (_key("reference", ["vga"]), "reference: expected"),
    "reference unknown": (_key("reference", "thermal"), "reference stream 'thermal' has no detections"),
    "joints a string": (_key("joints", "19"), "joints: expected"),
    "typo key": (_key("time_ms", [1200.0]), "time_ms: unknown field"),
    "top level a list": (lambda det: det.clear() or det.update({"cameras": None}), "cameras: expected"),
    "camera name a path": (lambda det: det["cameras"].update({"../../x": det["cameras"]["01_01"]}),
                           'cameras["../../x"]: expected a plain name'),
}


@pytest.mark.parametrize("case", sorted(BAD_DETECTIONS))
def test_bad_detections(world, tmp_path, monkeypatch, capsys, case):
    root, det = world
    edit, expected = BAD_DETECTIONS[case]
    det = copy.deepcopy(det)
    edit(det)
    (tmp_path / "det.json").write_text(json.dumps(det))
    code, _, err = _in_process(["triangulate", str(tmp_path / "det.json"), "--bundle", str(root / "bundle"),
                                "-o", str(tmp_path / "sk")], monkeypatch, capsys)
    _refused(code, err, expected)
    assert _files(tmp_path) == ["det.json"]  # no output folder, no staging left


@pytest.mark.parametrize("target", ["file", "fifo", "folder of other files", "broken bundle"])
def test_bad_triangulate_output_or_bundle(world, tmp_path, monkeypatch, capsys, target):
    root, det = world
    (tmp_path / "det.json").write_text(json.dumps(det))
    out, bundle = tmp_path / "sk", root / "bundle"
    if target == "file":
        out.write_text("mine")
        expected = "is a file, not a folder"
    elif target == "fifo":
        os.mkfifo(out)
        expected = "is a FIFO (named pipe)"
    elif target == "folder of other files":
        out.mkdir()
        (out / "thesis.tex").write_text("mine")
        expected = "holds thesis.tex (no record of dome-calib lists it)"
    else:
        bundle = tmp_path / "bundle"
        shutil.copytree(root / "bundle", bundle)
        cal = json.loads((bundle / "calibration_test.json").read_text())
        cal["cameras"][0]["K"] = "745"
        (bundle / "calibration_test.json").write_text(json.dumps(cal))
        expected = "calibration_test.json: camera "
    before = {p.name: p.lstat().st_mode for p in tmp_path.iterdir()}
    code, _, err = _in_process(["triangulate", str(tmp_path / "det.json"), "--bundle", str(bundle), "-o", str(out)],
                               monkeypatch, capsys)
    _refused(code, err, expected)
    assert {p.name: p.lstat().st_mode for p in tmp_path.iterdir()} == before  # nothing replaced, nothing added
    if target == "folder of other files":
        assert _files(out) == ["thesis.tex"]


def test_pointcloud_onto_a_fifo_is_refused(world, tmp_path, monkeypatch, capsys):
    root, _ = world
    os.mkfifo(tmp_path / "cloud.ply")
    (tmp_path / "depth" / "KINECTNODE1").mkdir(parents=True)
    code, _, err = _in_process(["pointcloud", "--bundle", str(root / "bundle"), "--time-ms", "1200", "--depth",
                                str(tmp_path / "depth"), "-o", str(tmp_path / "cloud.ply")], monkeypatch, capsys)
    _refused(code, err, "cloud.ply: is a FIFO (named pipe), not a file")  # before any work
    assert stat.S_ISFIFO(os.lstat(tmp_path / "cloud.ply").st_mode)


# --- inputs that must work: the right result --------------------------------------------------------------------


def test_null_confidences_are_not_detected(world, tmp_path, monkeypatch, capsys):
    """null in u, v or c: not detected. (NaN, which JSON does not have, is refused naming its place, as in every
    input file read through its schema: BAD_DETECTIONS "pixel NaN".)"""
    root, det = world
    det = copy.deepcopy(det)
    det["cameras"]["01_01"]["joints"][0][4][2] = None
    det["cameras"]["02_16"]["joints"][0][4] = [None, None, None]
    first = det["cameras"]["01_01"]["frames"][0]
    (tmp_path / "det.json").write_text(json.dumps(det))
    code, out, err = _in_process(["triangulate", str(tmp_path / "det.json"), "--bundle", str(root / "bundle"),
                                  "-o", str(tmp_path / "sk")], monkeypatch, capsys)
    assert code == 0 and "joints reconstructed" in out, err
    _, _, c = read_skeleton(tmp_path / "sk" / f"body3DScene_{first:08d}.json")  # that time step is there
    assert (c >= 0).sum() >= 17


def test_some_times_outside_warn_in_one_line(world, tmp_path):
    """Subprocess: the warning as the user sees it, one line beside the result."""
    root, det = world
    (tmp_path / "det.json").write_text(json.dumps({**det, "times_ms": [100.0, 1200.0, 1250.0]}))
    code, out, err = _subprocess(["triangulate", str(tmp_path / "det.json"), "--bundle", str(root / "bundle"),
                                  "-o", str(tmp_path / "sk")])
    lines = err.strip().splitlines()
    assert code == 0 and "Traceback" not in err and len(lines) == 1, err
    assert "1 of 3 times lie outside the detected frames' universal times" in lines[0]
    assert _files(tmp_path / "sk") == [RECORD] + [f"body3DScene_{k:08d}.json" for k in range(3)]


def test_bad_input_through_the_real_shell(world, tmp_path):
    """Subprocess: a confidence of 10.72 as the user sees it: one line, exit 1, nothing written."""
    root, det = world
    det = copy.deepcopy(det)
    det["cameras"]["01_01"]["joints"][2][3][2] = 10.72
    (tmp_path / "det.json").write_text(json.dumps(det))
    code, _, err = _subprocess(["triangulate", str(tmp_path / "det.json"), "--bundle", str(root / "bundle"),
                                "-o", str(tmp_path / "sk")])
    assert code == 1 and err.strip().count("\n") == 0 and "Traceback" not in err, err
    assert "joints[2][3][2]: confidence 10.72 outside [0, 1]" in err and _files(tmp_path) == ["det.json"]
