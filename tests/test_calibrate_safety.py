"""Issue 15, the pipeline's part: no stale result, one run per work folder, output checked before any work,
the bundle folder replaced whole, interrupts in one line. The SfM and BA stages are stand-ins (no images read
unless a test says so), so these tests take a second each."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import dome_calib.pipeline.full as pipeline
from dome_calib import bundle_io
from dome_calib.ownership import RECORD, mark_scratch, write_bytes, write_text
from dome_calib.bundle_io import load_bundle, recover_folder, replace_folder, write_bundle
from dome_calib.errors import CaptureError, DomeCalibError
from dome_calib.pipeline.workstate import WorkFolderBusy, WorkState

from .report_data import NO_PLOTS, REPORT_FILES
from .test_calibrate import capture, stand_in_stages  # noqa: F401  (fixtures)

ROOT = Path(__file__).resolve().parents[1]


def _options(**kw):
    return pipeline.CalibrateOptions(**{"report": NO_PLOTS, **kw})  # no test here reads a plot


def _write_png(path: Path, value: int) -> None:
    import cv2

    cv2.imwrite(str(path), np.full((48, 64), value, np.uint8))


# ------------------------------------------------------------------------------------------ stale resume
def test_rerun_after_the_images_changed_does_not_return_the_old_result(tmp_path, capture, stand_in_stages,
                                                                       monkeypatch):
    """Calibrate, replace every image by a black one, rerun: the SfM runs again on the new images (here it then
    finds nothing, as the real one would), and its old databases are gone from the work folder."""
    cap, _ = capture
    images = [cap / "scenes" / "scene_01" / f"{n}.png" for n in ("01_01", "01_02", "00_00")]
    for p in images:
        _write_png(p, 128)
    stand_in = pipeline.run_sfm_stage

    def sfm(capture_dir, work_dir, **kw):
        work_dir.mkdir(parents=True, exist_ok=True)
        (work_dir / "database.db").write_text("features of the images seen")
        if all(float(np.mean(__import__("cv2").imread(str(p), 0))) == 0.0 for p in images):
            raise CaptureError(f"{capture_dir}: no scene could be reconstructed (scene_01: blank images)")
        return stand_in(capture_dir, work_dir, **kw)

    monkeypatch.setattr(pipeline, "run_sfm_stage", sfm)
    out = tmp_path / "bundle"
    pipeline.run_calibration(cap, out, _options(seq="s"))
    time.sleep(0.01)  # a new mtime even on coarse clocks
    for p in images:
        _write_png(p, 0)
    with pytest.raises(CaptureError, match="no scene could be reconstructed"):
        pipeline.run_calibration(cap, out, _options(seq="s"))
    assert stand_in_stages["sfm"] == 1  # the second SfM call failed before the stand-in: nothing resumed
    assert load_bundle(out).seq == "s"  # the old bundle is untouched by the failed run


def test_rerun_with_the_same_images_resumes(tmp_path, capture, stand_in_stages):
    cap, _ = capture
    _write_png(cap / "scenes" / "scene_01" / "01_01.png", 128)
    pipeline.run_calibration(cap, tmp_path / "b", _options(seq="s"))
    again = pipeline.run_calibration(cap, tmp_path / "b", _options(seq="s"))
    assert again.resumed == ["sfm", "ba"] and stand_in_stages == {"sfm": 1, "ba": 1}


def test_a_changed_prior_starts_over(tmp_path, capture, stand_in_stages):
    cap, truth = capture
    prior = write_bundle(type(truth)(seq="old", cameras=dict(truth.cameras)), tmp_path / "prior")
    pipeline.run_calibration(cap, tmp_path / "b", _options(prior=prior))
    time.sleep(0.01)
    write_bundle(type(truth)(seq="old", cameras=dict(truth.cameras), calib_data_source="edited"), prior)
    again = pipeline.run_calibration(cap, tmp_path / "b", _options(prior=prior))
    assert again.resumed == [] and stand_in_stages == {"sfm": 2, "ba": 2}


# ------------------------------------------------------------------------------------------ lock
def test_a_second_run_on_the_same_work_folder_fails_at_once_naming_the_holder(tmp_path, capture, stand_in_stages):
    cap, _ = capture
    out = tmp_path / "bundle"
    with WorkState.open(out.with_name("bundle.work"), {}):
        with pytest.raises(WorkFolderBusy, match=rf"in use by another run \(pid {os.getpid()} on .+, started 20"):
            pipeline.run_calibration(cap, out, _options())
        result = CliRunner().invoke(__import__("dome_calib.cli", fromlist=["app"]).app,
                                    ["calibrate", str(cap), "-o", str(out)])
        assert result.exit_code != 0 and isinstance(result.exception, WorkFolderBusy)
    assert stand_in_stages == {"sfm": 0, "ba": 0} and not out.exists()


def test_a_stale_lock_of_a_dead_run_is_taken_over_with_a_warning(tmp_path, capture, stand_in_stages, caplog):
    cap, _ = capture
    work = tmp_path / "bundle.work"
    work.mkdir()
    mark_scratch(work)  # a work folder of ours (as WorkState.open makes it)
    (work / "lock").write_text(json.dumps({"pid": 999_999_999, "host": "node7", "started": "2026-01-01T00:00:00"}))
    pipeline.run_calibration(cap, tmp_path / "bundle", _options())
    assert "taking over from a run that stopped without releasing it (pid 999999999 on node7" in caplog.text
    assert (work / "lock").read_text() == ""  # released


# ------------------------------------------------------------------------------------------ output checks
@pytest.mark.parametrize("kind", ["file", "fifo", "symlink to a file", "foreign folder"])
def test_an_output_that_is_not_a_bundle_folder_is_refused_before_any_work(tmp_path, capture, stand_in_stages, kind):
    cap, _ = capture
    out = tmp_path / "out"
    if kind == "file":
        out.write_text("precious")
    elif kind == "fifo":
        os.mkfifo(out)
    elif kind == "symlink to a file":
        (tmp_path / "elsewhere").write_text("precious")
        out.symlink_to(tmp_path / "elsewhere")
    else:
        out.mkdir()
        (out / "thesis.tex").write_text("precious")
    with pytest.raises(DomeCalibError, match="out: (is a (file|FIFO|symbolic link)|holds thesis.tex)"):
        pipeline.run_calibration(cap, out, _options())
    assert stand_in_stages == {"sfm": 0, "ba": 0}
    assert not (tmp_path / "out.work").exists()
    if kind == "file":
        assert out.read_text() == "precious"


def test_a_symlink_where_the_bundle_folder_belongs_is_refused_before_any_work(tmp_path, capture, stand_in_stages):
    cap, truth = capture
    real = write_bundle(type(truth)(seq="old", cameras=dict(truth.cameras)), tmp_path / "real")
    link = tmp_path / "link"
    link.symlink_to(real)
    with pytest.raises(DomeCalibError, match="link: is a symbolic link"):
        pipeline.run_calibration(cap, link, _options(seq="new"))
    assert link.is_symlink() and load_bundle(real).seq == "old" and stand_in_stages == {"sfm": 0, "ba": 0}


def test_a_bundle_folder_of_another_seq_is_replaced_whole(tmp_path, capture, stand_in_stages):
    cap, truth = capture
    out = write_bundle(type(truth)(seq="other", cameras=dict(truth.cameras)), tmp_path / "bundle")
    write_text(out / "synctables_other.json", "{}")  # as `timecode sync` writes it: ours
    pipeline.run_calibration(cap, out, _options(seq="new"))
    assert sorted(p.name for p in out.iterdir()) == [RECORD, "calibration_new.json", "report"]
    assert load_bundle(out).seq == "new"


def test_a_recalibration_keeps_the_kinect_and_sync_files_of_the_same_seq(tmp_path, capture, stand_in_stages):
    cap, truth = capture
    out = write_bundle(type(truth)(seq="s", cameras=dict(truth.cameras)), tmp_path / "bundle")
    write_text(out / "kcalibration_s.json", "kinect")  # as `dome-calib kinect` and `timecode sync` write them
    (out / "report").mkdir()
    sync = (REPORT_FILES / "sync.json").read_bytes()  # a real sync report (it is read back through its schema)
    write_bytes(out / "report" / "sync.json", sync)
    pipeline.run_calibration(cap, out, _options(seq="s"))
    assert (out / "kcalibration_s.json").read_text() == "kinect"
    assert (out / "report" / "sync.json").read_bytes() == sync
    assert (out / "report" / "report.json").exists()


# ------------------------------------------------------------------------------------------ whole-folder swap
@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "fallback"])
def test_replace_folder_swaps_whole_folders(tmp_path, truth_bundle, monkeypatch, exchange):
    if not exchange:
        monkeypatch.setattr(bundle_io, "_exchange", lambda a, b: False)
    out = write_bundle(truth_bundle, tmp_path / "b")
    write_text(out / "old_only.txt", "x")  # ours (recorded): the swap may remove it
    staging = bundle_io.staging_folder(out)
    write_bundle(type(truth_bundle)(seq="new", cameras=truth_bundle.cameras), staging)
    replace_folder(staging, out)
    assert sorted(p.name for p in out.iterdir()) == [RECORD, "calibration_new.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]  # no staging or set-aside folder left


def test_a_replacement_stopped_between_its_renames_is_undone_at_the_next_run(tmp_path, truth_bundle):
    out = tmp_path / "b"
    write_bundle(truth_bundle, tmp_path / ".b.aside")  # the old bundle set aside, the new one not yet in
    (tmp_path / ".b.staging").mkdir()
    recover_folder(out)
    assert load_bundle(out).seq == truth_bundle.seq
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]


@pytest.fixture
def truth_bundle():
    from dome_calib.layout import nominal_dome

    return nominal_dome("tiny", seed=0)


# ------------------------------------------------------------------------------------------ interrupts
_SLOW_SFM = """
import signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)  # as from a terminal, even if this test runs in a background job
from pathlib import Path
import dome_calib.pipeline.full as pipeline
from dome_calib.executor.local import LocalProcessExecutor

MARKER = Path(sys.argv.pop())

def sfm(capture_dir, work_dir, **kw):
    with LocalProcessExecutor(2) as pool:  # workers busy when the signal comes
        futures = [pool.submit(time.sleep, 30) for _ in range(4)]
        MARKER.write_text("started")
        [f.result() for f in futures]

pipeline.run_sfm_stage = sfm
from dome_calib.cli import main
main()
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupt_gives_one_line_stops_the_workers_and_exits_130(tmp_path, capture, sig):
    cap, _ = capture
    marker = tmp_path / "started"
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_SFM, "calibrate", str(cap), "-o", str(tmp_path / "out"),
                             str(marker)], stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            start_new_session=True, cwd=ROOT)
    deadline = time.monotonic() + 60
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    os.killpg(proc.pid, sig)  # as a terminal's Ctrl-C: the whole process group, workers included
    _, err = proc.communicate(timeout=60)
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == 130
    assert lines == ["dome-calib: interrupted during sfm; rerun the same command to resume"], err
    assert not (tmp_path / "out").exists()
    assert (tmp_path / "out.work" / "lock").read_text() == ""  # released: a rerun can start at once
