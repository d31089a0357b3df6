"""Issue 37: outputs that are inputs, outputs that cannot be written, a full disk and an interrupted first stage.
Each situation is refused (or resumed) before the work, in one line, with nothing written or changed. The SfM and
BA stages are the stand-ins of tests/test_calibrate.py, so each test takes about a second."""
from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

import dome_calib.pipeline.full as pipeline
from dome_calib.bundle_io import load_bundle
from dome_calib.errors import DomeCalibError
from dome_calib import io_utils
from dome_calib.io_utils import OutputPathError

from .cli_runner import run_in_process
from .report_data import NO_PLOTS  # no test here reads a plot
from .test_calibrate import capture, stand_in_stages  # noqa: F401  (fixtures)

LTC = Path(__file__).parent / "data" / "ltc" / "ltcsync_ltc.wav"


def _timecode(args, monkeypatch, capsys):
    from timecode.cli import main

    return run_in_process(main, "timecode", args, monkeypatch, capsys)


def _unwritable_folder(tmp_path: Path) -> Path:
    """A folder nothing can be created in: a read-only one (chmod 555) for a normal user; as root (who may write
    anywhere permissions say no) sysfs, which refuses new entries to everybody."""
    if os.geteuid() != 0:
        folder = tmp_path / "read_only"
        folder.mkdir()
        folder.chmod(0o555)
        return folder
    return Path("/sys")


# ------------------------------------------------------------------------------------------ output = an input
@pytest.mark.parametrize("how", ["same path", "another path", "symlink", "hard link", "a folder's file"])
def test_timecode_decode_onto_its_own_recording_is_refused_and_the_recording_kept(tmp_path, how, monkeypatch,
                                                                                   capsys):
    rec = tmp_path / "rec.wav"
    rec.write_bytes(LTC.read_bytes())
    given, out = str(rec), str(rec)
    if how == "another path":
        (tmp_path / "sub").mkdir()
        out = str(tmp_path / "sub" / ".." / "rec.wav")
    elif how == "symlink":
        out = str(tmp_path / "link.wav")
        os.symlink(rec, out)
    elif how == "hard link":
        out = str(tmp_path / "hard.wav")
        os.link(rec, out)
    elif how == "a folder's file":
        given = str(tmp_path)
    done = _timecode(["decode", given, "-o", out], monkeypatch, capsys)
    assert done.returncode == 1
    assert "(the same file)" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert rec.read_bytes() == LTC.read_bytes()


def test_timecode_decode_checks_its_output_before_reading(tmp_path, monkeypatch, capsys):
    import timecode.cli.decode_command as dc

    def no_reading(*a, **k):
        raise AssertionError("the input was read before the output was checked")

    monkeypatch.setattr(dc, "run_decode", no_reading)
    done = _timecode(["decode", LTC, "-o", _unwritable_folder(tmp_path) / "table.txt"], monkeypatch, capsys)
    assert done.returncode == 1 and "cannot write in" in done.stderr
    done = _timecode(["decode", LTC, "-o", tmp_path], monkeypatch, capsys)
    assert done.returncode == 1 and "is a folder, not a file" in done.stderr


def test_an_output_folder_holding_the_capture_or_a_work_folder_that_is_an_input_is_refused(tmp_path, capture,
                                                                                           stand_in_stages):
    cap, _ = capture
    (cap / "calibration_old.json").write_text("{}")  # the capture folder looks like a bundle: it would be replaced
    with pytest.raises(OutputPathError, match="is the input"):
        pipeline.run_calibration(cap, cap, pipeline.CalibrateOptions(progress=None))
    for work in (cap, cap / "scenes", tmp_path):
        with pytest.raises(DomeCalibError, match="--work"):  # an emptied work folder would delete the images
            pipeline.run_calibration(cap, tmp_path / "out", pipeline.CalibrateOptions(progress=None, work_dir=work))
    assert (cap / "capture.json").exists() and (cap / "scenes" / "scene_01").is_dir()
    assert stand_in_stages == {"sfm": 0, "ba": 0}


def test_pointcloud_onto_a_bundle_file_is_refused(tmp_path, capture):
    from dome_calib.recon.commands import pointcloud_file

    cap, _ = capture
    calib = cap / "ground_truth" / "calibration_synth.json"
    text = calib.read_text()
    with pytest.raises(OutputPathError, match="is the input"):
        pointcloud_file(cap / "ground_truth", 0.0, tmp_path, calib)
    assert calib.read_text() == text


def test_refuse_output_among_inputs_compares_files_not_names(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("a")
    b.write_text("b")
    io_utils.refuse_output_among_inputs(b, [a])  # different files
    io_utils.refuse_output_among_inputs(tmp_path / "new.txt", [a])  # not there yet
    io_utils.refuse_output_among_inputs(tmp_path, [a])  # a folder written into, not replaced whole
    with pytest.raises(OutputPathError):
        io_utils.refuse_output_among_inputs(tmp_path, [a], whole_folder=True)


# ------------------------------------------------------------------------------------------ unwritable outputs
def test_calibrate_under_a_read_only_parent_is_refused_before_the_calibration(tmp_path, capture, stand_in_stages,
                                                                              dome_calib_cli):
    cap, _ = capture
    out = _unwritable_folder(tmp_path) / "bundle"
    done = dome_calib_cli("calibrate", cap, "-o", out, "--work", tmp_path / "work")
    assert done.returncode == 1, done.stderr
    assert f"{out}: cannot write in {out.parent}" in done.stderr
    assert stand_in_stages == {"sfm": 0, "ba": 0}


@pytest.mark.parametrize("command", ["synth", "pointcloud", "triangulate", "kinect", "sync"])
def test_every_writing_command_checks_its_output_first(tmp_path, command, monkeypatch, capsys, dome_calib_cli,
                                                       capture):
    cap, _ = capture
    ro = _unwritable_folder(tmp_path)
    bundle = cap / "ground_truth"
    if command == "synth":
        done = dome_calib_cli("synth", ro / "cap")
    elif command == "pointcloud":
        done = dome_calib_cli("pointcloud", "--bundle", bundle, "--time-ms", "0", "--depth", tmp_path,
                              "-o", ro / "c.ply")
    elif command == "triangulate":
        det = tmp_path / "det.json"
        det.write_text("{}")
        done = dome_calib_cli("triangulate", det, "--bundle", bundle, "-o", ro / "skel")
    elif command == "kinect":
        done = dome_calib_cli("kinect", tmp_path, "--bundle", bundle, "-o", ro / "b")
    else:
        done = _timecode(["sync", tmp_path, "-o", ro / "b"], monkeypatch, capsys)
    assert done.returncode == 1
    assert "cannot write in" in done.stderr, done.stderr


def test_check_writable_probes_the_nearest_existing_folder(tmp_path):
    io_utils.check_writable(tmp_path / "a" / "b" / "c.txt")  # created later, under tmp_path
    assert list(tmp_path.iterdir()) == []  # the probe leaves nothing
    with pytest.raises(OutputPathError, match="cannot write in"):
        io_utils.check_writable(_unwritable_folder(tmp_path) / "x" / "y")


# ------------------------------------------------------------------------------------------ disk full
@pytest.mark.parametrize("failure", [
    RuntimeError("[database_sqlite.cc:1362] SQLite error: database or disk is full"),  # pycolmap's database
    "ENOSPC", "EDQUOT",
])
def test_a_full_disk_in_the_work_folder_is_one_line_naming_it(tmp_path, capture, stand_in_stages, monkeypatch,
                                                               dome_calib_cli, failure):
    cap, _ = capture

    def sfm(capture_dir, work_dir, **k):
        if failure == "ENOSPC":
            raise OSError(errno.ENOSPC, "No space left on device", str(work_dir / "scene_01" / "database.db"))
        if failure == "EDQUOT":
            raise OSError(errno.EDQUOT, "Disk quota exceeded", str(work_dir / "x.npz"))
        raise failure

    monkeypatch.setattr(pipeline, "run_sfm_stage", sfm)
    done = dome_calib_cli("calibrate", cap, "-o", tmp_path / "out", "--work", tmp_path / "work")
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [done.stderr.strip()]
    assert f"{tmp_path / 'work'}: " in done.stderr and "while stage sfm wrote" in done.stderr
    assert "Traceback" not in done.stderr


def test_an_unreadable_input_inside_a_stage_is_not_called_a_full_work_folder(tmp_path, capture, stand_in_stages,
                                                                             monkeypatch, dome_calib_cli):
    cap, _ = capture

    def sfm(capture_dir, work_dir, **k):
        raise PermissionError(errno.EACCES, "Permission denied", str(capture_dir / "scenes" / "scene_01" / "01_01.png"))

    monkeypatch.setattr(pipeline, "run_sfm_stage", sfm)
    done = dome_calib_cli("calibrate", cap, "-o", tmp_path / "out", "--work", tmp_path / "work")
    assert done.returncode == 1
    assert done.stderr.strip() == ("dome-calib: error: [Errno 13] Permission denied: "
                                   f"'{cap / 'scenes' / 'scene_01' / '01_01.png'}'")  # the file, not the work folder


def test_run_cli_says_a_storage_failure_of_any_library_in_one_line(capsys):
    import typer

    from dome_calib.errors import run_cli

    app = typer.Typer()

    @app.command()
    def go() -> None:
        raise RuntimeError("SQLite error: database or disk is full")

    with pytest.raises(SystemExit) as exc:
        import sys
        argv, sys.argv = sys.argv, ["x"]
        try:
            run_cli(app, prog="x")
        finally:
            sys.argv = argv
    assert exc.value.code == 1
    assert capsys.readouterr().err.startswith("x: error: no space left on the disk")


# ------------------------------------------------------------------------------------------ interrupted SfM
def test_an_sfm_stopped_in_its_first_stage_is_resumed_not_thrown_away(tmp_path, capture, stand_in_stages,
                                                                      monkeypatch):
    cap, _ = capture
    stand_in = pipeline.run_sfm_stage
    seen = []

    def sfm(capture_dir, work_dir, **kw):
        work_dir.mkdir(parents=True, exist_ok=True)
        seen.append((work_dir / "database.db").exists())
        if len(seen) == 1:
            (work_dir / "database.db").write_text("features extracted before the stop")
            raise KeyboardInterrupt
        return stand_in(capture_dir, work_dir, **kw)

    monkeypatch.setattr(pipeline, "run_sfm_stage", sfm)
    out = tmp_path / "bundle"
    with pytest.raises(KeyboardInterrupt):
        pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(progress=None, report=NO_PLOTS))
    state = json.loads((tmp_path / "bundle.work" / "state.json").read_text())
    assert state["stages"] == {}
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(progress=None, report=NO_PLOTS))
    assert seen == [False, True]  # the rerun found the first run's features
    assert load_bundle(out).cameras


def test_export_import_and_reconstruct_onto_their_inputs_are_refused_and_the_inputs_kept(tmp_path, capture):
    """The same cause in the commands added since: an output that is (or holds) an input is refused before
    anything is read or written: export onto a file of the bundle, import onto its own source file, reconstruct
    and triangulate into the folder that holds their detections or the bundle."""
    from dome_calib.interop.convert import export_bundle, import_calibration
    from dome_calib.recon.commands import triangulate_file
    from dome_calib.recon.people.commands import reconstruct_folder

    cap, _ = capture
    bundle = cap / "ground_truth"
    calib = bundle / "calibration_synth.json"
    before = {p.name: p.read_bytes() for p in bundle.iterdir() if p.is_file()}
    with pytest.raises(OutputPathError, match="is the input"):
        export_bundle(bundle, "aniposelib", calib)
    with pytest.raises(OutputPathError, match="holds the input"):
        export_bundle(bundle, "colmap", cap)
    toml = tmp_path / "calibration.toml"
    export_bundle(bundle, "aniposelib", toml)
    text = toml.read_bytes()
    with pytest.raises(OutputPathError, match="is the input"):
        import_calibration(toml, "aniposelib", toml)
    assert toml.read_bytes() == text
    detections = tmp_path / "detections"
    (detections / "01_01").mkdir(parents=True)
    with pytest.raises(OutputPathError, match="is the input"):
        reconstruct_folder(detections, bundle, detections)
    with pytest.raises(OutputPathError, match="holds the input"):
        reconstruct_folder(detections, bundle, cap)
    det_file = tmp_path / "det.json"
    det_file.write_text("{}")
    with pytest.raises(OutputPathError, match="holds the input"):
        triangulate_file(bundle, det_file, tmp_path)
    assert {p.name: p.read_bytes() for p in bundle.iterdir() if p.is_file()} == before
    assert det_file.read_text() == "{}" and (detections / "01_01").is_dir()
