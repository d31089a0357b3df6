"""Issue 50: a bundle given to compare with (report --previous, calibrate --prior) that shares fewer than 3 cameras
is refused before work in one line naming the option, its folder and the bundle or capture it is compared with.
Before (main at aaf6910): `report --previous` said "only 2 cameras in common; need at least 3 to align", naming
neither; `calibrate --prior` found out after the structure from motion."""
from __future__ import annotations

import pytest

import dome_calib.pipeline.full as pipeline
from dome_calib.align import AlignmentError
from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.layout import nominal_dome

from .report_data import NO_PLOTS  # no test here reads a plot
from .test_calibrate import capture, stand_in_stages  # noqa: F401  (fixtures)


@pytest.fixture(scope="module")
def dome():
    return nominal_dome("tiny", seed=0)


def _bundle(dome, names, folder):
    return write_bundle(Bundle(seq="old", cameras={n: dome.cameras[n] for n in names}), folder)


@pytest.mark.parametrize("shared", [0, 1, 2])
def test_report_previous_sharing_too_few_cameras(dome, shared, dome_calib_cli, tmp_path):
    names = sorted(dome.cameras)
    new = _bundle(dome, names[:8], tmp_path / "b")
    old = _bundle(dome, names[8 - shared:8 - shared + 6], tmp_path / "old")
    out = dome_calib_cli("report", str(new), "--previous", str(old))
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 1 and len(lines) == 1, out.stderr
    assert f"--previous {old}: {shared} camera(s) in common with the bundle {new}" in lines[0], lines[0]
    assert not (new / "report").exists()  # refused before any work


def test_report_previous_sharing_three_cameras_compares(dome, dome_calib_cli, tmp_path):
    names = sorted(dome.cameras)
    new = _bundle(dome, names[:8], tmp_path / "b")
    old = _bundle(dome, names[5:12], tmp_path / "old")
    out = dome_calib_cli("report", str(new), "--previous", str(old))
    assert out.returncode == 0, out.stderr
    assert "added 5, gone 4" in out.stdout, out.stdout


def test_calibrate_prior_sharing_too_few_cameras_is_refused_before_work(capture, stand_in_stages, dome,  # noqa: F811
                                                                        tmp_path):
    cap, _ = capture
    prior = _bundle(dome, sorted(dome.cameras)[:2], tmp_path / "prior")
    with pytest.raises(AlignmentError, match=f"--prior {prior}: 2 camera\\(s\\) in common with the capture {cap}"):
        pipeline.run_calibration(cap, tmp_path / "out", pipeline.CalibrateOptions(prior=prior, report=NO_PLOTS))
    assert stand_in_stages["sfm"] == 0 and not (tmp_path / "out").exists()
