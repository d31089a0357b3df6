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
import tempfile
from pathlib import Path

from dome_calib import panoptic_io as pio
from dome_calib.bundle import Bundle, SyncTables
from dome_calib.errors import BundleFormatError
from dome_calib.final_place import stage
from dome_calib.ownership import claim_file, claim_folder, claim_into, seal, write_bytes

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
    """Write the bundle's files into ``folder`` (:func:`update_bundle` with every kind): each appears whole or not
    at all, and replaces only a file dome-calib wrote."""
    update_bundle(bundle, folder)
    return Path(folder)


def check_bundle_update(folder: str | Path, seq: str, kinds: tuple[str, ...] = FILE_KINDS, *,
                        option: str = "-o") -> None:
    """Before any work: the files of ``kinds`` that :func:`update_bundle` would write into ``folder`` may be
    written (nothing there, or a file dome-calib wrote, unchanged: :func:`dome_calib.ownership.claim_file`)."""
    claim_into(folder, option=option)
    for path in (Path(folder) / f"{kind}_{seq}.json" for kind in kinds):
        claim_file(path, option=option)


def update_bundle(bundle: Bundle, folder: str | Path, kinds: tuple[str, ...] = FILE_KINDS, *,
                  option: str = "-o") -> list[Path]:
    """Write the bundle's files of ``kinds`` into the existing (or new) bundle folder ``folder``, each replacing
    only a file of ours (:mod:`dome_calib.ownership`); a file whose bytes would not change is left as it is.
    Everything is formatted before anything is written. Returns the files written."""
    folder = Path(folder)
    texts = {name: text for name, text in bundle_texts(bundle).items() if name.split("_", 1)[0] in kinds}
    changed = {}
    for name, text in texts.items():
        data = text.encode("utf-8")
        path = folder / name
        if not (path.is_file() and not path.is_symlink() and path.read_bytes() == data):
            claim_file(path, option=option)
            changed[path] = data
    folder.mkdir(parents=True, exist_ok=True)
    for path, data in changed.items():
        write_bytes(path, data, option=option)
    return list(changed)


# ------------------------------------------------------------------------------ replacing a bundle folder whole
def _sibling(target: Path, role: str) -> Path:
    return target.with_name(f".{target.name}.{role}")


def staging_folder(target: Path) -> Path:
    """An empty folder beside ``target`` to build its replacement in (a leftover one is removed first)."""
    staging = _sibling(Path(target), "staging")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    return stage(staging, target)  # said at ``target`` (:func:`dome_calib.final_place.said`)


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


def replace_folder(staging: Path, target: Path, *, option: str = "-o", keep: tuple[str, ...] = ()) -> None:
    """Put the folder ``staging`` in place of ``target`` so that a reader sees the old folder or the new one,
    never a mix: an atomic exchange where the system has it, else set the old aside, rename the new in and
    remove the old (a stop between the two renames is undone by :func:`recover_folder`). ``staging`` is sealed
    (its record of what dome-calib wrote) and ``target`` claimed again just before (:mod:`dome_calib.ownership`;
    ``keep``: files of ``target`` carried into ``staging``)."""
    staging, target = Path(staging), Path(target)
    seal(staging)
    claim_folder(target, option=option, keep=keep)
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


def check_output_folder(out: Path, inputs: list[Path] = (), keep: tuple[str, ...] = ()) -> str | None:
    """Before any work: ``out`` may be replaced whole (:func:`dome_calib.ownership.claim_folder`: new, empty, or
    what dome-calib wrote, unchanged; a symlink or a file is refused; not one of ``inputs`` nor holding one;
    ``keep``: its files the new bundle carries over, which need not be ours).

    Returns the seq of the bundle it holds (None when it holds none).
    """
    out = claim_folder(out, inputs=inputs, keep=keep)
    found = sorted(out.glob("calibration_*.json")) if out.is_dir() else []
    return found[0].stem.removeprefix("calibration_") if found else None  # several: replaced whole anyway
