"""`dome-calib synth`: the capture folder contract, determinism, atomic output and one-line errors."""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from dome_calib.bundle_io import load_bundle
from dome_calib.cli import app
from dome_calib.ownership import NotOursError
from dome_calib.synth.capture import SynthOptions, synthesize
from dome_calib.layout import nominal_dome

from .conftest import SFM_CAMERAS, SFM_SEED

REAL = Path(__file__).parent / "data" / "panoptic" / "calibration_160906_band1.json"


def test_synth_cli_writes_contract_folder(tmp_path):
    out = tmp_path / "cap"
    result = CliRunner().invoke(app, ["synth", str(out), "--preset", "tiny", "--scenes", "2", "--seed", "4",
                                      "--cameras", "01_01,01_02", "--workers", "1"])
    assert result.exit_code == 0, result.output
    meta = json.loads((out / "capture.json").read_text())
    assert meta["scenes"] == ["scene_01", "scene_02"] and meta["cameras"] == ["01_01", "01_02"]
    assert meta["preset"] == "tiny" and meta["seed"] == 4 and meta["generator_version"]
    for scene in meta["scenes"]:
        for cam in meta["cameras"]:
            img = cv2.imread(str(out / "scenes" / scene / f"{cam}.png"), cv2.IMREAD_UNCHANGED)
            assert img.shape == (480, 640) and img.dtype == np.uint8
        tent = np.load(out / "ground_truth" / f"tent_{scene}.npz")
        assert tent["vertices_cm"].shape[1] == 3 and tent["faces"].shape[1] == 3
    gt = load_bundle(out / "ground_truth")
    truth = nominal_dome("tiny", seed=4).cameras["01_01"]
    np.testing.assert_allclose(gt.cameras["01_01"].K, truth.K, atol=1e-6)
    np.testing.assert_allclose(gt.cameras["01_01"].R, truth.R, atol=1e-9)
    assert not list(tmp_path.glob(".cap.tmp-*"))  # nothing left behind


def test_synth_deterministic_serial_equals_parallel_and_seeded(tmp_path, sfm_capture):
    """The parallel run is conftest's shared SfM capture (2 workers, nine cameras, two scenes, seed SFM_SEED):
    two of its cameras rendered again in this process, alone and with one scene, are the same bytes; another
    seed gives other images."""
    names = ["01_01", "01_04"]

    def run(name, seed):
        synthesize(tmp_path / name, SynthOptions(preset="full", n_scenes=1, seed=seed, cameras=names, workers=1))
        return [(tmp_path / name / "scenes" / "scene_01" / f"{n}.png").read_bytes() for n in names]

    assert sorted(json.loads((sfm_capture / "capture.json").read_text())["cameras"]) == SFM_CAMERAS
    serial = run("serial", SFM_SEED)
    assert serial == [(sfm_capture / "scenes" / "scene_01" / f"{n}.png").read_bytes() for n in names]
    assert run("other_seed", SFM_SEED + 1) != serial


def test_synth_from_real_layout(tmp_path):
    out = tmp_path / "real"
    synthesize(out, SynthOptions(preset="full", n_scenes=1, layout=REAL, cameras=["01_19"], workers=1))
    gt = load_bundle(out / "ground_truth")
    assert list(gt.cameras) == ["01_19"]
    img = cv2.imread(str(out / "scenes/scene_01/01_19.png"), cv2.IMREAD_GRAYSCALE)
    assert img[150:350, 200:450].std() > 20  # the tent is in view of a real camera


def test_synth_cli_errors_are_one_line(tmp_path, dome_calib_cli):
    for args, needle in (
        (["synth", str(tmp_path / "x"), "--preset", "huge"], "--preset huge"),
        (["synth", str(tmp_path / "x"), "--scenes", "0"], "--scenes 0"),
        (["synth", str(tmp_path / "x"), "--cameras", "99_99"], "camera 99_99"),
        (["synth", str(tmp_path / "x"), "--layout", str(tmp_path / "missing.json")], "missing.json"),
    ):
        r = dome_calib_cli(*args)
        assert r.returncode == 1, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0] and lines[0].startswith("dome-calib: error:"), r.stderr
    (tmp_path / "exists").mkdir()
    r = dome_calib_cli("synth", tmp_path / "exists")
    assert r.returncode == 1 and "already exists" in r.stderr


def test_synth_overwrite_replaces_its_own_capture_only(tmp_path):
    out = tmp_path / "cap"
    options = SynthOptions(preset="tiny", n_scenes=1, cameras=["01_01"], workers=1, overwrite=True)
    synthesize(out, options)
    synthesize(out, options)  # a capture synth wrote is replaced
    assert (out / "capture.json").exists()
    (out / "old.txt").write_text("old")  # someone else's file in it: refused, nothing lost
    with pytest.raises(NotOursError, match="old.txt"):
        synthesize(out, options)
    assert (out / "old.txt").read_text() == "old" and (out / "capture.json").exists()
