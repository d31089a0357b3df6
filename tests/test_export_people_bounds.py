"""Issue 50, export-people's numbers and sizes, and what C++ writers leave on a full disk. Before (main at aaf6910):
a rate measured as 0 gave "0 fps" in TRC, a C++ abort in C3D, ZeroDivisionError in BVH; `--fps 1e400`
OverflowError; frame numbers 0 and 999999999999 a MemoryError, a 20-digit frame an OverflowError; two files for one
frame merged in silence; 14 people made a C3D ezc3d refuses (DESCRIPTIONS past 255 with a one-byte count), 4,000
people took > 300 s; a full disk left a cut C3D or COLMAP model with exit 0; SIGTERM left the staging folder, exit
143, no word. Each is now one line (or a file its readers take), for every format it applies to."""
from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from .skeletons_helpers import c3d_package_read, write_scenes

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-c", "import sys; from dome_calib.cli import main; sys.argv[0] = 'dome-calib'; main()"]
FORMATS = ["trc", "c3d", "bvh"]


def _body(rng, centre=(0.0, -90.0, 0.0)) -> np.ndarray:
    return np.concatenate([rng.normal(size=(19, 3)) * 20 + centre, np.full((19, 1), 0.9)], axis=1)


def _scenes(folder: Path, frames, times_ms, n_people: int = 2, fps_type: str = "custom") -> Path:
    rng = np.random.default_rng(0)
    return write_scenes(folder, frames, times_ms, [{p: _body(rng) for p in range(n_people)} for _ in frames],
                        fps_type=fps_type)


def _one_line(out, *named: str) -> str:
    lines = [ln for ln in out.stderr.strip().splitlines() if not ln.startswith("dome-calib: read ")]  # progress log
    assert out.returncode == 1 and len(lines) == 1 and lines[0].startswith("dome-calib: error:"), out.stderr[-3000:]
    assert all(n in lines[0] for n in named), lines[0]
    return lines[0]


def _nothing_left(tmp_path: Path, keep=("people",)) -> None:
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(keep)  # no output, no staging folder


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_rate_measured_as_nothing_asks_for_fps(fmt, dome_calib_cli, tmp_path):
    """Two frames 11.6 days apart (fpsType custom): 1e-6 fps, rounded to 0."""
    people = _scenes(tmp_path / "people", [0, 1], [0.0, 1e9])
    _one_line(dome_calib_cli("export-people", str(people), "--to", fmt, "-o", str(tmp_path / "o")),
              "univTime", "give --fps")
    _nothing_left(tmp_path)
    ok = dome_calib_cli("export-people", str(people), "--to", fmt, "-o", str(tmp_path / "o"), "--fps", "25")
    assert ok.returncode == 0, ok.stderr


@pytest.mark.parametrize("fps", ["1e400", "0", "1e-9", "-25", "1/0", "nan"])
def test_an_impossible_fps_is_one_line(fps, dome_calib_cli, tmp_path):
    people = _scenes(tmp_path / "people", [0, 1, 2], [0.0, 40.0, 80.0])
    for fmt in FORMATS:
        _one_line(dome_calib_cli("export-people", str(people), "--to", fmt, "-o", str(tmp_path / "o"), "--fps", fps),
                  "--fps")
    _nothing_left(tmp_path)


@pytest.mark.parametrize("fmt", ["c3d", "bvh"])
def test_frame_numbers_far_apart_are_refused_before_work(fmt, dome_calib_cli, tmp_path):
    """C3D and BVH hold every frame between the first and the last: 0 and 999999999999 asked for 10^12 frames."""
    people = _scenes(tmp_path / "people", [0, 999_999_999_999], [0.0, 40.0], fps_type="vga_25")
    _one_line(dome_calib_cli("export-people", str(people), "--to", fmt, "-o", str(tmp_path / "o")),
              "spans 1000000000000 frame numbers", "--ids")
    _nothing_left(tmp_path)


def test_frame_numbers_far_apart_in_trc(dome_calib_cli, tmp_path):
    """TRC has one row per file: written (OpenSim's Frame# column holds the numbers)."""
    people = _scenes(tmp_path / "people", [0, 999_999_999_999], [0.0, 40.0], fps_type="vga_25")
    out = dome_calib_cli("export-people", str(people), "--to", "trc", "-o", str(tmp_path / "o"))
    assert out.returncode == 0, out.stderr
    (trc,) = (tmp_path / "o").glob("*_P0_*.trc")  # Pose2Sim's multi-person name: <trial>_P0_<first>-<last>.trc
    rows = trc.read_text().splitlines()[5:]
    assert [r.split("\t")[0] for r in rows] == ["0", "999999999999"]  # Frame#: the files' own frame numbers


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_frame_number_of_20_digits_is_one_line(fmt, dome_calib_cli, tmp_path):
    people = _scenes(tmp_path / "people", [0, 1], [0.0, 40.0], fps_type="vga_25")
    (people / "body3DScene_00000000000000000000123.json").write_text(
        (people / "body3DScene_00000001.json").read_text().replace('"univTime": 40.0', '"univTime": 80.0'))
    (people / "body3DScene_12345678901234567890.json").write_text(
        (people / "body3DScene_00000001.json").read_text().replace('"univTime": 40.0', '"univTime": 90.0'))
    _one_line(dome_calib_cli("export-people", str(people), "--to", fmt, "-o", str(tmp_path / "o")),
              "body3DScene_12345678901234567890.json", "frame number")
    _nothing_left(tmp_path)


@pytest.mark.parametrize("fmt", FORMATS)
def test_two_files_for_one_frame_are_refused_naming_both(fmt, dome_calib_cli, tmp_path):
    people = _scenes(tmp_path / "people", [0, 1, 2], [0.0, 40.0, 80.0], fps_type="vga_25")
    (people / "body3DScene_1.json").write_text((people / "body3DScene_00000001.json").read_text())
    line = _one_line(dome_calib_cli("export-people", str(people), "--to", fmt, "-o", str(tmp_path / "o")),
                     "frame 1", "body3DScene_1.json", "body3DScene_00000001.json")
    assert "one file per frame" in line
    _nothing_left(tmp_path)


def test_c3d_of_14_and_215_people_is_read_by_ezc3d_and_the_c3d_package(dome_calib_cli, tmp_path):
    """Past 255 points the labels go on in LABELS2, ... (C3D's one-byte item count), as ezc3d and Vicon split them."""
    import ezc3d

    for n in (14, 215):
        people = _scenes(tmp_path / f"p{n}", [5, 6, 7], [0.0, 40.0, 80.0], n_people=n, fps_type="vga_25")
        out = dome_calib_cli("export-people", str(people), "--to", "c3d", "-o", str(tmp_path / f"o{n}"))
        assert out.returncode == 0, out.stderr
        path = tmp_path / f"o{n}" / "people.c3d"
        c = ezc3d.c3d(str(path))
        point = c["parameters"]["POINT"]
        labels = [lab for k in ["", *range(2, 20)] if f"LABELS{k}" in point for lab in point[f"LABELS{k}"]["value"]]
        assert labels[0] == "P0:Neck" and labels[-1] == f"P{n - 1}:REar" and len(labels) == 19 * n
        assert c["data"]["points"].shape == (4, 19 * n, 3)
        pkg = c3d_package_read(path)
        assert pkg["X"].shape == (3, 19 * n, 3) and pkg["labels"][:255] == labels[:255]


@pytest.mark.parametrize("n", [216, 4000])
def test_c3d_past_what_readers_take_is_refused_before_work(n, dome_calib_cli, tmp_path):
    """4,000 people took > 300 s in ezc3d's label lookups before its file was refused by every reader; now refused
    before any writing, naming the limit and the remedy (2.5 s on the 2-core machine, the files read)."""
    people = _scenes(tmp_path / "people", [5, 6], [0.0, 40.0], n_people=n, fps_type="vga_25")
    _one_line(dome_calib_cli("export-people", str(people), "--to", "c3d", "-o", str(tmp_path / "o")),
              f"{n} people x 19 joints", "4095", "--ids")
    _nothing_left(tmp_path)


# ---- what a full disk leaves: the C++ writers (ezc3d, pycolmap) do not report a failed write -------------------

def _cut_writes(limit_bytes: int):
    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return limit


def _cli(args: list[str], limit_bytes: int) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([*CLI, *args], capture_output=True, text=True, env=env,
                          preexec_fn=_cut_writes(limit_bytes), timeout=300)


def test_a_cut_c3d_is_an_error_not_exit_0(tmp_path):
    people = _scenes(tmp_path / "people", range(100), np.arange(100) * 40.0, n_people=7, fps_type="vga_25")
    out = _cli(["export-people", str(people), "--to", "c3d", "-o", str(tmp_path / "o")], 40_000)  # of 213 kB
    _one_line(out, "people.c3d", "written cut", "disk full")
    _nothing_left(tmp_path)


def test_a_cut_colmap_model_is_an_error_not_exit_0(tmp_path):
    from dome_calib.bundle_io import write_bundle
    from dome_calib.layout import nominal_dome

    write_bundle(nominal_dome("tiny", seed=0), tmp_path / "b")
    out = _cli(["export", str(tmp_path / "b"), "--to", "colmap", "-o", str(tmp_path / "m")], 1_000)
    _one_line(out, "does not read back", "disk full")
    _nothing_left(tmp_path, keep=("b",))


def test_sigterm_during_export_people_cleans_up_and_says_one_line(tmp_path):
    """Before: the hidden staging folder with its files stayed, exit 143, no message."""
    people = _scenes(tmp_path / "people", range(20), np.arange(20) * 40.0, n_people=700, fps_type="vga_25")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([*CLI, "export-people", str(people), "--to", "bvh",
                             "-o", str(tmp_path / "o")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:  # until the staging folder holds 20 files
        staging = [p for p in tmp_path.iterdir() if p.name.startswith(".o.")]
        if staging and len(list(staging[0].iterdir())) >= 20:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGSTOP)  # frozen where it stands: the check below and the SIGTERM see the same moment
    staged = [p for p in tmp_path.iterdir() if p.name.startswith(".o.")]
    assert proc.poll() is None and staged, f"the export ended before it could be stopped: {proc.communicate()}"
    proc.send_signal(signal.SIGTERM)  # pending until it runs again (before: sent between two polls, it could land
    proc.send_signal(signal.SIGCONT)  # after the export had finished, exit 0 on a fast machine)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-2000:]
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("dome-calib: read ")]  # progress log
    assert len(lines) == 1 and lines[0].startswith("dome-calib: interrupted"), err
    _nothing_left(tmp_path)
