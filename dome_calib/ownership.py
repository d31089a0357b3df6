"""Whose file is it: the one place that decides whether a command may replace what is at an output path.

Only what dome-calib wrote is ever replaced, and a record of ours proves it, never a file's name (someone else's
tool may use the same names: the Panoptic dataset's own ``body3DScene_<n>.json``, COLMAP's ``cameras.bin``).

The record is a file named :data:`RECORD` (``.dome-calib-written.json``) in a folder we wrote in: every entry we
wrote under that folder (its relative path) with the sha256 of a file's bytes, ``"folder"`` for a folder,
``"symlink:<target>"`` for a link. A folder written whole (:func:`replace_folder`) carries its own record, written
last, inside the staging folder before it is swapped in; a single file written into a folder (:func:`replace_file`)
is added to the record of the nearest folder at or above it that has one, else to a new record in its folder.

The rule, for every output place (:func:`claim_folder`, :func:`claim_file`), checked before any work and again
just before the swap:

- nothing there, or an empty folder: may be written;
- a symbolic link (to anything), or a file where a folder goes (or a folder, FIFO, device where a file goes):
  refused;
- an entry is ours when the nearest record at or above its folder lists it and, for a file, its bytes still have
  the recorded hash; a folder holding its own record is ours as a container (its entries judged by that record);
- anything else (a file no record lists, a file changed since we wrote it, an unreadable record): refused, in one
  line naming the entry, with the remedy: remove it yourself, or choose another path. Outputs written by
  dome-calib before records existed have none: they are refused the same way (remove them once).
"""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from dome_calib.io_utils import (OutputPathError, atomic_folder, atomic_path, check_writable, new_mode,
                                 refuse_output_among_inputs)

#: The record's file name, in every folder we wrote in.
RECORD = ".dome-calib-written.json"
_WRITER = "dome-calib"
_VERSION = 1
FOLDER = "folder"
REMEDY = "remove it yourself if it can go, or choose another path"


class NotOursError(OutputPathError):
    """An output place holds something dome-calib did not write (or that changed since): it is not replaced."""


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return "sha256:" + h.hexdigest()


def _lkind(mode: int) -> str:
    for test, name in ((stat.S_ISLNK, "a symbolic link"), (stat.S_ISDIR, "a folder"), (stat.S_ISREG, "a file"),
                       (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "a special file"


class _Records:
    """The records met while judging one place, read once each. ``entries(folder)``: its record's entries, None
    when it has no record; a record that is not ours (unreadable, not JSON, not our layout) is an error."""

    def __init__(self) -> None:
        self._cache: dict[Path, dict[str, str] | None] = {}

    def entries(self, folder: Path) -> dict[str, str] | None:
        if folder not in self._cache:
            self._cache[folder] = _read_record(folder)
        return self._cache[folder]

    def nearest(self, folder: Path) -> tuple[Path, dict[str, str]] | None:
        """The nearest folder at or above ``folder`` holding a record, with its entries."""
        for here in (folder, *folder.parents):
            found = self.entries(here)
            if found is not None:
                return here, found
        return None


def _read_record(folder: Path) -> dict[str, str] | None:
    path = folder / RECORD
    try:
        if not stat.S_ISREG(os.lstat(path).st_mode):
            raise NotOursError(f"{path}: not a record of dome-calib (not a file); {REMEDY}")
        data = json.loads(path.read_bytes())
    except FileNotFoundError:
        return None
    except NotADirectoryError:
        return None
    except (OSError, ValueError) as exc:
        raise NotOursError(f"{path}: not a readable record of dome-calib ({exc}); {REMEDY}") from None
    entries = data.get("entries") if isinstance(data, dict) and data.get("written_by") == _WRITER else None
    if not isinstance(entries, dict) or not all(isinstance(k, str) and isinstance(v, str)
                                                for k, v in entries.items()):
        raise NotOursError(f"{path}: not a record of dome-calib (unknown layout); {REMEDY}")
    return entries


def _why_not_ours(path: Path, records: _Records) -> str | None:
    """Why the entry ``path`` (not followed if a link) is not ours; None when a record proves it is."""
    mode = os.lstat(path).st_mode
    if stat.S_ISDIR(mode) and records.entries(path) is not None:
        return None  # a folder of ours with its own record: its entries are judged by it
    owner = records.nearest(path.parent)
    if owner is None:
        return "no record of dome-calib lists it"
    root, entries = owner
    want = entries.get(path.relative_to(root).as_posix())
    if want is None:
        return f"the record {root / RECORD} does not list it"
    if stat.S_ISDIR(mode):
        return None if want == FOLDER else "a folder where dome-calib wrote something else"
    if stat.S_ISLNK(mode):
        return None if want == "symlink:" + os.readlink(path) else "a link dome-calib did not make"
    if stat.S_ISREG(mode):
        return None if want == _sha256(path) else "changed since dome-calib wrote it"
    return f"{_lkind(mode)}, which dome-calib never writes"


def foreign_entry(folder: str | os.PathLike[str], keep: Iterable[str] = ()) -> tuple[Path, str] | None:
    """The first entry under ``folder`` (sorted, depth first; links not followed) that is not ours, with why;
    ``keep``: regular files (paths relative to ``folder``) that the writer carries into the new folder (nothing
    of them is lost)."""
    records = _Records()
    root = Path(folder)
    kept = {root / name for name in keep}
    for here, dirs, files in os.walk(root):
        here_path = Path(here)
        dirs.sort()
        for name in sorted(files) + list(dirs):
            if here_path / name in kept and stat.S_ISREG(os.lstat(here_path / name).st_mode):
                continue
            if name == RECORD:
                records.entries(here_path)  # readable and ours, or NotOursError
                continue
            why = _why_not_ours(here_path / name, records)
            if why is not None:
                return here_path / name, why
    return None


def _refuse_link(given: Path, option: str, what: str) -> None:
    if given.is_symlink():
        raise NotOursError(f"{option} {given}: is a symbolic link; {what} is written only at a real path, never "
                           f"through a link: give the real path ({os.path.realpath(given)}) or another one")


def claim_folder(path: str | os.PathLike[str], *, option: str = "-o",
                 inputs: Iterable[str | os.PathLike[str]] = (), keep: Iterable[str] = ()) -> Path:
    """Before any work: ``path`` may be replaced whole by a folder we write (module docstring), and is not, and
    does not hold, one of ``inputs``. ``keep``: its files (relative paths) that the command reads and carries into
    the new folder (the report's report.json, residuals and kept files): nothing of them is lost, so they need not be
    ours. Returns it; NotOursError / OutputPathError in one line otherwise."""
    given = Path(path)
    refuse_output_among_inputs(given, inputs, option=option, whole_folder=True)
    _refuse_link(given, option, "an output folder")
    try:
        mode = os.lstat(given).st_mode
    except FileNotFoundError:
        check_writable(given)
        return given
    if not stat.S_ISDIR(mode):
        raise NotOursError(f"{option} {given}: is {_lkind(mode)}, not a folder; the output is a folder: "
                           f"{REMEDY}")
    found = foreign_entry(given, keep)
    if found is not None:
        entry, why = found
        raise NotOursError(f"{option} {given}: holds {entry.relative_to(given)} ({why}); the folder would be "
                           f"replaced whole: {REMEDY}")
    check_writable(given)
    return given


def claim_file(path: str | os.PathLike[str], *, option: str = "-o",
               inputs: Iterable[str | os.PathLike[str]] = ()) -> Path:
    """Before any work: a file we write may go at ``path``: nothing there, or a file of ours, unchanged; and it
    is not one of ``inputs``. Returns it; NotOursError / OutputPathError in one line otherwise."""
    given = Path(path)
    refuse_output_among_inputs(given, inputs, option=option)
    _refuse_link(given, option, "an output file")
    try:
        mode = os.lstat(given).st_mode
    except FileNotFoundError:
        check_writable(given)
        if given.parent.is_dir():
            _read_record(given.parent)  # the record the file will be added to is ours (NotOursError if not)
        return given
    if not stat.S_ISREG(mode):
        raise NotOursError(f"{option} {given}: is {_lkind(mode)}, not a file; the output is one file: {REMEDY}")
    why = _why_not_ours(given, _Records())
    if why is not None:
        raise NotOursError(f"{option} {given}: a file dome-calib did not write ({why}); {REMEDY}")
    check_writable(given)
    return given


def claim_into(folder: str | os.PathLike[str], *, option: str = "-o",
               inputs: Iterable[str | os.PathLike[str]] = ()) -> Path:
    """Before any work: a folder that outputs are written into (each of them claimed by itself, the folder never
    replaced): absent or a real folder, not a link, not a file, not one of ``inputs`` nor holding one, writable."""
    given = Path(folder)
    refuse_output_among_inputs(given, inputs, option=option, whole_folder=True)
    _refuse_link(given, option, "an output folder")
    if os.path.lexists(given) and not given.is_dir():
        raise NotOursError(f"{option} {given}: is {_lkind(os.lstat(given).st_mode)}, not a folder; the output is a "
                           f"folder: {REMEDY}")
    check_writable(given, into=True)
    return given


#: A scratch folder's record: the whole folder is ours to empty (a work folder; its files change as it works).
_SCRATCH = "scratch"


def claim_scratch(folder: str | os.PathLike[str], *, option: str = "--work") -> Path:
    """Before any work: a scratch folder (a run's work folder, emptied when it was made for other inputs) may be
    used: absent, empty, or marked as ours by :func:`mark_scratch`; a link or a file is refused."""
    given = Path(folder)
    _refuse_link(given, option, "a work folder")
    if not os.path.lexists(given):
        return given
    if not given.is_dir():
        raise NotOursError(f"{option} {given}: is {_lkind(os.lstat(given).st_mode)}, not a folder; {REMEDY}")
    entries = _read_record(given)
    if entries is not None and entries.get(_SCRATCH) == _SCRATCH:
        return given
    content = sorted(p.name for p in given.iterdir())
    if content:
        raise NotOursError(f"{option} {given}: holds {content[0]}, and is not a work folder dome-calib made (it would "
                           f"be emptied): {REMEDY}")
    return given


def mark_scratch(folder: str | os.PathLike[str]) -> None:
    """Mark ``folder`` (existing) as a scratch folder of ours (:func:`claim_scratch`)."""
    _write_record(Path(folder), {_SCRATCH: _SCRATCH})


def record_entries(folder: Path) -> dict[str, str]:
    """Every entry under ``folder`` as a record lists it; a sub-folder holding its own record is just ``"folder"``
    (its record lists its entries)."""
    entries: dict[str, str] = {}
    for here, dirs, files in os.walk(folder):
        here_path = Path(here)
        for name in files:
            p = here_path / name
            if name == RECORD:
                continue
            mode = os.lstat(p).st_mode
            entries[p.relative_to(folder).as_posix()] = (
                "symlink:" + os.readlink(p) if stat.S_ISLNK(mode) else _sha256(p) if stat.S_ISREG(mode) else "")
        for name in list(dirs):
            p = here_path / name
            entries[p.relative_to(folder).as_posix()] = ("symlink:" + os.readlink(p) if p.is_symlink() else FOLDER)
            if p.is_symlink() or os.path.lexists(p / RECORD):
                dirs.remove(name)  # a link is not followed; a folder with its own record keeps it
    return {k: v for k, v in sorted(entries.items()) if v}


def _write_record(folder: Path, entries: dict[str, str]) -> None:
    text = json.dumps({"written_by": _WRITER, "version": _VERSION,
                       "about": "what dome-calib wrote here (sha256 per file); only these may be replaced by it",
                       "entries": dict(sorted(entries.items()))}, indent=1)
    fd, tmp = tempfile.mkstemp(prefix=f"{RECORD}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.chmod(tmp, new_mode(0o666))
        os.replace(tmp, folder / RECORD)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def seal(folder: str | os.PathLike[str]) -> None:
    """Write ``folder``'s record of everything in it, and the records of its sub-folders that have one, anew
    (call last, on a staged folder that this run wrote, before it is swapped in)."""
    folder = Path(folder)
    for here, dirs, _ in os.walk(folder, topdown=False):
        for name in dirs:
            sub = Path(here) / name
            if not sub.is_symlink() and os.path.lexists(sub / RECORD):
                _write_record(sub, record_entries(sub))
    _write_record(folder, record_entries(folder))


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def record_written(paths: Iterable[str | os.PathLike[str]]) -> None:
    """Add files just written (each by its path) to the record of the folder each was written into (made when it
    has none)."""
    for path in paths:
        path = Path(os.path.abspath(path))
        with _locked(path.parent):
            entries = dict(_read_record(path.parent) or {})
            entries[path.name] = _sha256(path)
            _write_record(path.parent, entries)


@contextlib.contextmanager
def replace_folder(path: str | os.PathLike[str], *, option: str = "-o") -> Iterator[Path]:
    """Yield an empty staging folder beside ``path``; on success it is sealed (its record written) and replaces
    ``path`` whole, which is claimed again just before the swap (it may have changed meanwhile). On any error or
    interrupt the staging folder is removed and ``path`` is as it was."""
    target = claim_folder(path, option=option)

    def still_ours() -> None:
        claim_folder(target, option=option)

    with atomic_folder(target, before_swap=still_ours) as staging:
        yield staging
        seal(staging)


@contextlib.contextmanager
def replace_file(path: str | os.PathLike[str], *, option: str = "-o") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` (claimed before and again just
    before the rename) and is added to the record. On any error the temporary file is removed."""
    target = claim_file(path, option=option)
    with atomic_path(target, before_rename=lambda: claim_file(target, option=option)) as tmp:
        yield tmp
    record_written([target])


def write_text(path: str | os.PathLike[str], text: str, *, option: str = "-o") -> None:
    """Write ``text`` (UTF-8) to the output file ``path`` (:func:`replace_file`)."""
    with replace_file(path, option=option) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_bytes(path: str | os.PathLike[str], data: bytes, *, option: str = "-o") -> None:
    """Write ``data`` to the output file ``path`` (:func:`replace_file`)."""
    with replace_file(path, option=option) as tmp:
        tmp.write_bytes(data)
