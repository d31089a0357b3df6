"""Issue 50: the one place errors spell a file's values (dome_calib.schema.show) cuts while it spells, and a YAML
file whose aliases expand past what any calibration holds is refused. Before (main at aaf6910): an 836-byte Kalibr
camchain.yaml of nested aliases kept `import --from kalibr` busy past 150 s at 4 GB (json.dumps of 10^9 values,
then cut to 40 characters)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from dome_calib.schema import MAX_EXPANDED_VALUES, InputFileError, refuse_alias_bombs, show

ROOT = Path(__file__).resolve().parents[1]


def _bomb(levels: int = 9, width: int = 9) -> list:
    value: list = [1] * width
    for _ in range(levels - 1):
        value = [value] * width  # shared, as YAML aliases are
    return value


def _bomb_yaml(field: str) -> str:
    """A camchain.yaml whose ``field`` of cam0 is 9^9 values written in about 400 bytes of aliases."""
    parts = ["&a [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    prev = "a"
    for name in "bcdefgh":
        parts.append(f"&{name} [" + ", ".join([f"*{prev}"] * 9) + "]")
        prev = name
    parts.append("[" + ", ".join([f"*{prev}"] * 9) + "]")
    fields = {"camera_model": "pinhole", "distortion_model": "radtan", "distortion_coeffs": "[0, 0, 0, 0]",
              "intrinsics": "[500, 500, 320, 240]", "resolution": "[640, 480]"}
    fields[field] = "[" + ", ".join(parts) + "]"
    return "cam0:\n" + "".join(f"  {k}: {v}\n" for k, v in fields.items())


def test_show_spells_only_what_it_shows():
    assert show(_bomb()) == "[[[[[[[[[1, 1, 1, 1, 1, 1, 1, 1, 1], ..."
    assert show("x" * 10**7) == '"' + "x" * 36 + "..."
    assert show(10**5000) == "<an integer of 16610 bits>"
    assert show({"k": [float("nan"), float("inf"), None, True]}) == '{"k": [NaN, Infinity, null, true]}'
    assert show([[[]]]) == "[[[]]]" and show("a\\nb") == '"a\\\\nb"'
    deep: list = []
    for _ in range(100_000):
        deep = [deep]
    assert show(deep) == "[" * 37 + "..."  # no recursion past what is shown


def test_alias_bombs_are_refused_in_bounded_steps():
    with pytest.raises(InputFileError, match="aliases expand to more than"):
        refuse_alias_bombs({"cam0": {"resolution": _bomb()}}, "x.yaml")
    big_but_real = {"cam0": {"intrinsics": list(range(MAX_EXPANDED_VALUES - 10))}}
    assert refuse_alias_bombs(big_but_real, "x.yaml") is big_but_real


@pytest.mark.parametrize("field", ["resolution", "camera_model"])
def test_a_kalibr_alias_bomb_is_one_line_in_seconds(field, tmp_path):
    """In a subprocess with a 60 s limit (main: past 150 s at 4 GB for the bad `resolution`)."""
    (tmp_path / "camchain.yaml").write_text(_bomb_yaml(field))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = "import sys; from dome_calib.cli import main; sys.argv[0] = 'dome-calib'; main()"
    out = subprocess.run([sys.executable, "-c", cmd, "import", str(tmp_path / "camchain.yaml"), "--from", "kalibr",
                          "-o", str(tmp_path / "b")], capture_output=True, text=True, env=env, timeout=60)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 1 and len(lines) == 1, out.stderr[-2000:]
    assert "camchain.yaml: its aliases expand to more than 1,000,000 values" in lines[0]
    assert not (tmp_path / "b").exists()
