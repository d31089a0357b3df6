"""Shared fixtures: the real Panoptic calibration (copied into tests/data, see PROVENANCE.md)."""
from __future__ import annotations

import fcntl
import os
import pickle
from pathlib import Path
from typing import Callable, TypeVar

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

T = TypeVar("T")


def built_once(tmp_path_factory, name: str, build: Callable[[Path], T]) -> T:
    """``build(folder)``'s value, built by one process of the run: a session fixture's read-only inputs, which
    every pytest-xdist worker would otherwise build again (``--dist loadfile`` gives the files using it to both).
    The first worker to take the lock builds into ``folder`` (in the run's own temporary folder, which its workers
    share) and keeps the value (pickled) beside it; the others wait, then read it. A failed build leaves nothing
    and the next worker tries again. Without xdist, a folder of this session."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the controller's basetemp: popen-gw0, popen-gw1, ... are in it
    folder, value = root / f"built-{name}", root / f"built-{name}.pickle"
    with open(root / f"built-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not value.exists():
            folder.mkdir()
            try:
                built = build(folder)
            except BaseException:
                import shutil

                shutil.rmtree(folder, ignore_errors=True)
                raise
            staged = value.with_suffix(".staged")
            staged.write_bytes(pickle.dumps(built))
            staged.rename(value)
            return built
    return pickle.loads(value.read_bytes())


#: The nine cameras of the SfM tests' rendered capture: one HD (00_00) and eight VGA around the tent.
SFM_CAMERAS = ["00_00", "01_01", "01_02", "01_03", "01_04", "01_05", "01_06", "01_11", "01_12"]
SFM_SEED = 1


@pytest.fixture(scope="session")
def sfm_capture(tmp_path_factory) -> Path:
    """A rendered capture of SFM_CAMERAS, 2 scenes (the full preset, seed SFM_SEED), built once per run
    (``built_once``): test_sfm and test_sfm_known each copy it and break or remove images in their copy;
    test_synth_cli renders two of its cameras again (the same bytes in one process as in its 2-worker build)."""
    from dome_calib.synth.capture import SynthOptions, synthesize

    def build(folder: Path) -> Path:
        synthesize(folder / "capture", SynthOptions(preset="full", n_scenes=2, seed=SFM_SEED, cameras=SFM_CAMERAS,
                                                    workers=2))
        return folder / "capture"

    return built_once(tmp_path_factory, "sfm_capture", build)


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
    Built once per run (``built_once``): read it, never write into it. Returns (session folder, ground-truth
    bundle)."""
    import dome_calib.synth.session as synth_session
    from dome_calib.bundle_io import load_bundle

    def build(folder: Path) -> Path:
        root = folder / "sess"
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(synth_session, "write_capture", stub_capture)
            synth_session.make_product_session(root, synth_session.SessionOptions(
                duration_s=3.0, kinect_sensors=("KINECTNODE4",), kinect_good_frames=6, kinect_blurred_frames=1,
                kinect_cut_off_frames=0))
        return root

    root = built_once(tmp_path_factory, "product", build)
    return root, load_bundle(root / "ground_truth")
