"""Issue 37: `calibrate --prior --only-changed` with a prior that no longer holds (every camera moved 2 cm, another
dome's calibration) says "run a full calibration" in one line instead of a bundle worse than its prior or a pycolmap
ValueError. Synthetic scene databases of tests/test_quick_recalibration.py: no images, seconds per test."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import dome_calib.pipeline.full as pipeline
import dome_calib.pipeline.quick as quick
from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.errors import DomeCalibError
from dome_calib.layout import nominal_dome

from .test_quick_recalibration import CAMERAS, _matched_scene, _neighbourhood


def _all_moved(prior: Bundle, cm: float, seed: int = 0) -> Bundle:
    """Every camera moved ``cm`` in a random direction (its orientation kept)."""
    rng = np.random.default_rng(seed)
    now = {}
    for n, c in prior.cameras.items():
        d = rng.normal(size=3)
        now[n] = dataclasses.replace(c, t_cm=-c.R @ (c.center_cm + cm * d / np.linalg.norm(d)))
    return Bundle(seq="now", cameras=now)


def _another_dome() -> Bundle:
    """The same camera names on another dome: the nominal dome of another seed (its own mounting jitter)."""
    other = nominal_dome("full", seed=7)
    return Bundle(seq="other", cameras={n: other.cameras[n] for n in CAMERAS})


@pytest.mark.parametrize("case", ["every camera moved 2 cm", "another dome's prior"])
def test_a_prior_that_no_longer_holds_says_run_a_full_calibration(tmp_path, case):
    truth = _neighbourhood()
    if case == "every camera moved 2 cm":
        prior, current = truth, _all_moved(truth, 2.0)
    else:
        prior, current = _another_dome(), truth
    matched = _matched_scene(tmp_path, current, prior, seed=5)
    det = quick.detect_suspects(matched, prior)
    with pytest.raises(quick.PriorNoLongerHolds, match="no longer holds .*run a full calibration"):
        quick.check_prior_holds(det, "old_bundle", len(matched.cameras))


def test_a_prior_that_holds_passes_the_check(tmp_path):
    prior = _neighbourhood()
    matched = _matched_scene(tmp_path, _all_moved(prior, 0.0), prior, seed=5)
    det = quick.detect_suspects(matched, prior)
    quick.check_prior_holds(det, "old_bundle", len(matched.cameras))  # nothing moved
    assert det.held_pair_px < 0.5 and det.held_cameras == len(CAMERAS)


def test_only_changed_with_a_stale_prior_is_one_line_and_writes_nothing(tmp_path, monkeypatch, dome_calib_cli):
    truth = _neighbourhood()
    matched = _matched_scene(tmp_path, _all_moved(truth, 2.0), truth, seed=5)
    cap = tmp_path / "capture"
    (cap / "scenes" / "scene_01").mkdir(parents=True)
    (cap / "capture.json").write_text(json.dumps({"scenes": ["scene_01"], "cameras": CAMERAS}))
    monkeypatch.setattr(quick, "match_first_scene", lambda *a, **k: matched)
    prior_dir = write_bundle(truth, tmp_path / "prior")
    done = dome_calib_cli("calibrate", cap, "-o", tmp_path / "out", "--prior", prior_dir, "--only-changed")
    assert done.returncode == 1
    assert done.stderr.startswith(f"dome-calib: error: --prior {prior_dir}: no longer holds for this capture")
    assert done.stderr.strip().endswith("run a full calibration (without --only-changed)")
    assert not (tmp_path / "out").exists()


def test_suspects_without_two_held_partners_are_refused_not_a_pycolmap_error(tmp_path):
    truth = _neighbourhood()
    matched = _matched_scene(tmp_path, truth, truth, seed=5)
    det = quick.Suspects(suspects=sorted(CAMERAS), unknown=[], bad_pair_px=2.0)  # every camera suspect
    with pytest.raises(DomeCalibError, match="0 unchanged camera.*run a full calibration"):
        quick.reestimate(matched, det, truth, tmp_path / "work")
