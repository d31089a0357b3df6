"""A bundle folder on disk: find its files, load it, write it.

A bundle is one folder holding the Panoptic-format files (each read and formatted by :mod:`dome_calib.panoptic_io`):
``calibration_<seq>.json`` (required), ``kcalibration_<seq>.json``, ``synctables_<seq>.json``,
``ksynctables_<seq>.json`` (optional), and ``report/``. The seq is read from the one ``calibration_<seq>.json``.
"""
from __future__ import annotations

import logging
import shutil
import tempfile
from pathlib import Path

from dome_calib import panoptic_io as pio
from dome_calib.bundle import Bundle, SyncTables
from dome_calib.errors import BundleFormatError

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
