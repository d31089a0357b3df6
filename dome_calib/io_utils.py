"""Atomic file and folder writing: a reader never sees a half-written output.

Output paths (``-o``) follow these rules: a symlink is followed, so the file it points to is replaced atomically
and the link stays (a dangling link gets its target created); a folder, FIFO, device or socket where a file is
to be written is refused in one line before anything is written; a replaced file keeps its permission bits, a
new file or folder gets the ones ``open()`` / ``mkdir()`` would give (0666 / 0777 less the umask).
"""
from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from dome_calib.errors import DomeCalibError


class OutputPathError(DomeCalibError, ValueError):
    """An output path cannot take the output (a folder where a file goes, a FIFO, a device, a symlink loop)."""


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def output_file(path: str | os.PathLike[str]) -> Path:
    """The regular file that writing ``path`` replaces (symlinks followed); OutputPathError if it cannot be one."""
    given = Path(path)
    target = Path(os.path.realpath(given)) if given.is_symlink() else given
    if target.is_symlink():
        raise OutputPathError(f"{given}: a symlink that does not resolve (a loop); remove it or choose another path")
    try:
        mode = target.stat().st_mode
    except FileNotFoundError:
        return target
    if not stat.S_ISREG(mode):
        raise OutputPathError(f"{given}: is {_kind(mode)}, not a file; outputs are written whole and renamed into "
                              "place, so give a file path")
    return target


def output_folder(path: str | os.PathLike[str]) -> Path:
    """The folder that writing ``path`` as a whole replaces (symlinks followed); refused if it is not a folder."""
    given = Path(path)
    target = Path(os.path.realpath(given)) if given.is_symlink() else given
    try:
        mode = target.stat().st_mode
    except FileNotFoundError:
        return target
    if not stat.S_ISDIR(mode):
        raise OutputPathError(f"{given}: is {_kind(mode) if not stat.S_ISREG(mode) else 'a file'}, not a folder")
    return target


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``, on error delete it.

    ``path`` may be a symlink (the file it points to is replaced); a folder, FIFO or device is refused first.

    Example:
        with atomic_path("out/cal.json") as tmp:
            tmp.write_text(text)
    """
    target = output_file(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    mode = stat.S_IMODE(target.stat().st_mode) if target.exists() else new_mode(0o666)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.chmod(tmp, mode)  # mkstemp makes 0600; give the file the permissions open() would (or it had)
        output_file(target)  # still a file (or absent) at the moment of the rename
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield an empty staging folder beside ``path``; on success it replaces ``path`` as a whole (renames only, the
    old folder removed after), on error it is deleted and ``path`` is untouched."""
    target = output_folder(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.new.", dir=target.parent))
    old = None
    try:
        os.chmod(staging, new_mode(0o777))  # mkdtemp makes 0700
        yield staging
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old.", dir=target.parent))
            target.replace(old / target.name)
        staging.replace(target)
    except BaseException:
        if old is not None and not target.exists():  # put the old folder back
            (old / target.name).replace(target)
        shutil.rmtree(staging, ignore_errors=True)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


def new_mode(mode: int) -> int:
    """Permission bits a new file (0o666) or folder (0o777) gets from ``open()`` / ``mkdir()``: less the umask."""
    return mode & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
