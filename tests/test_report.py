"""The calibration report (dome_calib.report) and the `dome-calib report` command, on the tiny nominal dome."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from dome_calib.ownership import RECORD
from dome_calib.bundle_io import write_bundle
from dome_calib.report import ReportError, ReportOptions, Residuals, build_report, load_residuals, write_report
from dome_calib.layout import nominal_dome
from dome_calib.reasons import ReasonCode, reason


@pytest.fixture(scope="module")
def tiny():
    return nominal_dome("tiny", seed=0)


def _residuals(bundle, sigma_px=0.5, n_per_cam=300, few="01_01", noisy="00_00", seed=0):
    """Gaussian residuals per camera; ``few`` gets 20 observations, ``noisy`` 5x the noise."""
    rng = np.random.default_rng(seed)
    names = sorted(bundle.cameras)
    idx, res = [], []
    for k, n in enumerate(names):
        m = 20 if n == few else n_per_cam
        idx.append(np.full(m, k))
        res.append(rng.normal(0, sigma_px * (5 if n == noisy else 1), size=(m, 2)))
    return Residuals(camera_names=names, camera_index=np.concatenate(idx), residual_px=np.concatenate(res))


def test_build_report_flags_cameras(tiny):
    res = _residuals(tiny)
    rep = build_report(tiny, res, ReportOptions(min_observations=100),
                       changes={"01_03": [reason(ReasonCode.MOVED, "moved 3.1 cm")]}, missing={"01_24": "saw no tent"})
    reasons = {row.name: {r.code: r.text for r in row.reasons} for row in rep.to_check}
    assert set(reasons) == {"01_01", "00_00", "01_03", "01_24"}
    assert reasons["01_01"] == {ReasonCode.TOO_FEW_OBSERVATIONS: "too few observations (20 < 100)"}
    assert list(reasons["00_00"]) == [ReasonCode.HIGH_RMS] and reasons["01_03"] == {ReasonCode.MOVED: "moved 3.1 cm"}
    assert reasons["01_24"] == {ReasonCode.NOT_CALIBRATED: "not calibrated: saw no tent"}
    # per-coordinate RMS of Gaussian noise is sigma
    vga_rms = rep.per_type["vga"].rms_px
    assert vga_rms == pytest.approx(0.5, rel=0.05)
    assert rep.per_camera["01_01"].observations == 20
    json.loads(rep.model_dump_json())  # plain, finite data


def test_residuals_round_trip_and_bad_file(tmp_path, tiny):
    res = _residuals(tiny)
    res.save(tmp_path / "r.npz")
    back = Residuals.load(tmp_path / "r.npz")
    assert back.camera_names == res.camera_names
    np.testing.assert_array_equal(back.camera_index, res.camera_index)
    np.testing.assert_allclose(back.residual_px, res.residual_px, atol=1e-6)  # stored as float32
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ReportError, match="bad.npz: not a residual file"):
        Residuals.load(tmp_path / "bad.npz")


def test_unknown_camera_in_residuals(tiny):
    res = _residuals(tiny)
    res.camera_names[0] = "19_19"
    with pytest.raises(ReportError, match="19_19"):
        build_report(tiny, res)


def test_write_report_whole_or_nothing(tmp_path, tiny, monkeypatch):
    folder = write_bundle(tiny, tmp_path / "b")
    target = write_report(folder, tiny, _residuals(tiny))
    assert {p.name for p in target.iterdir()} == {"report.json", "residuals.npz", "dome.png", "residuals.png",
                                                   "observations.png", "index.html", RECORD}
    assert load_residuals(folder) is not None
    before = (target / "report.json").read_text()

    import dome_calib.report.plots as plots

    def boom(*a, **k):
        raise RuntimeError("plot failed")

    monkeypatch.setattr(plots, "plot_observations", boom)
    with pytest.raises(RuntimeError):
        write_report(folder, tiny, None)
    assert (target / "report.json").read_text() == before  # the old report is untouched
    assert sorted(p.name for p in folder.iterdir() if p.name.startswith(".")) == [RECORD]  # no staging left


def test_report_cli(tmp_path, tiny):
    from dome_calib.cli import app

    folder = write_bundle(tiny, tmp_path / "b")
    moved = dict(tiny.cameras)
    c = moved["01_02"]
    moved["01_02"] = dataclasses.replace(c, t_cm=c.t_cm + [4.0, 0, 0])
    prior = write_bundle(dataclasses.replace(tiny, cameras=moved), tmp_path / "prior")
    result = CliRunner().invoke(app, ["report", str(folder), "--prior", str(prior)])
    assert result.exit_code == 0, result.output
    assert "no residuals saved" in result.output and "01_02: moved 4.0 cm" in result.output
    rep = json.loads((folder / "report" / "report.json").read_text())
    assert rep["has_residuals"] is False and [r["name"] for r in rep["to_check"]] == ["01_02"]


def test_report_cli_bad_input(tmp_path, dome_calib_cli):
    proc = dome_calib_cli("report", tmp_path / "missing")
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1 and "missing: not a folder" in proc.stderr


def test_text_from_the_bundle_is_drawn_as_text_in_the_plots(tmp_path, tiny):
    """A seq with matplotlib's math markup (an unbalanced ``$``) failed the whole report (ValueError from the math
    parser): the plots draw names as they are."""
    odd = dataclasses.replace(tiny, seq="take$\\frac{1$2", calib_data_source="$\\oops{")
    folder = write_bundle(odd, tmp_path / "b")
    target = write_report(folder, odd, _residuals(odd))
    assert {"dome.png", "observations.png", "residuals.png"} <= {p.name for p in target.iterdir()}
    assert json.loads((target / "report.json").read_text())["seq"] == "take$\\frac{1$2"
