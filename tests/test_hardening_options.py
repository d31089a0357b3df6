"""Issue 37: `pointcloud`'s default file name is exact (two times, two files), and NaN or infinite numbers in the
options are refused in one line (a `<=` bound check lets NaN through), in every float option of the commands and
of the options objects behind them (every options class: tests/test_options.py)."""
from __future__ import annotations

import pytest


def test_pointcloud_default_names_of_close_times_differ():
    from dome_calib.cli.recon import exact_ms

    assert exact_ms(36001000.0) == "36001000" and exact_ms(36001040.0) == "36001040"
    assert exact_ms(0.5) == "0.5" and exact_ms(36001000.25) == "36001000.25"
    times = [36001000.0 + k * 1000 / 30 for k in range(100)] + [36001040.0, 1e16, 1e16 + 2]
    assert len({exact_ms(t) for t in times}) == len(times)
    for t in times:
        assert float(exact_ms(t)) == t  # the name gives the time back


def test_pointcloud_cli_uses_the_exact_name(tmp_path, dome_calib_cli, monkeypatch):
    import dome_calib.recon.commands as commands

    seen = []

    def fake(bundle, time_ms, depth, out, **kw):
        seen.append(out)
        return commands.PointCloudSummary(out=out, points=0, sensors=[], time_offsets_ms=[])

    monkeypatch.setattr(commands, "pointcloud_file", fake)
    monkeypatch.chdir(tmp_path)
    for t in ("36001000", "36001040"):
        done = dome_calib_cli("pointcloud", "--bundle", tmp_path, "--time-ms", t, "--depth", tmp_path)
        assert done.returncode == 0, done.stderr
    assert [p.name for p in seen] == ["pointcloud_36001000ms.ply", "pointcloud_36001040ms.ply"]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
@pytest.mark.parametrize("command", ["triangulate --threshold-px", "pointcloud --time-ms",
                                     "pointcloud --max-offset-ms", "kinect --square-mm"])
def test_a_non_finite_number_in_an_option_is_one_line(tmp_path, dome_calib_cli, command, value):
    name, option = command.split()
    det = tmp_path / "det.json"
    det.write_text("{}")
    args = {"triangulate": ["triangulate", det, "--bundle", tmp_path, option, value],
            "pointcloud": ["pointcloud", "--bundle", tmp_path, "--depth", tmp_path, "--time-ms", "0", option, value],
            "kinect": ["kinect", tmp_path, "--bundle", tmp_path, option, value]}[name]
    done = dome_calib_cli(*args)
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1 and value.lstrip("-") in done.stderr.lower(), done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.parametrize("value", ["nan", "inf"])
def test_timecode_sync_max_extrapolation_nan_is_refused(tmp_path, value, monkeypatch, capsys):
    from timecode.cli import main

    from .cli_runner import run_in_process

    done = run_in_process(main, "timecode", ["sync", tmp_path, "-o", tmp_path / "b", "--max-extrapolation", value],
                          monkeypatch, capsys)
    assert done.returncode == 1 and "expected a finite number" in done.stderr
