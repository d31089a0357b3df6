"""The calibrate pipeline's work folder: which stages finished for which inputs, a lock, and stage timing.

    with WorkState.open(work, fingerprint, progress=tasks) as state:  # tasks: a bar per stage (dome_calib.progress)
        sfm = state.run("sfm", lambda: run_sfm_stage(...))   # taken from the folder if it finished before
        normalized = state.time("normalize", lambda: normalize(...))  # timed, not kept
        with state.timing("write"):  # the same, for work done in the block
            write_out(...)

A stage's result is pickled into ``WORK/<stage>.pkl`` and listed in ``WORK/state.json`` with the inputs'
fingerprint (:func:`input_fingerprint`: the content of every image and of the prior, by size and mtime, plus the
options). A rerun with the same fingerprint resumes after the last finished stage; with another one the work
folder is emptied first (the SfM databases hold features of the old images).

The lock (``WORK/lock``, ``fcntl.flock``) lets one run use a work folder at a time: a second run fails at once
naming the holder (pid, host, start time). The kernel releases the lock of a process that died (even by SIGKILL);
the next run then finds the dead holder's record, warns, and takes the folder over.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import pickle
import shutil
import socket
import time
from collections.abc import Callable, Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import TypeVar

from dome_calib.errors import DomeCalibError, Interrupted, restore_interrupt_handler, storage_failure
from dome_calib.io_utils import atomic_path, atomic_write_text
from dome_calib.ownership import RECORD, claim_scratch, mark_scratch
from dome_calib.progress import ProgressTasks, task_progress

logger = logging.getLogger(__name__)

T = TypeVar("T")

STATE_FILE = "state.json"
LOCK_FILE = "lock"
STATE_VERSION = 4  # 2: stage results are the typed outcomes of pipeline_stages / pipeline_quick; 3: the quick
# path's first round on halved HD images and its suspect_match stage; 4: the pickled types moved into
# dome_calib.pipeline (types, quick): a work folder of an older version is emptied, not unpickled


class WorkFolderBusy(DomeCalibError):
    """Another run holds the work folder."""


def file_signature(path: Path) -> list:
    """[name, size in bytes, mtime in ns] of a file: changes when its content is replaced."""
    st = path.stat()
    return [path.name, st.st_size, st.st_mtime_ns]


def input_fingerprint(capture: Path, scenes: list[str], cameras: list[str], prior: Path | None,
                      options: dict) -> dict:
    """What a work folder's results depend on: the capture's images (every ``scenes/<scene>/*.png`` by size and
    mtime), its ``capture.json``, the prior bundle's files, and the run's options. JSON-ready."""
    digest = hashlib.sha256()
    for scene in scenes:
        for png in sorted((capture / "scenes" / scene).glob("*.png")):
            digest.update(json.dumps([scene, *file_signature(png)]).encode())
    meta = capture / "capture.json"
    if meta.exists():
        digest.update(json.dumps(file_signature(meta)).encode())
    prior_files = sorted(p for p in Path(prior).iterdir() if p.is_file()) if prior is not None else []
    for p in prior_files:
        digest.update(json.dumps(file_signature(p)).encode())
    return {"capture": str(capture.resolve()), "scenes": scenes, "cameras": cameras,
            "prior": str(Path(prior).resolve()) if prior is not None else None, "options": options,
            "content_sha256": digest.hexdigest()}


@contextlib.contextmanager
def _stage_status(text: str, tasks: ProgressTasks | None) -> Iterator[None]:
    """A stage as a task of one unit: ``progress(0, 1)`` when it starts, ``progress(1, 1)`` when it ends."""
    progress = task_progress(tasks, text)
    if progress is not None:
        progress(0, 1)
    yield
    if progress is not None:
        progress(1, 1)


class WorkLock:
    """An exclusive lock on a work folder, held while the object is open (see the module docstring)."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / LOCK_FILE
        self._fd: int | None = None

    def acquire(self) -> None:
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise WorkFolderBusy(f"{self.path.parent}: in use by another run ({_describe(holder)}); wait for it to "
                                 "finish, or give this run another --work / -o") from None
        previous = _read_holder(fd)
        if previous:  # a holder that released the lock without clearing it: it died
            logger.warning("%s: taking over from a run that stopped without releasing it (%s)",
                           self.path.parent, _describe(previous))
        me = {"pid": os.getpid(), "host": socket.gethostname(),
              "started": datetime.now(timezone.utc).isoformat(timespec="seconds")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(me).encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.ftruncate(self._fd, 0)
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None


def _read_holder(fd: int) -> dict:
    try:
        data = os.pread(fd, 4096, 0)
        return json.loads(data) if data.strip() else {}
    except ValueError:
        return {"unreadable": True}


def _describe(holder: dict) -> str:
    if not holder or "pid" not in holder:
        return "holder unknown"
    return f"pid {holder['pid']} on {holder.get('host', '?')}, started {holder.get('started', '?')}"


def _in_folder(exc: OSError, folder: Path) -> bool:
    """Whether a failed file operation was in ``folder`` (a write the work folder's disk refused), or names no
    file; a permission error on a file elsewhere is not the work folder's."""
    if exc.errno == errno.EACCES:
        return False
    if not exc.filename:
        return True
    return os.path.abspath(str(exc.filename)).startswith(os.path.abspath(folder) + os.sep)


class WorkState:
    """Finished stages and their timings for one run; use :meth:`open` (locks the folder)."""

    def __init__(self, folder: Path, fingerprint: dict, *, progress: ProgressTasks | None = None,
                 labels: dict[str, str] | None = None) -> None:
        self.folder, self.fingerprint, self.progress = Path(folder), fingerprint, progress
        self.labels = labels or {}
        self.path = self.folder / STATE_FILE
        self.seconds: dict[str, float] = {}  # stage -> wall seconds (of the run that computed it, if resumed)
        self.resumed: list[str] = []  # stages taken from the folder
        self.current: str | None = None  # the stage running now (named when interrupted)
        self._lock = WorkLock(self.folder)
        self.state: dict = {}

    @classmethod
    @contextlib.contextmanager
    def open(cls, folder: Path, fingerprint: dict, **kwargs) -> Iterator[WorkState]:
        """Lock the work folder, load or reset its state, and release the lock at the end."""
        state = cls(folder, fingerprint, **kwargs)
        claim_scratch(state.folder)  # emptied when made for other inputs: only a work folder of ours
        state.folder.mkdir(parents=True, exist_ok=True)
        mark_scratch(state.folder)
        state._lock.acquire()
        try:
            state._load()
            yield state
        finally:
            state._lock.release()

    def _load(self) -> None:
        try:
            state = json.loads(self.path.read_text(encoding="utf-8")) if self.path.exists() else {}
        except ValueError:
            state = {"unreadable": True}
        if state.get("version") != STATE_VERSION or state.get("fingerprint") != self.fingerprint:
            if any(p.name not in (LOCK_FILE, RECORD) for p in self.folder.iterdir()):
                logger.info("work folder %s was made for other inputs: starting over", self.folder)
                self._empty()
            state = {"version": STATE_VERSION, "fingerprint": self.fingerprint, "stages": {}}
            # on disk before the first stage starts: a stop inside it leaves work (SfM's databases) that a rerun
            # with the same inputs recognises and resumes, instead of "made for other inputs: starting over"
            atomic_write_text(self.path, json.dumps(state, indent=1))
        self.state = state

    def _empty(self) -> None:
        for p in self.folder.iterdir():
            if p.name in (LOCK_FILE, RECORD):
                continue
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()

    def done(self, stage: str) -> bool:
        return stage in self.state["stages"] and (self.folder / f"{stage}.pkl").exists()

    def run(self, name: str, fn: Callable[[], T]) -> T:
        """The stage's result: from the work folder if it finished before for these inputs, else ``fn()``, kept."""
        if self.done(name):
            self.resumed.append(name)
            self.seconds[name] = self.state["stages"][name]["seconds"]
            logger.info("stage %s: taken from %s", name, self.folder)
            with open(self.folder / f"{name}.pkl", "rb") as f:
                return pickle.load(f)
        value = self.time(name, fn)
        with atomic_path(self.folder / f"{name}.pkl") as tmp:
            tmp.write_bytes(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        self.state["stages"][name] = {"seconds": self.seconds[name]}
        atomic_write_text(self.path, json.dumps(self.state, indent=1))
        logger.info("stage %s: done in %.1f s", name, self.seconds[name])
        return value

    def time(self, name: str, fn: Callable[[], T]) -> T:
        """``fn()`` timed as stage ``name`` (not kept); an interrupt names the stage (:class:`Interrupted`)."""
        with self.timing(name):
            return fn()

    @contextlib.contextmanager
    def timing(self, name: str) -> Iterator[None]:
        """The block timed as stage ``name`` (not kept), for a caller that does the work itself (no callback into
        it); an interrupt names the stage (:class:`Interrupted`)."""
        self.current = name
        restore_interrupt_handler()  # a library loaded during an earlier stage may have replaced it
        t0 = time.perf_counter()
        try:
            with _stage_status(f"{name}: {self.labels.get(name, name)}", self.progress):
                yield
        except KeyboardInterrupt as exc:
            raise Interrupted(name) from exc
        except Exception as exc:
            why = storage_failure(exc)
            if why is None or (isinstance(exc, OSError) and not _in_folder(exc, self.folder)):
                raise  # not a write to the work folder (an unreadable image, ...): run_cli names its own path
            raise DomeCalibError(f"{self.folder}: {why} while stage {name} wrote its work; free space there or give "
                                 "--work on another disk, then rerun the same command to resume") from exc
        self.seconds[name] = time.perf_counter() - t0
        self.current = None
