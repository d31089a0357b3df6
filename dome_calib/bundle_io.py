"""A bundle folder on disk: find its files, load it, write it.

A bundle is one folder holding the Panoptic-format files (each read and formatted by :mod:`dome_calib.panoptic_io`):
``calibration_<seq>.json`` (required), ``kcalibration_<seq>.json``, ``synctables_<seq>.json``,
``ksynctables_<seq>.json`` (optional), and ``report/``. The seq is read from the one ``calibration_<seq>.json``.
"""
from __future__ import annotations

import ctypes
import errno
import logging
import os
import shutil
import stat
import tempfile
from pathlib import Path

from dome_calib import panoptic_io as pio
from dome_calib.bundle import Bundle, SyncTables
from dome_calib.errors import BundleFormatError, DomeCalibError
from dome_calib.io_utils import check_writable

logger = logging.getLogger(__name__)

FILE_KINDS = ("calibration", "kcalibration", "synctables", "ksynctables")


def bundle_seq(folder: str | Path) -> str | None:
    """The seq of the bundle in ``folder`` (from its ``calibration_<seq>.json``), None if it holds none.

    Raises :class:`BundleFormatError` when the folder holds several calibration files (it would not load).
    """
    folder = Path(folder)
    found = sorted(folder.glob("calibration_*.json")) if folder.is_dir() else []
    if len(found) > 1:
        raise BundleFormatError(f"{folder}: several calibration_*.json files ({', '.join(p.name for p in found)})")
    return found[0].stem.removeprefix("calibration_") if found else None


def bundle_files(folder: Path, seq: str) -> dict[str, Path]:
    """Kind ("calibration", "kcalibration", "synctables", "ksynctables") -> path of that file of ``seq``."""
    return {k: Path(folder) / f"{k}_{seq}.json" for k in FILE_KINDS}


def load_bundle(folder: str | Path) -> Bundle:
    """Read and validate a bundle folder. Raises :class:`BundleFormatError` naming file, camera and field."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BundleFormatError(f"{folder}: not a folder")
    seq = bundle_seq(folder)
    if seq is None:
        raise BundleFormatError(f"{folder}: no calibration_<seq>.json in this folder (is it a bundle?)")
    files = bundle_files(folder, seq)
    cameras, source = pio.read_calibration(files["calibration"])
    bundle = Bundle(seq=seq, cameras=cameras, calib_data_source=source)
    if files["kcalibration"].exists():
        bundle.kinect = pio.read_kcalibration(files["kcalibration"])
    if files["synctables"].exists() or files["ksynctables"].exists():
        bundle.sync = SyncTables()
        if files["synctables"].exists():
            bundle.sync.streams = pio.read_synctables(files["synctables"])
        if files["ksynctables"].exists():
            bundle.sync.kinect_color, bundle.sync.kinect_depth = pio.read_ksynctables(files["ksynctables"])
    logger.debug("loaded bundle %s: %d cameras", folder, len(cameras))
    return bundle


def bundle_texts(bundle: Bundle) -> dict[str, str]:
    """File name -> formatted content of every file the bundle has (nothing written)."""
    texts = {f"calibration_{bundle.seq}.json": pio.format_calibration(bundle.cameras, bundle.calib_data_source)}
    if bundle.kinect is not None:
        texts[f"kcalibration_{bundle.seq}.json"] = pio.format_kcalibration(bundle.kinect)
    if bundle.sync is not None and bundle.sync.streams:
        texts[f"synctables_{bundle.seq}.json"] = pio.format_synctables(bundle.sync.streams)
    if bundle.sync is not None and (bundle.sync.kinect_color or bundle.sync.kinect_depth):
        texts[f"ksynctables_{bundle.seq}.json"] = pio.format_ksynctables(bundle.sync.kinect_color, bundle.sync.kinect_depth)
    return texts


def write_bundle(bundle: Bundle, folder: str | Path) -> Path:
    """Write the bundle's files into ``folder``. Each file appears whole or not at all (temp file, then rename)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    texts = bundle_texts(bundle)
    staging = Path(tempfile.mkdtemp(prefix=".bundle.", dir=folder))
    try:
        for name, text in texts.items():  # everything formatted and staged before anything is replaced
            (staging / name).write_text(text, encoding="utf-8")
        for name in texts:
            (staging / name).replace(folder / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return folder


# ------------------------------------------------------------------------------ replacing a bundle folder whole
def _sibling(target: Path, role: str) -> Path:
    return target.with_name(f".{target.name}.{role}")


def staging_folder(target: Path) -> Path:
    """An empty folder beside ``target`` to build its replacement in (a leftover one is removed first)."""
    staging = _sibling(Path(target), "staging")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    return staging


def recover_folder(target: Path) -> None:
    """Finish or undo a replacement that a stop interrupted: put a set-aside bundle back if ``target`` is gone,
    and remove leftover staging / set-aside folders. Call with the work folder locked."""
    target = Path(target)
    aside = _sibling(target, "aside")
    if aside.is_dir() and not target.exists():
        aside.rename(target)
        logger.warning("%s: restored the previous bundle after an interrupted replacement", target)
    for leftover in (aside, _sibling(target, "staging")):
        shutil.rmtree(leftover, ignore_errors=True)


_libc = ctypes.CDLL(None, use_errno=True)
_AT_FDCWD, _RENAME_EXCHANGE = -100, 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where the system cannot."""
    renameat2 = getattr(_libc, "renameat2", None)
    if renameat2 is None:
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def replace_folder(staging: Path, target: Path) -> None:
    """Put the folder ``staging`` in place of ``target`` so that a reader sees the old folder or the new one,
    never a mix: an atomic exchange where the system has it, else set the old aside, rename the new in and
    remove the old (a stop between the two renames is undone by :func:`recover_folder`)."""
    staging, target = Path(staging), Path(target)
    if not target.exists():
        staging.rename(target)
        return
    if _exchange(staging, target):
        shutil.rmtree(staging)  # now the old folder
        return
    aside = _sibling(target, "aside")
    shutil.rmtree(aside, ignore_errors=True)
    target.rename(aside)
    staging.rename(target)
    shutil.rmtree(aside)


def _kind(path: Path) -> str:
    mode = path.lstat().st_mode
    return ("a symbolic link" if stat.S_ISLNK(mode) else "a named pipe (FIFO)" if stat.S_ISFIFO(mode)
            else "a regular file" if stat.S_ISREG(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "not a folder")


def check_output_folder(out: Path) -> str | None:
    """Before any work: ``out`` must be new, an empty folder or a bundle folder (which will be replaced whole).

    Returns the seq of the bundle it holds (None when new or empty). Raises :class:`DomeCalibError` for a path
    that is not a folder (file, FIFO, a symbolic link: resolve it first, ...) or a folder of other things.
    """
    out = Path(out)
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise DomeCalibError(f"{out}: the output is {_kind(out)}, not a folder; give a new or bundle folder")
    check_writable(out)  # it is replaced whole, beside itself: before the work, not after it
    if not out.exists():
        return None
    found = sorted(out.glob("calibration_*.json"))
    if not found:
        others = sorted(p.name for p in out.iterdir())
        if others:
            raise DomeCalibError(f"{out}: not a calibration bundle (holds {', '.join(others[:3])}"
                                 f"{', ...' if len(others) > 3 else ''}); give a new, empty or bundle folder")
        return None
    return found[0].stem.removeprefix("calibration_")  # several (a broken folder): it is replaced whole anyway
