"""The report keeps what the calibration found: held cameras are reported as held (issue 37, "the quick path's
report cries wolf"), `dome-calib report` rebuilds without losing the calibration's findings (issue 37, "forgets
what the calibration found"), the change since the previous calibration, and hostile report folders."""
from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

import dome_calib.pipeline.full as pipeline
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.layout import nominal_dome
from dome_calib.report import ReportError, Residuals, write_report

from .report_data import NO_PLOTS, REPORT_FILES, copy_kept_files, moved_copy, old_report_json, synthetic_residuals
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
                                                                              progress=None, report=NO_PLOTS))
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
    assert [r.name for r in rep.to_check] == [names[2]]  # the estimated camera with 40 observations
    assert [(r.code, r.text) for r in rep.to_check[0].reasons] == [("too_few_observations",
                                                                     "too few observations (40 < 100)")]


def test_report_rebuild_keeps_what_the_calibration_found(tmp_path, capture, stand_in_stages, dome_calib_cli):  # noqa: F811
    """Two cameras to check after calibrate (a poorly determined centre; one camera not calibrated); session.json
    and sync.json in report/: `dome-calib report` keeps all of it."""
    cap, _ = capture
    out = tmp_path / "bundle"
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None, report=NO_PLOTS))
    report_dir = out / "report"
    before = json.loads((report_dir / "report.json").read_text())
    assert sorted(r["name"] for r in before["to_check"]) == ["01_24", UNCERTAIN]
    copy_kept_files(report_dir)
    proc = dome_calib_cli("report", out)
    assert proc.returncode == 0, proc.stderr
    assert "cameras to check: 2" in proc.stdout
    after = json.loads((report_dir / "report.json").read_text())
    assert after["to_check"] == before["to_check"]
    for key in ("center_sigma_cm", "world_frame", "stage_seconds", "cluster", "found"):
        assert after[key] == before[key], key
    for name in ("session.json", "sync.json"):
        assert (report_dir / name).read_bytes() == (REPORT_FILES / name).read_bytes()
    assert (report_dir / "index.html").exists()


def test_report_rebuild_of_a_report_json_from_before_found_was_saved(tmp_path, capture, stand_in_stages,  # noqa: F811
                                                                     dome_calib_cli):
    """Layout 1 (no version, no "found", reasons as texts in to_check only): read through the migration, the
    calibration's reasons told from the rules' by the texts that layout wrote."""
    cap, _ = capture
    out = tmp_path / "bundle"
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None, report=NO_PLOTS))
    path = out / "report" / "report.json"
    new = json.loads(path.read_text())
    old = {k: v for k, v in new.items() if k not in ("found", "report_version", "expected_per_type")}
    old["to_check"] = [dict(row, reasons=[r["text"] for r in row["reasons"]]) for row in new["to_check"]]
    path.write_text(json.dumps(old))
    proc = dome_calib_cli("report", out)
    assert proc.returncode == 0, proc.stderr
    assert "was of layout 1: read through its migration" in proc.stdout
    after = json.loads(path.read_text())
    assert after["to_check"] == new["to_check"] and after["report_version"] == 3
    assert after["found"]["missing"] == {"01_24": "saw no tent in any scene"}
    assert list(after["found"]["reasons"]) == [UNCERTAIN]
    assert after["found"]["reasons"][UNCERTAIN][0]["code"] == "position_uncertain"


def test_calibrate_compares_with_the_bundle_out_held_and_with_previous(tmp_path, capture, stand_in_stages):  # noqa: F811
    cap, truth = capture
    out = tmp_path / "bundle"
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None, report=NO_PLOTS))
    assert json.loads((out / "report" / "report.json").read_text())["previous"] is None  # OUT was new
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None, report=NO_PLOTS))
    prev = json.loads((out / "report" / "report.json").read_text())["previous"]
    assert prev["source"] == str(out.resolve()) and prev["added"] == [] and prev["gone"] == []
    assert max(c["moved_mm"] for c in prev["cameras"].values()) < 1e-6  # the same calibration again
    moved = write_bundle(moved_copy(load_bundle(out), {"01_02": 3.0}), tmp_path / "moved")
    pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(seq="test", progress=None, report=NO_PLOTS, previous=moved))
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
    with pytest.raises(ReportError, match=r"report.json: not valid JSON"):
        read_report_folder(folder)


def test_residuals_without_pixel_positions_still_load_and_the_page_says_so(tmp_path):
    """residuals.npz from before uv_px was saved (its old keys only) loads; the page names what it cannot draw."""
    from dome_calib.report.page import read_report_folder

    tiny = nominal_dome("tiny", seed=0)
    res = synthetic_residuals(tiny, loose_lens="01_01", skewed="01_02", few="01_03")
    folder = write_bundle(tiny, tmp_path / "b")
    target = write_report(folder, tiny, res, NO_PLOTS)
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
    write_report(folder, tiny, synthetic_residuals(tiny, loose_lens="01_01", skewed="01_02", few="01_03"), NO_PLOTS)
    before = (folder / "report" / "report.json").read_text()
    (folder / "report" / "residuals.npz").write_bytes(b"PK\x03\x04 half a zip")
    proc = dome_calib_cli("report", folder)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "residuals.npz" in proc.stderr
    assert (folder / "report" / "report.json").read_text() == before


def test_report_cli_unreadable_report_json_is_one_line_and_writes_nothing(tmp_path, dome_calib_cli):
    """A truncated report.json holds what only the calibration knew: refused (one line), not rebuilt without it."""
    tiny = nominal_dome("tiny", seed=0)
    folder = write_bundle(tiny, tmp_path / "b")
    (folder / "report").mkdir()
    (folder / "report" / "report.json").write_text('{"seq": ')
    proc = dome_calib_cli("report", folder)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1
    assert "report.json: not valid JSON" in proc.stderr
    assert sorted(p.name for p in (folder / "report").iterdir()) == ["report.json"]
