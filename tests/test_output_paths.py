"""Issue 15, outputs: writing through atomic replace refuses a FIFO, device or folder target in one line before
writing, follows a symlink (the file it points to is replaced, the link stays), keeps a replaced file's
permissions; folders we create (report/, a staged output folder) get the umask-derived mode, not mkdtemp's 0700."""
from __future__ import annotations

import os
import socket
import stat

import pytest

from dome_calib.errors import DomeCalibError
from dome_calib.io_utils import atomic_folder, atomic_write_text, output_file


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.mark.parametrize("kind", ["fifo", "folder", "socket"])
def test_special_target_is_refused_in_one_line_and_left_alone(tmp_path, kind):
    target = tmp_path / "out.json"
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "folder":
        target.mkdir()
    else:
        with socket.socket(socket.AF_UNIX) as server:
            server.bind(str(target))  # the socket file stays after close
    with pytest.raises(DomeCalibError) as err:
        atomic_write_text(target, "{}")
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{target}: is a") and "not a file" in message
    assert stat.S_ISREG(os.lstat(target).st_mode) is False  # left as it was
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]  # no temporary file left


def test_device_target_is_refused_before_writing():
    # Only the check is called: a write through a regressed atomic replace would put a file in place of the device.
    with pytest.raises(DomeCalibError, match="/dev/null: is a character device, not a file"):
        output_file("/dev/null")


def test_symlink_target_is_followed_and_kept(tmp_path):
    real = tmp_path / "versions" / "cal_v2.json"
    real.parent.mkdir()
    real.write_text("old")
    os.chmod(real, 0o640)
    link = tmp_path / "current.json"
    link.symlink_to(real)
    atomic_write_text(link, "new")
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert real.read_text() == "new" and stat.S_IMODE(real.stat().st_mode) == 0o640  # replaced file keeps its mode
    dangling = tmp_path / "next.json"
    dangling.symlink_to(tmp_path / "versions" / "cal_v3.json")
    atomic_write_text(dangling, "v3")
    assert dangling.is_symlink() and (tmp_path / "versions" / "cal_v3.json").read_text() == "v3"
    assert stat.S_IMODE((tmp_path / "versions" / "cal_v3.json").stat().st_mode) == 0o666 & ~_umask()
    assert sorted(p.name for p in (tmp_path / "versions").iterdir()) == ["cal_v2.json", "cal_v3.json"]


def test_symlink_loop_is_refused(tmp_path):
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    with pytest.raises(DomeCalibError, match="a symlink that does not resolve"):
        atomic_write_text(tmp_path / "a", "{}")


def test_atomic_folder_mode_and_whole_replacement(tmp_path):
    target = tmp_path / "out"
    with atomic_folder(target) as staging:
        (staging / "a.json").write_text("1")
        (staging / "b.json").write_text("1")
    assert stat.S_IMODE(target.stat().st_mode) == 0o777 & ~_umask()
    with atomic_folder(target) as staging:
        (staging / "a.json").write_text("2")
    assert sorted(p.name for p in target.iterdir()) == ["a.json"] and (target / "a.json").read_text() == "2"
    with pytest.raises(RuntimeError):
        with atomic_folder(target) as staging:
            (staging / "c.json").write_text("half")
            raise RuntimeError("stop")
    assert sorted(p.name for p in target.iterdir()) == ["a.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging or old folder left


def test_report_folder_has_the_normal_mode(tmp_path):
    from dome_calib.report import write_report
    from dome_calib.report.build import ReportOptions
    from dome_calib.layout import nominal_dome

    bundle = nominal_dome("tiny", seed=0)
    report = write_report(tmp_path, bundle, None, ReportOptions(plots=False))
    assert stat.S_IMODE(report.stat().st_mode) == 0o777 & ~_umask()  # was 0700 from mkdtemp
