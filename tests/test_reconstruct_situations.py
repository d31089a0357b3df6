"""Issue 42, `dome-calib reconstruct` tried as a user would: each situation found there, fixed at its cause. Every
test here failed on main at 2a6a476 (the before is in each docstring)."""
from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.body3d_scene import read_scene
from dome_calib.synth.detector import write_openpose_folder

from .people_helpers import group_detections
from .recon_helpers import real_bundle
from .test_people_cli import _copy_det, _one_line_error, _small, group  # noqa: F401  (group: a fixture)
from .test_people_real import CAMERA_MAP, DATA, pose2sim_bundle

ROOT = Path(__file__).resolve().parents[1]


def _run(cli, det, bundle, out, *args):
    return cli("reconstruct", str(det), "--bundle", str(bundle), "-o", str(out), "--fps", "30", *args)


def _nothing_written(tmp_path, keep=("det",)):
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(keep)  # no output, no staging folder


# ---------------------------------------------------------------------------------------------- wrong body model
def test_body_25_files_read_as_body_25b_are_refused_naming_body_25(group, dome_calib_cli, tmp_path):
    """Before: exit 0, every body's joints were other joints (42 cm from the people, median) at 3.5 px."""
    root, _, _ = group
    out = _run(dome_calib_cli, root / "det", root / "bundle", tmp_path / "out", "--body-model", "BODY_25B")
    line = _one_line_error(out)
    assert "--body-model BODY_25B does not fit" in line and line.endswith("give --body-model BODY_25"), line
    assert "off a person's proportions" in line
    assert not (tmp_path / "out").exists()
    # without --body-model the 25-joint files are still refused, now saying which order they fit
    line = _one_line_error(_run(dome_calib_cli, root / "det", root / "bundle", tmp_path / "out"))
    assert "give --body-model" in line and "the joint order fits BODY_25 " in line, line


def test_real_body_25b_files_read_as_body_25_are_refused_naming_body_25b(dome_calib_cli, tmp_path):
    """Pose2Sim's real OpenPose BODY_25B output, read as BODY_25: refused naming BODY_25B, before any work."""
    shutil.copytree(DATA / "pose", tmp_path / "pose")
    write_bundle(pose2sim_bundle(DATA / "calibration" / "Calib_qualisys.toml"), tmp_path / "bundle")
    args = ("--camera-map", CAMERA_MAP, "--fps", "60")
    line = _one_line_error(_run(dome_calib_cli, tmp_path / "pose", tmp_path / "bundle", tmp_path / "out",
                                "--body-model", "BODY_25", *args))
    assert line.endswith("give --body-model BODY_25B"), line
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- frame rates and silent empty results
@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    """8 VGA cameras of a rig without sync tables (one shared frame index), 2 people, 12 frames, COCO-18."""
    root = tmp_path_factory.mktemp("shared")
    bundle = _small(real_bundle(kinect=False, sync=False, n_vga=40), n_vga=8, n_hd=0)
    write_bundle(bundle, root / "bundle")
    people, _ = group_detections(bundle, sorted(bundle.cameras), 2, seed=5, shared_frames=np.arange(40, 52))
    write_openpose_folder(root / "det", people, body_model="COCO_18")
    return root


def _ids(out: Path) -> list[list[int]]:
    return [sorted(read_scene(f)[1]) for f in sorted(out.glob("body3DScene_*.json"))]


def test_a_time_lapse_rig_keeps_its_people(shared, dome_calib_cli, tmp_path):
    """Frames 1 s apart (--fps 1). Before: 0 people, exit 0, and a reprojection figure (every track ended after
    500 ms, so none lasted 3 times). The track gap now follows the frame rate."""
    for fps in ("30", "1"):
        out = _run(dome_calib_cli, shared / "det", shared / "bundle", tmp_path / fps, "--fps", fps)
        assert out.returncode == 0 and "2 people, 24 body-frames" in out.stdout, out.stdout + out.stderr
    assert _ids(tmp_path / "1") == _ids(tmp_path / "30") == [[0, 1]] * 12
    assert json.loads((tmp_path / "1" / "body3DScene_00000041.json").read_text())["univTime"] == 41000.0


@pytest.mark.parametrize("case", ["nobody_detected", "not_enough_views", "too_short"])
def test_an_empty_result_says_what_dropped_it(shared, dome_calib_cli, tmp_path, case):
    """Before: "0 people, 0 body-frames, median reprojection 1.9 px" and nothing else."""
    det = tmp_path / "det"
    shutil.copytree(shared / "det", det)
    args = []
    if case == "nobody_detected":
        for f in det.rglob("*.json"):
            f.write_text('{"version": 1.3, "people": []}')
        args = ["--body-model", "COCO_18"]
        expect = "no camera detected a person"
    elif case == "not_enough_views":  # every camera's folder names another camera: nobody agrees
        names = sorted(p.name for p in det.iterdir())
        args = ["--camera-map", ",".join(f"{a}={b}" for a, b in zip(names, names[1:] + names[:1]))]
        expect = "but none was seen alike by --min-views 3 cameras"
    else:  # people at one time of three (a session of 1 or 2 times keeps the people seen in it: issue 50)
        for f in det.rglob("*.json"):
            if int(f.stem.split("_")[-2]) > 42:
                f.unlink()
            elif int(f.stem.split("_")[-2]) > 40:
                f.write_text('{"version": 1.3, "people": []}')
        args = ["--body-model", "COCO_18"]
        expect = "none was tracked over 3 times"
    out = _run(dome_calib_cli, det, shared / "bundle", tmp_path / "out", *args)
    assert out.returncode == 0, out.stderr
    assert "no person reconstructed: " in out.stdout and expect in out.stdout, out.stdout
    assert "median reprojection" not in out.stdout


# -------------------------------------------------------------------------------------------- overflowing numbers
@pytest.mark.parametrize("case", ["frame_beyond_int64", "frame_13_digits", "coordinate_1e300"])
def test_overflowing_numbers_are_one_line(group, dome_calib_cli, tmp_path, case):
    """Before: OverflowError traceback (frame 10^23), a 13-digit frame read as a time 10^14 ms away, 1e300 px
    through float32 to inf (RuntimeWarnings from the lens model)."""
    root, bundle, _ = group
    det = tmp_path / "det"
    _copy_det(root / "det", det)
    cam = sorted(bundle.of_type("vga"))[0]
    first = sorted((det / cam).iterdir())[0]
    if case == "coordinate_1e300":
        data = json.loads(first.read_text())
        data["people"][0]["pose_keypoints_2d"][3] = 1e300
        first.write_text(json.dumps(data))
        expect = [str(first), "pose_keypoints_2d", "joint 1", "1e+300"]
    else:
        digits = "9" * 23 if case == "frame_beyond_int64" else "1" + "0" * 12
        bad = det / cam / f"{cam}_{digits}_keypoints.json"
        bad.write_text(first.read_text())
        expect = [str(bad), "frame number", "OpenPose numbers frames with 12 digits"]
    line = _one_line_error(_run(dome_calib_cli, det, root / "bundle", tmp_path / "out", "--body-model", "BODY_25"))
    assert all(e in line for e in expect), line
    _nothing_written(tmp_path)


# ---------------------------------------------------------------------------------------------- paths as typed
def test_dot_and_dot_dot_name_the_output_from_the_folder(shared, dome_calib_cli, tmp_path, monkeypatch):
    """Before: `reconstruct .` was a ValueError traceback; `reconstruct ..` inside a camera folder wrote `.._people`
    into that camera folder (the next run would read it)."""
    shutil.copytree(shared / "det", tmp_path / "det")
    camera = sorted((tmp_path / "det").iterdir())[0]
    monkeypatch.chdir(tmp_path / "det")
    out = dome_calib_cli("reconstruct", ".", "--bundle", str(shared / "bundle"), "--fps", "30")
    assert out.returncode == 0 and out.stdout.rstrip().endswith(f"-> {tmp_path / 'det_people'}"), out.stderr
    shutil.rmtree(tmp_path / "det_people")
    monkeypatch.chdir(camera)
    out = dome_calib_cli("reconstruct", "..", "--bundle", str(shared / "bundle"), "--fps", "30")
    assert out.returncode == 0, out.stderr
    assert _ids(tmp_path / "det_people") == [[0, 1]] * 12
    assert sorted(tmp_path.iterdir()) == [tmp_path / "det", tmp_path / "det_people"]
    assert all(p.suffix == ".json" and p.is_file() for p in camera.iterdir())  # nothing written among the inputs


@pytest.mark.parametrize("inside", ["detections", "camera", "bundle"])
def test_an_output_inside_an_input_is_refused(shared, dome_calib_cli, tmp_path, inside):
    det = tmp_path / "det"
    shutil.copytree(shared / "det", det)
    shutil.copytree(shared / "bundle", tmp_path / "bundle")
    where = {"detections": det / "people", "camera": sorted(det.iterdir())[0] / "x" / "..",
             "bundle": tmp_path / "bundle" / "people"}[inside]
    line = _one_line_error(_run(dome_calib_cli, det, tmp_path / "bundle", where))
    assert "inside the input folder" in line, line
    _nothing_written(tmp_path, keep=("det", "bundle"))
    assert not (det / "people").exists() and not (tmp_path / "bundle" / "people").exists()


# ------------------------------------------------------------------------------------------- streams without sync
def test_vga_and_hd_without_sync_tables_are_refused(group, dome_calib_cli, tmp_path):
    """VGA and HD detections (each numbering its own frames) with a bundle that has no sync tables. Before: the
    frame numbers were merged into one index (the demo's 7 people came out as 27), exit 0."""
    root, bundle, _ = group
    write_bundle(Bundle(seq=bundle.seq, cameras=bundle.cameras, calib_data_source="import"), tmp_path / "b")
    line = _one_line_error(_run(dome_calib_cli, root / "det", tmp_path / "b", tmp_path / "out", "--body-model",
                                "BODY_25"))
    assert "has no sync tables" in line and "2 streams" in line and "hd: 6 cameras" in line, line
    assert "vga: 14 cameras" in line and "timecode sync" in line and "one stream's cameras" in line, line
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------------- messages name what was typed
@pytest.mark.parametrize("args, message", [
    (["--min-views", "1"], "--min-views 1: a person must be seen by at least 2 cameras"),
    (["--min-views", "21"], "--min-views 21: only 20 cameras have detections"),
    (["--smooth", "-1"], "--smooth -1: expected 0 (off)"),
    (["--fps", "1e-400"], "--fps '1e-400': expected a frame rate from 1/86400"),
    (["--workers", "0"], "--workers 0: expected 1 to 1024 processes"),
    (["--workers", "99999999999999999999999"], "--workers 99999999999999999999999: expected 1 to 1024"),
    (["--reference", "KINECTNODE9"], "--reference KINECTNODE9: that stream has no detections"),
    (["--body-model", "BODY25X"], "--body-model BODY25X: unknown (known: BODY_25, BODY_25B")])
def test_a_bad_option_is_named_as_typed(group, dome_calib_cli, tmp_path, args, message):
    """Before: `--min-views 1` answered "min_person_views >= 2, candidate_cm > 0, ..." (internal fields); a huge
    --workers or a tiny --fps was a traceback, --workers 0 ran, --min-views 21 gave 0 people in silence."""
    root, _, _ = group
    model = [] if "--body-model" in args else ["--body-model", "BODY_25"]
    line = _one_line_error(_run(dome_calib_cli, root / "det", root / "bundle", tmp_path / "o", *model, *args))
    assert message in line, line
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------------- cameras not skipped
def test_upper_case_json_files_are_read_and_an_empty_camera_is_said(group, dome_calib_cli, tmp_path, caplog):
    """A camera folder of `.JSON` files (a case-insensitive file system's copy). Before: left out in silence, as was
    a camera folder with no detections."""
    root, bundle, _ = group
    det = tmp_path / "det"
    _copy_det(root / "det", det, limit=6)
    upper = sorted(bundle.of_type("vga"))[2]
    for f in list((det / upper).iterdir()):
        f.rename(f.with_name(f.name.replace("_keypoints.json", "_KEYPOINTS.JSON")))
    gone = sorted(bundle.of_type("vga"))[5]
    for f in (det / gone).iterdir():
        f.unlink()
    with caplog.at_level(logging.WARNING):
        out = _run(dome_calib_cli, det, root / "bundle", tmp_path / "out", "--body-model", "BODY_25")
    assert out.returncode == 0, out.stderr
    assert "from 19 cameras" in out.stdout  # 20 folders, one empty: the upper-case one is read
    cams = json.loads((tmp_path / "out" / "cameras.json").read_text())["cameras"]
    assert cams[upper]["detected"] > 0 and gone not in cams
    said = [r.getMessage() for r in caplog.records if gone in r.getMessage()]
    assert said == [f"{det / gone}: no OpenPose .json file (empty): camera {gone} left out"], said


# --------------------------------------------------------------------------------------------------- signals
def _wait_for(predicate, seconds=60.0):
    deadline = time.monotonic() + seconds
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.05)
    return predicate()


def test_sigterm_is_one_line_and_exit_130(group, tmp_path):
    """The run is held where it reads its camera map (a FIFO nobody writes), after pycolmap is loaded. Before:
    pycolmap's C handler printed a 35-line stack dump and the process died of the signal."""
    root, _, _ = group
    fifo = tmp_path / "map.json"
    os.mkfifo(fifo)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", "from dome_calib.cli import main; main()", "reconstruct",
                             str(root / "det"), "--bundle", str(root / "bundle"), "-o", str(tmp_path / "out"),
                             "--body-model", "BODY_25", "--camera-map", str(fifo), "--fps", "30"], cwd=tmp_path,
                            env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert _wait_for(lambda: "pycolmap" in Path(f"/proc/{proc.pid}/maps").read_text() or proc.poll() is not None)
        time.sleep(1.0)  # pycolmap's handler is replaced right after it loads
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert err.splitlines() == ["dome-calib: interrupted; the output folder is as it was; rerun the same command"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.json"]


_HELD_WRITE = """
import sys, time
from pathlib import Path
from dome_calib.errors import interrupt_as_one_line
from dome_calib.io_utils import atomic_folder
with interrupt_as_one_line("x"):
    with atomic_folder(sys.argv[1]) as staging:
        (staging / "body3DScene_00000001.json").write_text("{}")
        Path(sys.argv[2]).write_text(staging.name)
        time.sleep(120)
"""


def _held_writer(out: Path, marker: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", _HELD_WRITE, str(out), str(marker)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert _wait_for(lambda: marker.exists() or proc.poll() is not None), proc.communicate()[1]
    return proc


def test_a_run_killed_while_writing_leaves_a_staging_folder_the_next_run_removes(shared, dome_calib_cli, tmp_path):
    """SIGTERM while the output is staged: the staging folder goes. SIGKILL (no handler runs): it stays, and the
    next run that writes the same output removes it, but not one of a run still alive nor one it cannot prove
    dead. Before: left for ever."""
    out = tmp_path / "out"
    term = _held_writer(out, tmp_path / "m1")
    term.send_signal(signal.SIGTERM)
    assert term.wait(timeout=60) == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m1"]
    alive = _held_writer(out, tmp_path / "m3")  # (a writer removes the stale ones when it starts: this one first)
    killed = _held_writer(out, tmp_path / "m2")
    killed.send_signal(signal.SIGKILL)
    killed.wait(timeout=60)
    foreign = tmp_path / f".out.new.00000000.{(tmp_path / 'm2').read_text().split('.')[4]}.1.1.abcdefgh"
    foreign.mkdir()  # another machine's (host 00000000): cannot be proven dead
    try:
        stale, live = (tmp_path / (tmp_path / m).read_text() for m in ("m2", "m3"))
        assert stale.is_dir() and live.is_dir()
        result = _run(dome_calib_cli, shared / "det", shared / "bundle", out)
        assert result.returncode == 0, result.stderr
        assert not stale.exists() and live.is_dir() and foreign.is_dir()
        assert _ids(out) == [[0, 1]] * 12
    finally:
        alive.kill()
        alive.wait(timeout=60)


def test_every_input_is_checked_before_the_executor_opens(shared, dome_calib_cli, tmp_path):
    """A missing bundle with a scheduler that does not answer. Before: the scheduler was contacted first (5 s, then
    a line about the scheduler, not about the bundle)."""
    out = dome_calib_cli("reconstruct", str(shared / "det"), "--bundle", str(tmp_path / "nobundle"), "-o",
                         str(tmp_path / "out"), "--scheduler", "tcp://127.0.0.1:9")
    line = _one_line_error(out)
    assert "nobundle" in line and "scheduler" not in line, line
