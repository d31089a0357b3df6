"""Issue 37: a Kinect that vanishes on a typo. Kinect node names are validated where they enter (session.json,
kinect/ folders) and where they are written (kcalibration, ksynctables), and a session's kinect/ folders, sync
nodes and 50_<nn> cameras are cross-checked before any work; `timecode sync` into a calibrated bundle checks its
nodes against the bundle's Kinects. Uses the small product session of tests/conftest.py (KINECTNODE4 on 50_04)."""
from __future__ import annotations

import json
import shutil

import pytest

from dome_calib.bundle_io import write_bundle
from dome_calib.errors import BundleFormatError, CaptureError

from .cli_runner import run_in_process


def _renamed(root, tmp_path, new: str):
    """A copy of the session whose session.json calls KINECTNODE4 ``new``."""
    copy = tmp_path / "sess"
    shutil.copytree(root, copy)
    path = copy / "sync" / "session.json"
    doc = json.loads(path.read_text())
    doc["kinect"] = {new: doc["kinect"].pop("KINECTNODE4")}
    path.write_text(json.dumps(doc))
    return copy


def _untouched(out):
    return {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()}


@pytest.mark.parametrize("new, message", [
    ("KINECTNODE9", "KINECTNODE4: no Kinect KINECTNODE4 in"),  # 50_09 is a camera of the capture: the typo of 4
    ("KINECTNODE7", "KINECTNODE7: its colour camera 50_07 is not a camera of the capture"),
    ("KINECT4", 'session.json: kinect.KINECT4: "KINECT4" is not a Kinect node name'),
])
def test_session_with_a_kinect_named_differently_in_sync_is_refused_before_any_work(small_product_session, tmp_path,
                                                                                     dome_calib_cli, new, message):
    root, truth = small_product_session
    sess = _renamed(root, tmp_path, new)
    out = write_bundle(truth, tmp_path / "bundle")
    before = _untouched(out)
    done = dome_calib_cli("session", sess, "-o", out)
    assert done.returncode == 1
    errors = [ln for ln in done.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and message in errors[0], done.stderr
    assert "dome-calib session: calibrate" not in done.stderr  # refused before the calibration started
    assert _untouched(out) == before and not (tmp_path / "bundle.work").exists()


def test_timecode_sync_with_a_key_no_reader_accepts_is_refused_and_the_bundle_kept(small_product_session, tmp_path,
                                                                                    monkeypatch, capsys):
    from timecode.cli import main

    root, truth = small_product_session
    sess = _renamed(root, tmp_path, "KINECT4")
    out = write_bundle(truth, tmp_path / "bundle")
    before = _untouched(out)
    done = run_in_process(main, "timecode", ["sync", sess / "sync", "-o", out], monkeypatch, capsys)
    assert done.returncode == 1 and 'session.json: kinect.KINECT4: "KINECT4" is not a Kinect node name' in done.stderr
    assert _untouched(out) == before


def test_timecode_sync_names_a_node_the_calibrated_bundle_does_not_have(small_product_session, tmp_path,
                                                                          monkeypatch, capsys):
    from timecode.cli import main

    root, truth = small_product_session
    sess = _renamed(root, tmp_path, "KINECTNODE7")  # 50_07 is not a camera of the tiny dome
    out = write_bundle(truth, tmp_path / "bundle")
    before = _untouched(out)
    done = run_in_process(main, "timecode", ["sync", sess / "sync", "-o", out], monkeypatch, capsys)
    assert done.returncode == 1
    assert "session.json: kinect.KINECTNODE7: the bundle" in done.stderr and "no colour camera 50_07" in done.stderr
    assert _untouched(out) == before


def test_a_kinect_folder_with_a_malformed_node_name_is_refused(tmp_path):
    from dome_calib.kinect.detect import find_sensor_frames

    for name in ("KINECTNODE07", "KINECTNODE0", "KinectNode4"):
        (tmp_path / name).mkdir()
        with pytest.raises(CaptureError, match=f"{name}: not a Kinect node name"):
            find_sensor_frames(tmp_path)
        (tmp_path / name).rmdir()


def test_the_writers_never_write_a_kinect_name_their_readers_refuse():
    import numpy as np

    from dome_calib.bundle import SyncTable
    from dome_calib.panoptic_io import format_ksynctables

    table = SyncTable(index=np.arange(3), univ_time_ms=np.arange(3.0))
    format_ksynctables({"KINECTNODE4": table}, {})
    with pytest.raises(BundleFormatError, match="'KINECT4': not named KINECTNODE<n>"):
        format_ksynctables({"KINECT4": table}, {})


def test_a_session_bundle_that_does_not_read_back_names_the_output_not_the_staging_folder(
        small_product_session, tmp_path, dome_calib_cli, monkeypatch):
    """Whatever slips through to the final read-back check is named by OUT (the staging folder is gone then)."""
    import numpy as np

    import dome_calib.pipeline.full as pipeline
    import dome_calib.pipeline.session as session
    from dome_calib.pipeline.stages import residuals_of
    from dome_calib.pipeline.types import BAOutcome, SfmOutcome

    from .test_calibrate import _problem

    root, truth = small_product_session

    def fake_ba(problem, *, progress=True):
        return BAOutcome(problem=problem, cameras={n: problem.camera(n) for n in problem.camera_names},
                         residuals=residuals_of(problem), inlier=np.ones(problem.n_observations, bool))

    monkeypatch.setattr(pipeline, "run_sfm_stage", lambda *a, **k: SfmOutcome(problem=_problem(truth)))
    monkeypatch.setattr(pipeline, "run_ba_stage", fake_ba)

    def broken_sync(result, folder, **kw):  # a writer that leaves a file its reader refuses
        (folder / "ksynctables_sess.json").write_text('{"kinect": {"color": {"KINECT4": {}}, "depth": {}}}')

    monkeypatch.setattr(session, "write_sync", broken_sync)
    out = tmp_path / "bundle"
    done = dome_calib_cli("session", root, "-o", out)
    assert done.returncode == 1
    error = [ln for ln in done.stderr.splitlines() if "error:" in ln][0]
    assert f"{out}/ksynctables_sess.json" in error and "staging" not in error and f"nothing written to {out}" in error
    assert not out.exists()
