"""Atomic file and folder writing: a reader never sees a half-written output.

This is the mechanism; whether a command may replace what is at an output path (only what dome-calib wrote; no
link; no input) is decided by :mod:`dome_calib.ownership`, which every command's outputs go through. The
mechanism itself: a symlink is followed, so the file it points to is replaced atomically and the link stays (a
dangling link gets its target created); a folder, FIFO, device or socket where a file is to be written is refused
in one line before anything is written; a replaced file keeps its permission bits, a new file or folder gets the
ones ``open()`` / ``mkdir()`` would give (0666 / 0777 less the umask).

A folder replaced whole (:func:`atomic_folder`) is staged beside it under a name that says whose it is
(``.<name>.new.<host>.<boot>.<pid>.<start>.<random>``: this machine, its boot, the process and the process's start
time). A run stopped where no handler runs (SIGKILL, a power cut) leaves it behind; the next run that writes the
same folder removes the ones it can prove are dead (same machine, and another boot, or no such process now, or
a process of that id started at another time) and leaves the others (another machine's, a live run's).

A path reaches the user only at its final place (:mod:`dome_calib.final_place`): every staging place made here
(:func:`atomic_path`'s temporary file, :func:`atomic_folder`'s folder) is recorded with the place it is renamed to
when it is made, so that the commands say it there.
"""
from __future__ import annotations

import contextlib
import glob
import hashlib
import logging
import os
import re
import shutil
import socket
import stat
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from dome_calib.errors import DomeCalibError
from dome_calib.final_place import stage

logger = logging.getLogger(__name__)


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
def atomic_path(path: str | os.PathLike[str], *, before_rename: Callable[[], object] | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``, on error delete it.

    ``path`` may be a symlink (the file it points to is replaced); a folder, FIFO or device is refused first.
    ``before_rename``: called just before the rename (a last check; an error there leaves ``path`` as it was).
    Whether a command may replace what is at ``path`` is :mod:`dome_calib.ownership`'s to decide.

    Example:
        with atomic_path("out/cal.json") as tmp:
            tmp.write_text(text)
    """
    target = output_file(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    mode = stat.S_IMODE(target.stat().st_mode) if target.exists() else new_mode(0o666)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = stage(tmp_name, target)
    try:
        yield tmp
        os.chmod(tmp, mode)  # mkstemp makes 0600; give the file the permissions open() would (or it had)
        output_file(target)  # still a file (or absent) at the moment of the rename
        if before_rename is not None:
            before_rename()
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip().replace("-", "")[:8]
    except OSError:
        return ""


def _start_ticks(pid: int) -> int | None:
    """When process ``pid`` started (clock ticks since boot, /proc/PID/stat field 22); None if there is none."""
    try:
        stat_line = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(stat_line[stat_line.rindex(")") + 2:].split()[19])


def _host() -> str:
    return hashlib.sha256(socket.gethostname().encode()).hexdigest()[:8]


def _owner_tag() -> str | None:
    """``<host>.<boot>.<pid>.<start>`` of this process; None where the system cannot tell (no /proc)."""
    boot, start = _boot_id(), _start_ticks(os.getpid())
    return None if not boot or start is None else f"{_host()}.{boot}.{os.getpid()}.{start}"


#: An owner tag in a name: host, boot, pid, start (:func:`_owner_tag`).
_TAG = r"([0-9a-f]{8})\.([0-9a-f]{8})\.(\d+)\.(\d+)"


def _owner_gone(host: str, boot: str, pid: int, start: int) -> bool:
    """Whether the run an owner tag names is provably over: this machine's (host name), and another boot, or no
    process of that id, or one started at another time. Another machine's run, or a live one, is not."""
    return host == _host() and not (boot == _boot_id() and _start_ticks(pid) == start)


def _staging_name(target: Path, role: str) -> str:
    tag = _owner_tag()
    return f".{target.name}.{role}." + (f"{tag}." if tag else "")


def remove_stale_staging(path: str | os.PathLike[str]) -> list[Path]:
    """Remove the staging (and set-aside) folders that earlier runs writing ``path`` with :func:`atomic_folder` left
    behind when they were killed, where this process can prove their owner is dead: same machine (host name), and
    another boot, or no process of that id, or one started at another time. Another machine's, or a live run's,
    are left alone. A set-aside previous folder is put back where ``path`` is missing (a kill between the two
    renames). Returns the folders removed."""
    target = Path(os.path.abspath(path))
    pattern = re.compile(rf"\.{re.escape(target.name)}\.(new|old)\.{_TAG}\.\w+")
    if not _boot_id() or not target.parent.is_dir():
        return []
    removed = []
    for entry in sorted(target.parent.iterdir()):
        m = pattern.fullmatch(entry.name)
        if m is None or not entry.is_dir() or entry.is_symlink():
            continue
        pid, start = int(m.group(4)), int(m.group(5))
        if not _owner_gone(m.group(2), m.group(3), pid, start):
            continue  # another machine's, or its run is alive (this one, or another writing the same folder now)
        if m.group(1) == "old" and not target.exists() and (entry / target.name).is_dir():
            (entry / target.name).replace(target)
            logger.warning("%s: put back the previous output, set aside by a run (pid %d) stopped mid-replacement",
                           target, pid)
        shutil.rmtree(entry, ignore_errors=True)
        logger.warning("%s: removed %s, left by an earlier run (pid %d) stopped while writing", target, entry.name,
                       pid)
        removed.append(entry)
    return removed


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike[str], *,
                  before_swap: Callable[[], object] | None = None) -> Iterator[Path]:
    """Yield an empty staging folder beside ``path``; on success it replaces ``path`` as a whole (renames only, the
    old folder removed after), on error it is deleted and ``path`` is untouched. Staging folders that killed runs
    left beside ``path`` are removed first (:func:`remove_stale_staging`). ``before_swap``: called just before the
    swap (a last check; an error there leaves ``path`` as it was). Whether a command may replace ``path`` is
    :mod:`dome_calib.ownership`'s to decide."""
    target = output_folder(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(target)
    staging = stage(tempfile.mkdtemp(prefix=_staging_name(target, "new"), dir=target.parent), target)
    old = None
    try:
        os.chmod(staging, new_mode(0o777))  # mkdtemp makes 0700
        yield staging
        if before_swap is not None:
            before_swap()
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=_staging_name(target, "old"), dir=target.parent))
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


@contextlib.contextmanager
def run_temp_folder(prefix: str, parent: str | os.PathLike[str] | None = None) -> Iterator[Path]:
    """A folder of this run's own in ``parent`` (default: the system's temporary folder), named ``prefix`` and
    this process's owner tag, removed when the run ends (also on an interrupt). Folders of the same ``prefix`` whose
    run is provably over (:func:`_owner_gone`: killed before it could remove its own) are removed first."""
    parent = Path(parent if parent is not None else tempfile.gettempdir())
    if _boot_id():
        pattern = re.compile(rf"{re.escape(prefix)}{_TAG}\.\w+")
        for entry in sorted(parent.glob(glob.escape(prefix) + "*")):
            m = pattern.fullmatch(entry.name)
            if m and entry.is_dir() and not entry.is_symlink() and _owner_gone(m.group(1), m.group(2),
                                                                                int(m.group(3)), int(m.group(4))):
                shutil.rmtree(entry, ignore_errors=True)
                logger.info("removed %s, left by an earlier run (pid %s) that was stopped", entry, m.group(3))
    tag = _owner_tag()
    folder = Path(tempfile.mkdtemp(prefix=prefix + (f"{tag}." if tag else ""), dir=parent))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


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


def refuse_output_inside_inputs(output: str | os.PathLike[str], inputs: Iterable[str | os.PathLike[str]], *,
                                option: str = "-o") -> None:
    """OutputPathError when the output (a folder, existing or not) would lie inside an input folder, by any path
    (compared after resolving links, ``.`` and ``..``): a later run would read it back as input."""
    out_real = Path(os.path.realpath(output))
    for given in inputs:
        real = Path(os.path.realpath(given))
        if real.is_dir() and out_real != real and out_real.is_relative_to(real):
            raise OutputPathError(f"{option} {out_real}: inside the input folder {real}; a later run would read it as "
                                  "input: give an output folder outside it")


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
