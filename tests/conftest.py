"""Shared fixtures: the real Panoptic calibration (copied into tests/data, see PROVENANCE.md)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# Every property test draws the same examples on every run and machine (fixed seeds: a red CI is a real defect,
# not a draw); HYPOTHESIS_PROFILE=explore draws afresh and keeps failures in .hypothesis/ when hunting.
settings.register_profile("fixed", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "fixed"))

DATA = Path(__file__).parent / "data"
REAL_CALIBRATION = DATA / "panoptic" / "calibration_160906_band1.json"
REAL_KCALIBRATION = DATA / "panoptic" / "kcalibration_171026_cello3.json"


@pytest.fixture(scope="session")
def real_cameras():
    """The 520 cameras of the real file, keyed by name."""
    from dome_calib.panoptic_io import read_calibration

    cameras, _ = read_calibration(REAL_CALIBRATION)
    return cameras


@pytest.fixture
def dome_calib_cli(monkeypatch, capsys):
    """Run ``dome-calib ARGS`` in this process through ``run_cli`` (as the installed command does): the
    one-line errors and exit codes are the command's own, without a second Python starting (~1.5 s each).
    Returns a ``subprocess.CompletedProcess`` (returncode, stdout, stderr)."""
    from dome_calib.cli import main

    from .cli_runner import run_in_process

    def run(*args: str):
        return run_in_process(main, "dome-calib", args, monkeypatch, capsys)

    return run


def stub_capture(out, options):
    """Stand-in for the tent capture of a synthetic product session (``synth.session.write_capture``): the scene
    list, ``capture.json`` and the ground truth only, no images (tests stand in for SfM and BA with the truth)."""
    import json

    from dome_calib.bundle_io import write_bundle
    from dome_calib.synth.capture import load_layout

    (out / "scenes" / "scene_01").mkdir(parents=True)
    cams = load_layout(options)
    (out / "capture.json").write_text(json.dumps({"preset": str(options.preset), "seed": options.seed,
                                                  "scenes": ["scene_01"], "cameras": sorted(cams.cameras)}))
    write_bundle(cams, out / "ground_truth")


@pytest.fixture(scope="session")
def small_product_session(tmp_path_factory):
    """A small whole-product session (dome_calib.synth.session) with its ground truth: the tiny dome as built,
    one Kinect (KINECTNODE4 on 50_04, 6 good + 1 blurred board frames), 3 s of LTC audio, the walking person's
    detections. The tent capture is a stub (scene list only): tests stand in for SfM and BA with the truth.
    Returns (session folder, ground-truth bundle)."""
    import dome_calib.synth.session as synth_session
    from dome_calib.bundle_io import load_bundle

    root = tmp_path_factory.mktemp("product") / "sess"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(synth_session, "write_capture", stub_capture)
        synth_session.make_product_session(root, synth_session.SessionOptions(
            duration_s=3.0, kinect_sensors=("KINECTNODE4",), kinect_good_frames=6, kinect_blurred_frames=1,
            kinect_cut_off_frames=0))
    return root, load_bundle(root / "ground_truth")
