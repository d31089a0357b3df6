"""SIGKILL `dome-calib calibrate` at random moments of a real run on the tiny synthetic dome (bench/kill.py with 3
kills over whole runs, then 2 over the bundle adjustment, world frame and write; the bench runs 20 + 10): the
output folder always loads, old or new bundle, and a rerun completes with the cameras of an uninterrupted run.
About two minutes: marked slow (`pytest -m slow`)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench" / "kill.py"

#: A resumed run matches an uninterrupted one closely, not bit for bit: COLMAP's mapping is multi-threaded and a
#: database filled over several killed runs may list the images in another order (bench/kill.py, 30 kills:
#: 0.011 mm and 0.0004 deg at most; another run: 1e-11). Far below the calibration's own error (~0.8 mm, 0.09 deg).
MAX_CENTER_DIFF_MM = 0.2
MAX_ROTATION_DIFF_DEG = 0.01


@pytest.mark.slow
def test_sigkill_at_random_moments_leaves_a_loadable_bundle_and_a_rerun_completes(tmp_path):
    spec = importlib.util.spec_from_file_location("bench_kill", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    summary = bench.main(["--kills", "3", "--late-kills", "2", "--seed", "1", "--work", str(tmp_path)])
    assert summary["unloadable"] == 0 and summary["late_phase"]["unloadable"] == 0, summary
    assert summary["old"] + summary["new"] + summary["finished"] == 3, summary
    assert summary["rerun_rc"] == 0, summary
    same = summary["vs_uninterrupted"]
    assert same["same_names"], summary
    assert same["center_mm_max"] < MAX_CENTER_DIFF_MM and same["rotation_deg_max"] < MAX_ROTATION_DIFF_DEG
