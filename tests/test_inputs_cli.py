"""Through the commands (issue 42): a malformed input file gives exit 1, one line naming the file and the field
path, no traceback, and nothing written (the output place absent or as it was). One case per input file of
docs/inputs.md and per kind of damage (another type, null, NaN, out of range, removed, an unknown field); the
mutations at random are in tests/test_input_mutations.py."""
from __future__ import annotations

import json
import math
import shutil

import pytest

from dome_calib.bundle_io import write_bundle

from .cli_runner import run_in_process
from .input_schemas import FILES

NAMES = {f.name for f in FILES}


def _files(folder):
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()} if folder.exists() else None


def _run(prog, args, monkeypatch, capsys):
    if prog == "timecode":
        from timecode.cli import main
    else:
        from dome_calib.cli import main
    return run_in_process(main, prog, args, monkeypatch, capsys)


def _one_line(done, *words):
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if "error:" in ln]
    assert done.returncode == 1 and len(errors) == 1, done.stderr
    assert "Traceback" not in done.stderr
    assert all(w in errors[0] for w in words), errors[0]


def _edit(path, edit):
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


CAPTURE_CASES = {
    "a camera true": (lambda d: d["cameras"].__setitem__(0, True), "cameras[0]: expected a camera name"),
    "nodes null": (lambda d: d.__setitem__("nodes", None), "nodes: expected an object mapping names to lists"),
    "scenes removed": (lambda d: d.pop("scenes"), "scenes: missing (expected a non-empty list of plain names"),
    "seed NaN": (lambda d: d.__setitem__("seed", math.nan), "seed: expected an integer or null, got NaN"),
    "an unknown field": (lambda d: d.__setitem__("node", {}), "node: unknown field (known fields: "),
}


@pytest.mark.parametrize("case", sorted(CAPTURE_CASES))
def test_calibrate_refuses_a_malformed_capture_json(tmp_path, monkeypatch, capsys, case):
    edit, words = CAPTURE_CASES[case]
    cap = tmp_path / "cap"
    (cap / "scenes" / "scene_01").mkdir(parents=True)
    (cap / "capture.json").write_text(json.dumps({"scenes": ["scene_01"], "cameras": ["01_01", "00_03"], "seed": 0}))
    _edit(cap / "capture.json", edit)
    done = _run("dome-calib", ["calibrate", cap, "-o", tmp_path / "out"], monkeypatch, capsys)
    _one_line(done, f"{cap / 'capture.json'}: {words}")
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.work").exists()


SESSION_CASES = {  # the issue's own example first
    "a channel false": (lambda d: d["ltc"].__setitem__("vga_channel", False),
                        "ltc.vga_channel: expected an integer >= 0 and <= 2^63-1, got false"),
    "a path null": (lambda d: d["ltc"].__setitem__("file", None),
                    "ltc.file: expected a path, relative to the session folder, got null"),
    "a rate 25": (lambda d: d["ltc"].__setitem__("vga_rate", 25), "ltc.vga_rate: expected a frame rate: "),
    "a reference frame NaN": (lambda d: d["streams"]["vga"].__setitem__("ref_index", math.nan),
                              "streams.vga.ref_index: expected a 64-bit integer or null, got NaN"),
    "one clock's channel twice": (lambda d: d["ltc"].__setitem__("hd_channel", d["ltc"]["vga_channel"]),
                                  "ltc.hd_channel: the same channel as vga_channel"),
    "an unknown field": (lambda d: d["ltc"].__setitem__("hd_chanel", 1), "ltc.hd_chanel: unknown field"),
}


@pytest.mark.parametrize("case", sorted(SESSION_CASES))
@pytest.mark.parametrize("command", ["timecode sync", "session"])
def test_sync_and_session_refuse_a_malformed_session_json_and_keep_the_bundle(small_product_session, tmp_path,
                                                                              monkeypatch, capsys, command, case):
    root, truth = small_product_session
    sess = tmp_path / "sess"
    shutil.copytree(root, sess)
    edit, words = SESSION_CASES[case]
    _edit(sess / "sync" / "session.json", edit)
    out = write_bundle(truth, tmp_path / "bundle")
    before = _files(out)
    if command == "session":
        done = _run("dome-calib", ["session", sess, "-o", out], monkeypatch, capsys)
        assert "dome-calib session: calibrate" not in done.stderr
    else:
        done = _run("timecode", ["sync", sess / "sync", "-o", out], monkeypatch, capsys)
    _one_line(done, f"{sess / 'sync' / 'session.json'}: {words}")
    assert _files(out) == before and not (tmp_path / "bundle.work").exists()


def test_sync_refuses_malformed_kinect_timestamps(small_product_session, tmp_path, monkeypatch, capsys):
    root, truth = small_product_session
    sess = tmp_path / "sess"
    shutil.copytree(root, sess)
    ts = next((sess / "sync" / "kinect").glob("*/timestamps.json"))
    _edit(ts, lambda d: d["color"]["device_time_100ns"].__setitem__(0, "12"))
    out = write_bundle(truth, tmp_path / "bundle")
    before = _files(out)
    done = _run("timecode", ["sync", sess / "sync", "-o", out], monkeypatch, capsys)
    _one_line(done, f"{ts}: color.device_time_100ns[0]: expected a 64-bit integer, got \"12\"")
    assert _files(out) == before


BUNDLE_CASES = {
    "calibration: K null": ("calibration", lambda d: d["cameras"][1].__setitem__("K", None),
                            "cameras[1].K: expected a 3 x 3 camera matrix"),
    "calibration: t out of range": ("calibration", lambda d: d["cameras"][0].__setitem__("t", [[1e7], [0], [0]]),
                                    "cameras[0].t[0]: expected a finite number >= -1e+06 and <= 1e+06, got 10000000.0"),
    "kcalibration: depth_scale NaN": ("kcalibration", lambda d: d["sensors"][0].__setitem__("depth_scale", math.nan),
                                      "sensors[0].depth_scale: expected a finite number >= -0.5 and <= 0.5, got NaN"),
    "kcalibration: unknown top field": ("kcalibration", lambda d: d.__setitem__("sensor", []),
                                        "sensor: unknown field (known fields: "),
    "synctables: index removed": ("synctables", lambda d: d["vga"].pop("index"), "vga.index: missing"),
    "ksynctables: a string time": ("ksynctables",
                                   lambda d: d["kinect"]["depth"][next(iter(d["kinect"]["depth"]))]["univ_time"]
                                   .__setitem__(0, "0"), "univ_time[0]: expected a finite number, got \"0\""),
}


#: Each case through one command, every command at least once (the four files read by one loader).
BUNDLE_COMMANDS = dict(zip(sorted(BUNDLE_CASES), ["info", "compare", "report", "kinect", "report", "info"]))


@pytest.mark.parametrize("case, command", sorted(BUNDLE_COMMANDS.items()))
def test_bundle_readers_refuse_a_malformed_bundle_file_and_write_nothing(small_product_session, tmp_path, monkeypatch,
                                                                        capsys, command, case):
    root, truth = small_product_session
    kind, edit, words = BUNDLE_CASES[case]
    bundle = write_bundle(truth, tmp_path / "bundle")
    path = bundle / f"{kind}_{truth.seq}.json"
    _edit(path, edit)
    before = _files(bundle)
    args = {"info": ["info", bundle], "compare": ["compare", bundle, root / "ground_truth"],
            "report": ["report", bundle], "kinect": ["kinect", root / "kinect", "--bundle", bundle]}[command]
    done = _run("dome-calib", args, monkeypatch, capsys)
    _one_line(done, f"{path}: ", words)
    assert _files(bundle) == before


def test_demo_refuses_a_session_folder_it_did_not_make(tmp_path, monkeypatch, capsys):
    out = tmp_path / "demo"
    (out / "session").mkdir(parents=True)
    (out / "session" / "dome_session.json").write_text(json.dumps({"version": 1, "options": {"seed": "0"}, "parts": {}}))
    (out / "session" / "notes.txt").write_text("mine")
    before = _files(out)
    done = _run("dome-calib", ["demo", "-o", out, "--people", "0"], monkeypatch, capsys)
    _one_line(done, f"{out / 'session' / 'dome_session.json'}: options.seed: expected an integer >= 0, got \"0\"",
              "not a session this toolkit made")
    assert _files(out) == before
    (out / "session" / "dome_session.json").unlink()
    done = _run("dome-calib", ["demo", "-o", out, "--people", "0"], monkeypatch, capsys)
    _one_line(done, f"{out / 'session'}: holds notes.txt (no record of dome-calib lists it)")
    assert (out / "session" / "notes.txt").read_text() == "mine"


def test_reconstruct_refuses_a_malformed_openpose_file_and_camera_map(small_product_session, tmp_path, monkeypatch,
                                                                      capsys):
    root, truth = small_product_session
    det = tmp_path / "det" / "00_01"
    det.mkdir(parents=True)
    path = det / "00_01_000000005010_keypoints.json"
    path.write_text(json.dumps({"people": [{"pose_keypoints_2d": [1.0, 2.0, 0.5] * 24 + [1.0, None, 0.5]}]}))
    out = tmp_path / "people"
    done = _run("dome-calib", ["reconstruct", tmp_path / "det", "--bundle", root / "ground_truth", "-o", out,
                               "--body-model", "BODY_25"], monkeypatch, capsys)
    _one_line(done, f"{path}: camera 00_01: frame 5010: people[0].pose_keypoints_2d[73]: expected a finite number, "
                    "got null")
    assert not out.exists()
    cmap = tmp_path / "map.json"
    cmap.write_text(json.dumps({"cam01": None}))
    done = _run("dome-calib", ["reconstruct", tmp_path / "det", "--bundle", root / "ground_truth", "-o", out,
                               "--camera-map", cmap], monkeypatch, capsys)
    _one_line(done, f"{cmap}: cam01: expected a non-empty string, got null")
    assert not out.exists()


DETECTIONS_CASES = {  # triangulate's detections file (recon.formats.DetectionsFile)
    "a frame as text": (lambda d: d["cameras"]["01_01"]["frames"].__setitem__(0, "100"),
                        "cameras.01_01.frames[0]: expected an integer >= 0"),
    "joints null": (lambda d: d["cameras"]["01_01"].__setitem__("joints", None), "cameras.01_01.joints: expected"),
    "a pixel NaN": (lambda d: d["cameras"]["01_01"]["joints"][0][3].__setitem__(0, math.nan),
                    "cameras.01_01.joints[0][3][0]: expected a finite number or null, got NaN"),
    "a confidence of 2": (lambda d: d["cameras"]["01_01"]["joints"][1][0].__setitem__(2, 2.0),
                          "cameras.01_01.joints[1][0][2]: confidence 2 outside [0, 1]"),
    "cameras removed": (lambda d: d.pop("cameras"), "cameras: missing"),
    "an unknown field": (lambda d: d.__setitem__("time_ms", [1.0]), "time_ms: unknown field"),
}


@pytest.mark.parametrize("case", sorted(DETECTIONS_CASES))
def test_triangulate_refuses_a_malformed_detections_file(tmp_path, monkeypatch, capsys, case):
    from .input_schemas import FILES as REGISTRY
    from .recon_helpers import real_bundle

    example = next(f for f in REGISTRY if f.name == "detections JSON").example()
    write_bundle(real_bundle(kinect=False, n_vga=40), tmp_path / "b")
    edit, words = DETECTIONS_CASES[case]
    edit(example)
    path = tmp_path / "det.json"
    path.write_text(json.dumps(example))
    out = tmp_path / "sk"
    done = _run("dome-calib", ["triangulate", path, "--bundle", tmp_path / "b", "-o", out], monkeypatch, capsys)
    _one_line(done, f"{path}: {words}")
    assert not out.exists()


REPORT_CASES = {  # the report's own files; more in tests/test_report_files.py and, in Chromium, test_report_page.py
    "report.json": (lambda d: d["found"]["reasons"].__setitem__("01_03", "moved"),
                    'found.reasons.01_03: expected a non-empty list of objects with code, text, got "moved"'),
    "session.json": (lambda d: d["pillars"]["kinect"]["sensors"][0].__setitem__("frames_used", None),
                     "pillars.kinect.sensors[0].frames_used: expected an integer >= 0"),
    "sync.json": (lambda d: d["streams"]["vga"].__setitem__("n_frames", "<img src=x onerror=alert(1)>"),
                  "streams.vga.n_frames: expected an integer >= 0"),
}


@pytest.mark.parametrize("name", sorted(REPORT_CASES))
def test_report_refuses_a_malformed_report_file(tmp_path, monkeypatch, capsys, name):
    from dome_calib.layout import nominal_dome
    from dome_calib.report import write_report

    from .input_schemas import FILES as REGISTRY

    tiny = nominal_dome("tiny", seed=0)
    bundle = write_bundle(tiny, tmp_path / "b")
    write_report(bundle, tiny, None)
    for f in REGISTRY:
        if f.name in ("report/session.json", "report/sync.json", "report/report.json"):
            (bundle / f.name).write_text(json.dumps(f.example()))
    edit, words = REPORT_CASES[name]
    _edit(bundle / "report" / name, edit)
    before = _files(bundle)
    done = _run("dome-calib", ["report", bundle], monkeypatch, capsys)
    _one_line(done, f"{bundle / 'report' / name}: {words}")
    assert _files(bundle) == before


IMAGES_CASES = {  # reconstruct --images FOLDER: FOLDER/images.json (recon.patches.images.ImagesFile)
    "a path as a number": ({"cameras": {"01_01": 3}}, "cameras.01_01: expected a path relative to the folder, got 3"),
    "cameras removed": ({"first_frame": {"01_01": 0}}, "cameras: missing"),
    "a crop origin below 0": ({"cameras": {"01_01": "a"}, "crop_origin_px": {"01_01": [-1, 0]}},
                              "crop_origin_px.01_01[0]: expected an integer >= 0"),
    "an unknown field": ({"cameras": {"01_01": "a"}, "first_frames": {}}, "first_frames: unknown field"),
    "a camera the bundle lacks": ({"cameras": {"99_99": "a"}}, "cameras.99_99: no camera of that name in bundle"),
}


@pytest.fixture(scope="module")
def tiny_detections(tmp_path_factory):
    """The tiny dome (with sync tables) and one frame of one person in three VGA cameras."""
    import numpy as np

    from dome_calib.layout import nominal_dome
    from dome_calib.synth.openpose_write import write_openpose_folder
    from dome_calib.synth.skeleton import synthetic_sync

    root = tmp_path_factory.mktemp("images_cases")
    bundle = nominal_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=500.0, seed=0)
    write_bundle(bundle, root / "bundle")
    person = np.concatenate([np.full((1, 19, 2), 300.0) + np.arange(19)[None, :, None], np.full((1, 19, 1), 0.9)], -1)
    write_openpose_folder(root / "det", {c: {105: person} for c in ("01_01", "01_02", "01_03")}, body_model="PANOPTIC19")
    return root


@pytest.mark.parametrize("case", sorted(IMAGES_CASES))
def test_reconstruct_refuses_a_malformed_images_json(tiny_detections, tmp_path, monkeypatch, capsys, case):
    doc, words = IMAGES_CASES[case]
    (tmp_path / "imgs" / "a").mkdir(parents=True)
    path = tmp_path / "imgs" / "images.json"
    path.write_text(json.dumps(doc))
    out = tmp_path / "people"
    done = _run("dome-calib", ["reconstruct", tiny_detections / "det", "--bundle", tiny_detections / "bundle",
                               "--body-model", "PANOPTIC19", "--images", tmp_path / "imgs", "-o", out],
                monkeypatch, capsys)
    _one_line(done, f"{path}: {words}")
    assert not out.exists()


CAMERAS_CASES = {  # dome-calib people-page FOLDER: FOLDER/cameras.json as reconstruct wrote it (scene_io.CamerasFile)
    "a count below 0": (lambda d: d["cameras"][next(iter(d["cameras"]))].update(detected=-1),
                        "cameras.{cam}.detected: expected an integer >= 0"),
    "a flagged camera not among the cameras": (lambda d: d.update(flagged=["99_99"]),
                                               "flagged[0]: camera 99_99 is not one of cameras"),
    "cameras removed": (lambda d: d.pop("cameras"), "cameras: missing"),
}


@pytest.fixture(scope="module")
def tiny_people(tiny_detections, tmp_path_factory):
    """reconstruct's output folder (with its cameras.json) for the tiny detections."""
    import subprocess
    import sys

    out = tmp_path_factory.mktemp("tiny_people") / "people"
    done = subprocess.run([sys.executable, "-c", "from dome_calib.cli import main; main()", "reconstruct",
                           str(tiny_detections / "det"), "--bundle", str(tiny_detections / "bundle"),
                           "--body-model", "PANOPTIC19", "-o", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return out


@pytest.mark.parametrize("case", sorted(CAMERAS_CASES))
def test_people_page_refuses_a_malformed_cameras_json(tiny_people, tmp_path, monkeypatch, capsys, case):
    import shutil

    folder = tmp_path / "people"
    shutil.copytree(tiny_people, folder)
    path = folder / "cameras.json"
    doc = json.loads(path.read_text())
    cam = next(iter(doc["cameras"]))
    change, words = CAMERAS_CASES[case]
    change(doc)
    path.write_text(json.dumps(doc))
    done = _run("dome-calib", ["people-page", folder, "-o", tmp_path / "page.html"], monkeypatch, capsys)
    _one_line(done, f"{path}: {words.format(cam=cam)}")
    assert not (tmp_path / "page.html").exists()


def test_every_input_file_of_the_page_has_a_case_here():
    covered = {"capture.json", "session.json", "timestamps.json", "calibration_<seq>.json", "kcalibration_<seq>.json",
               "synctables_<seq>.json", "ksynctables_<seq>.json", "OpenPose JSON", "camera map", "dome_session.json",
               "report/report.json", "report/session.json", "report/sync.json", "detections JSON", "images.json",
               "cameras.json"}
    assert covered == NAMES
