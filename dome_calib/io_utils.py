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
from collections.abc import Iterable, Iterator
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
        check_writable(target)
        return target
    if not stat.S_ISREG(mode):
        raise OutputPathError(f"{given}: is {_kind(mode)}, not a file; outputs are written whole and renamed into "
                              "place, so give a file path")
    check_writable(target)
    return target


def output_folder(path: str | os.PathLike[str]) -> Path:
    """The folder that writing ``path`` as a whole replaces (symlinks followed); refused if it is not a folder."""
    given = Path(path)
    target = Path(os.path.realpath(given)) if given.is_symlink() else given
    try:
        mode = target.stat().st_mode
    except FileNotFoundError:
        check_writable(target)
        return target
    if not stat.S_ISDIR(mode):
        raise OutputPathError(f"{given}: is {_kind(mode) if not stat.S_ISREG(mode) else 'a file'}, not a folder")
    check_writable(target)
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


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): not the same file
        return False


def refuse_output_among_inputs(output: str | os.PathLike[str], inputs: Iterable[str | os.PathLike[str]], *,
                               option: str = "-o", whole_folder: bool = False) -> None:
    """OutputPathError when the output is one of the inputs (the same file or folder by any path, hard or symbolic
    link: compared by device and inode), or, for an output folder replaced whole (``whole_folder``), one that holds
    an input. Call it before anything is read or written."""
    out = Path(output)
    if not out.exists():
        return
    out_real = Path(os.path.realpath(out))
    for given in inputs:
        given = Path(given)
        if _same(out, given):
            raise OutputPathError(f"{option} {out}: is the input {given} (the same file); writing the output would "
                                  "destroy it: give another output path")
        if whole_folder and out.is_dir() and Path(os.path.realpath(given)).is_relative_to(out_real):
            raise OutputPathError(f"{option} {out}: holds the input {given}; writing the output would replace it: "
                                  "give another output folder")


def check_writable(path: str | os.PathLike[str], *, into: bool = False) -> None:
    """OutputPathError when the output ``path`` cannot be written, checked before any work: nothing can be created
    in the folder it goes in (its nearest existing ancestor; ``into``: ``path`` itself when it is a folder that
    files are written into), because the folder or its file system is read-only or not ours. Probed by creating
    and removing a temporary folder there, so it holds for root and for read-only mounts alike."""
    given = Path(path)
    folder = Path(os.path.abspath(given))
    if not (into and folder.is_dir()):
        folder = folder.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        probe = tempfile.mkdtemp(prefix=".write-probe.", dir=folder)
    except OSError as exc:
        raise OutputPathError(f"{given}: cannot write in {folder} ({exc.strerror or exc}); give an output in a "
                              "folder you can write to") from None
    os.rmdir(probe)
