"""`dome-calib info` and the CLI error path, run as a technician would."""
from __future__ import annotations

import json
import re
import shutil

from .conftest import REAL_CALIBRATION



def test_help_lists_commands(dome_calib_cli):
    out = dome_calib_cli("--help")
    assert out.returncode == 0
    assert "info" in out.stdout


def test_info_summarises_real_bundle(tmp_path, dome_calib_cli):
    shutil.copy(REAL_CALIBRATION, tmp_path / "calibration_160906_band1.json")
    out = dome_calib_cli("info", str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert "520 cameras" in out.stdout
    assert re.search(r"vga +479 cameras +640x480", out.stdout)
    out = dome_calib_cli("info", str(tmp_path), "--json")
    summary = json.loads(out.stdout)
    assert summary["types"]["hd"]["count"] == 31
    assert summary["types"]["kinect-color"]["count"] == 10
    assert -350 < summary["types"]["vga"]["center_cm_min"][1] < summary["types"]["vga"]["center_cm_max"][1] < 0


def test_info_bad_input_is_one_line_and_nonzero(tmp_path, dome_calib_cli):
    data = json.loads(REAL_CALIBRATION.read_text())
    data["cameras"][4]["R"] = [[1, 0, 0], [0, 1, 0]]
    (tmp_path / "calibration_x.json").write_text(json.dumps(data))
    out = dome_calib_cli("info", str(tmp_path))
    assert out.returncode == 1
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert "camera 01_05: cameras[4].R: expected a 3 x 3 rotation" in lines[0]
    assert "Traceback" not in out.stderr
    out = dome_calib_cli("info", str(tmp_path / "missing"))
    assert out.returncode == 1 and "not a folder" in out.stderr
