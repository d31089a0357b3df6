"""Shared fixtures: the real Panoptic calibration (copied into tests/data, see PROVENANCE.md)."""
from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"
REAL_CALIBRATION = DATA / "panoptic" / "calibration_160906_band1.json"
REAL_KCALIBRATION = DATA / "panoptic" / "kcalibration_171026_cello3.json"


@pytest.fixture(scope="session")
def real_cameras():
    """The 520 cameras of the real file, keyed by name."""
    from dome_calib.panoptic_io import read_calibration

    cameras, _ = read_calibration(REAL_CALIBRATION)
    return cameras
