"""The report keeps what the calibration found: held cameras are reported as held (issue 37, "the quick path's
report cries wolf"), `dome-calib report` rebuilds without losing the calibration's findings (issue 37, "forgets
what the calibration found"), the change since the previous calibration, and hostile report folders."""
from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import dome_calib.pipeline.full as pipeline
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.layout import nominal_dome
from dome_calib.report import Residuals, write_report

from .report_data import moved_copy, old_report_json, synthetic_residuals
from .test_calibrate import CERTAIN, UNCERTAIN, capture, stand_in_stages  # noqa: F401  (fixtures)
from .test_quick_recalibration import _matched_scene, _neighbourhood


def _numpy_warnings(caught) -> list[str]:
    return [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]


def test_quick_path_with_nothing_changed_reports_every_camera_held_not_too_few(tmp_path, monkeypatch):
    """The issue's case: nothing changed, yet "cameras to check: 16 (too few observations, 0 < 100)", "RMS nan px"
    and numpy warnings. Every camera is held from the prior: nothing to check, no RMS, no warning."""
    import dome_calib.pipeline.quick as quick

    prior = _neighbourhood()
    matched = _matched_scene(tmp_path, prior, prior, seed=3)
    monkeypatch.setattr(quick, "match_first_scene", lambda *a, **k: matched)
    cap = tmp_path / "capture"
    (cap / "scenes" / "scene_01").mkdir(parents=True)
    (cap / "capture.json").write_text(json.dumps({"scenes": ["scene_01"], "cameras": sorted(prior.cameras)}))
    prior_dir = write_bundle(prior, tmp_path / "prior")
    out = tmp_path / "quick"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(prior=prior_dir, only_changed=True,
                                                                              progress=None))
        text = pipeline.format_result(result)
    assert _numpy_warnings(caught) == []
    assert result.to_check == [] and "nan" not in text and "too few" not in text
    assert "cameras to check: 0" in text
    rep = json.loads((out / "report" / "report.json").read_text())
    assert rep["to_check"] == []
    assert all(c["held"] == "held from the prior (agrees with it)" for c in rep["per_camera"].values())
    assert len(rep["per_camera"]) == len(prior.cameras)
    assert rep["found"]["held"].keys() == prior.cameras.keys()


def test_held_cameras_are_not_judged_by_their_observation_count_but_estimated_ones_are():
    tiny = nominal_dome("tiny", seed=0)
    names = sorted(tiny.cameras)
    res = synthetic_residuals(dataclasses.replace(tiny, cameras={n: tiny.cameras[n] for n in names[:3]}),
                              loose_lens=names[0], skewed=names[1], few=names[2])
    from dome_calib.report import build_report

    rep = build_report(tiny, res, held={n: "held from the prior (agrees with it)" for n in names[3:]})
    assert [r["name"] for r in rep["to_check"]] == [names[2]]  # the estimated camera with 40 observations
    assert "too few observations (40 < 100)" in rep["to_check"][0]["reasons"]


def test_report_rebuild_keeps_what_the_calibration_found(tmp_path, capture, stand_in_stages, dome_calib_cli):  # noqa: F811
    """Two cameras to check after calibrate (a poorly determined centre; one camera not calibrated); session.json
    and sync.json in report/: `dome-calib report` keeps all of it."""
    cap, _ = capture
    out = tmp_path / "bundle"
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None))
    report_dir = out / "report"
    before = json.loads((report_dir / "report.json").read_text())
    assert sorted(r["name"] for r in before["to_check"]) == ["01_24", UNCERTAIN]
    (report_dir / "session.json").write_text(json.dumps({"seq": "test", "pillars": {}}))
    (report_dir / "sync.json").write_text(json.dumps({"seq": "test", "streams": {}}))
    proc = dome_calib_cli("report", out)
    assert proc.returncode == 0, proc.stderr
    assert "cameras to check: 2" in proc.stdout
    after = json.loads((report_dir / "report.json").read_text())
    assert after["to_check"] == before["to_check"]
    for key in ("center_sigma_cm", "world_frame", "stage_seconds", "cluster", "found"):
        assert after[key] == before[key], key
    assert (report_dir / "session.json").exists() and (report_dir / "sync.json").exists()
    assert (report_dir / "index.html").exists()


def test_report_rebuild_of_a_report_json_from_before_found_was_saved(tmp_path, capture, stand_in_stages,  # noqa: F811
                                                                     dome_calib_cli):
    cap, _ = capture
    out = tmp_path / "bundle"
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None))
    path = out / "report" / "report.json"
    old = json.loads(path.read_text())
    for key in ("found", "report_version", "expected_per_type"):
        old.pop(key)
    path.write_text(json.dumps(old))
    proc = dome_calib_cli("report", out)
    assert proc.returncode == 0, proc.stderr
    after = json.loads(path.read_text())
    assert after["to_check"] == old["to_check"]
    assert after["found"]["missing"] == {"01_24": "saw no tent in any scene"}
    assert list(after["found"]["reasons"]) == [UNCERTAIN]


def test_calibrate_compares_with_the_bundle_out_held_and_with_previous(tmp_path, capture, stand_in_stages):  # noqa: F811
    cap, truth = capture
    out = tmp_path / "bundle"
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None))
    assert json.loads((out / "report" / "report.json").read_text())["previous"] is None  # OUT was new
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None))
    prev = json.loads((out / "report" / "report.json").read_text())["previous"]
    assert prev["source"] == str(out.resolve()) and prev["added"] == [] and prev["gone"] == []
    assert max(c["moved_mm"] for c in prev["cameras"].values()) < 1e-6  # the same calibration again
    moved = write_bundle(moved_copy(load_bundle(out), {"01_02": 3.0}), tmp_path / "moved")
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None, previous=moved))
    rep = json.loads((out / "report" / "report.json").read_text())
    cams = rep["previous"]["cameras"]
    assert cams["01_02"]["moved_mm"] == pytest.approx(30.0, abs=0.5)  # the rigid fit leaves the moved camera out
    assert cams["01_02"]["turned_deg"] == pytest.approx(0.5, abs=0.01)
    assert max(c["moved_mm"] for n, c in cams.items() if n != "01_02") < 0.5


def test_calibrate_refuses_a_previous_that_is_not_a_bundle_before_any_work(tmp_path, capture, stand_in_stages,  # noqa: F811
                                                                           dome_calib_cli):
    cap, _ = capture
    proc = dome_calib_cli("calibrate", cap, "-o", tmp_path / "out", "--previous", tmp_path / "nothing")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "nothing" in proc.stderr
    assert stand_in_stages == {"sfm": 0, "ba": 0} and not (tmp_path / "out").exists()


def test_report_cli_previous_lists_moves_added_and_gone(tmp_path, dome_calib_cli):
    tiny = nominal_dome("tiny", seed=0)
    folder = write_bundle(tiny, tmp_path / "b")
    names = sorted(tiny.cameras)
    prev = moved_copy(tiny, {names[3]: 2.0})
    prev = dataclasses.replace(prev, cameras={n: c for n, c in prev.cameras.items() if n != names[0]})
    prev.cameras["19_01"] = dataclasses.replace(nominal_dome("full", seed=0).cameras["19_01"])
    write_bundle(prev, tmp_path / "prev")
    proc = dome_calib_cli("report", folder, "--previous", tmp_path / "prev")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads((folder / "report" / "report.json").read_text())
    p = rep["previous"]
    assert p["added"] == [names[0]] and p["gone"] == ["19_01"]
    assert p["cameras"][names[3]]["moved_mm"] == pytest.approx(20.0, abs=0.5)
    assert f"{names[3]}: moved 2.0 cm" in proc.stdout


def test_hostile_report_folder_page_says_what_is_missing(tmp_path):
    """No residuals.npz, a report.json from an older version (only the keys of the first report): the page data
    lists both; an empty folder says report.json is missing."""
    from dome_calib.report.page import read_report_folder

    tiny = nominal_dome("tiny", seed=0)
    folder = tmp_path / "report"
    folder.mkdir()
    old = old_report_json(tiny, "x", [{"name": "01_01", "type": "vga", "reasons": ["moved 3 cm"]}])
    (folder / "report.json").write_text(json.dumps(old))
    data = read_report_folder(folder)
    text = " | ".join(data["missing"])
    assert "residuals.npz: not found" in text and "older version" in text and "per_type" in text
    assert len(data["cameras"]) == 16 and data["cameras"][0]["res"] is None
    (folder / "report.json").unlink()
    assert any("report.json: not found" in m for m in read_report_folder(folder)["missing"])
    (folder / "report.json").write_text("[1, 2")
    assert any("report.json: unreadable" in m for m in read_report_folder(folder)["missing"])


def test_residuals_without_pixel_positions_still_load_and_the_page_says_so(tmp_path):
    """residuals.npz from before uv_px was saved (its old keys only) loads; the page names what it cannot draw."""
    from dome_calib.report.page import read_report_folder

    tiny = nominal_dome("tiny", seed=0)
    res = synthetic_residuals(tiny, loose_lens="01_01", skewed="01_02", few="01_03")
    folder = write_bundle(tiny, tmp_path / "b")
    target = write_report(folder, tiny, res)
    back = Residuals.load(target / "residuals.npz")
    np.testing.assert_allclose(back.uv_px, res.uv_px, atol=1e-3)  # px, float32
    np.savez_compressed(target / "residuals.npz", camera_names=np.asarray(res.camera_names),
                        camera_index=res.camera_index, residual_px=res.residual_px.astype(np.float32))
    old = Residuals.load(target / "residuals.npz")
    assert old.uv_px is None and len(old.residual_px) == len(res.residual_px)
    data = read_report_folder(target)
    assert data["arrows"] == {} and any("no pixel positions" in m for m in data["missing"])
    assert set(data["hist"]) == {"vga", "hd", "kinect-color"}


def test_report_cli_damaged_residuals_is_one_line_and_writes_nothing(tmp_path, dome_calib_cli):
    tiny = nominal_dome("tiny", seed=0)
    folder = write_bundle(tiny, tmp_path / "b")
    write_report(folder, tiny, synthetic_residuals(tiny, loose_lens="01_01", skewed="01_02", few="01_03"))
    before = (folder / "report" / "report.json").read_text()
    (folder / "report" / "residuals.npz").write_bytes(b"PK\x03\x04 half a zip")
    proc = dome_calib_cli("report", folder)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "residuals.npz" in proc.stderr
    assert (folder / "report" / "report.json").read_text() == before


def test_report_cli_unreadable_report_json_says_so_in_one_line(tmp_path, dome_calib_cli):
    tiny = nominal_dome("tiny", seed=0)
    folder = write_bundle(tiny, tmp_path / "b")
    (folder / "report").mkdir()
    (folder / "report" / "report.json").write_text('{"seq": ')
    proc = dome_calib_cli("report", folder)
    assert proc.returncode == 0, proc.stderr
    assert sum("report.json: unreadable" in line for line in proc.stdout.splitlines()) == 1
    assert json.loads((folder / "report" / "report.json").read_text())["seq"] == tiny.seq


JSON_VALUES = st.recursive(st.none() | st.booleans() | st.integers(-5, 10**6) | st.floats(allow_nan=True)
                           | st.text(max_size=4),
                           lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner,
                                                                                        max_size=3), max_leaves=6)


@pytest.fixture(scope="module")
def tiny_report_files(tmp_path_factory):
    """report.json, session.json and sync.json of a tiny report, and its residuals."""
    tiny = nominal_dome("tiny", seed=0)
    folder = write_bundle(tiny, tmp_path_factory.mktemp("tiny") / "b")
    res = synthetic_residuals(tiny, loose_lens="01_01", skewed="01_02", few="01_03")
    target = write_report(folder, tiny, res, extra={"center_sigma_cm": {n: 0.05 for n in tiny.cameras}})
    report = json.loads((target / "report.json").read_text())
    session = {"pillars": {"kinect": {"achieved": "1 Kinect", "sensors": [{"sensor": "KINECTNODE4",
                                                                            "color_camera": "50_04",
                                                                            "frames_used": 6, "rms_ir_px": 0.1}],
                                      "to_check": []},
                           "sync": {"to_check": ["x"]}}, "stage_seconds": {"calibrate": 1.0}}
    sync = {"streams": {"vga": {"n_frames": 65, "first_ms": 1.0, "last_ms": 2.0}},
            "channels": {"vga": {"n_misread": 0, "segments": [{"residual_max_us": 0.2}]}},
            "kinect": {"KINECTNODE4": {"status": "synced", "device_clock": [{"residual_max_us": 3.0}]}}}
    return report, session, sync, res


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_page_data_of_a_mutated_report_never_fails_and_stays_plain_json(tiny_report_files, data):
    """Any value of report.json (top level or in a camera's entry), session.json or sync.json replaced by any JSON
    value: the page data is still built and is plain JSON (NaN and infinities dropped); nothing raises."""
    from dome_calib.report.page import page_data, render_page

    report, session, sync, res = (json.loads(json.dumps(x)) if isinstance(x, dict) else x
                                  for x in tiny_report_files)
    which = data.draw(st.sampled_from(["report", "camera", "session", "sync"]))
    value = data.draw(JSON_VALUES)
    if which == "report":
        report[data.draw(st.sampled_from(sorted(report)))] = value
    elif which == "camera":
        cam = report["per_camera"][data.draw(st.sampled_from(sorted(report["per_camera"])))]
        cam[data.draw(st.sampled_from(sorted(cam)))] = value
    elif which == "session" and data.draw(st.booleans()):
        session[data.draw(st.sampled_from(sorted(session)))] = value
    elif which == "session":
        session["pillars"]["kinect"]["sensors"] = value
    else:
        sync[data.draw(st.sampled_from(sorted(sync)))] = value
    built = page_data(report, res, session=session, sync=sync)
    json.dumps(built, allow_nan=False)
    assert "report-data" in render_page(built)
