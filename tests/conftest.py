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


@pytest.fixture
def dome_calib_cli(monkeypatch, capsys):
    """Run ``dome-calib ARGS`` in this process through ``run_cli`` (as the installed command does): the
    one-line errors and exit codes are the command's own, without a second Python starting (~1.5 s each).
    Returns a ``subprocess.CompletedProcess`` (returncode, stdout, stderr)."""
    import subprocess
    import sys

    from dome_calib.cli import main

    def run(*args: str) -> subprocess.CompletedProcess:
        monkeypatch.setattr(sys, "argv", ["dome-calib", *map(str, args)])
        capsys.readouterr()
        code = 0
        try:
            main()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        out = capsys.readouterr()
        return subprocess.CompletedProcess(["dome-calib", *args], code, out.out, out.err)

    return run
