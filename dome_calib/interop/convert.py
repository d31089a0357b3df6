"""Export a bundle to another tool's calibration files, and import theirs into a bundle (the commands' stages).

The formats are the rows of :mod:`dome_calib.interop.registry`; each row names the module that reads
(``read(source, options) -> Read``) or writes (``write(cams, out, unit, options) -> Written``) its files. This
module holds what is the same for every format: units, world axes, names, what a bundle holds that no format
carries, and where the output goes.

Every input and output place is checked before anything is read; every output is staged and renamed into place,
replacing only what dome-calib wrote (:mod:`dome_calib.ownership`): on any error nothing is written. An imported
bundle is written by :func:`dome_calib.bundle_io.write_bundle` and read back with
:func:`dome_calib.bundle_io.load_bundle` (the loader every stage uses) before it replaces anything.
"""
from __future__ import annotations

import importlib
import logging
import re
from dataclasses import dataclass, replace
from pathlib import Path
from types import ModuleType

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.errors import BundleFormatError
from dome_calib.interop.common import (ExportOptions, ExportResult, ImportOptions, InteropError, cm_per_unit,
                                       import_record, to_bundle, to_foreign)
from dome_calib.interop.registry import UP_AXES, FormatInfo, format_info
from dome_calib.ownership import claim_file, claim_folder, replace_file, replace_folder

logger = logging.getLogger(__name__)

#: A sequence name: it becomes part of a file name (calibration_<seq>.json).
_SEQ = re.compile(r"[^./\\\x00-\x1f\x7f][^/\\\x00-\x1f\x7f]{0,127}")


@dataclass(kw_only=True)
class ImportResult:
    out: Path
    format: str
    cameras: int
    unit: str  # the source file's length unit (stated by it, or given with --unit)
    world_up: str  # the source world's up axis, turned to Panoptic -y


def _info(fmt: str, direction: str) -> FormatInfo:
    try:
        return format_info(str(fmt), direction)
    except ValueError as exc:
        raise InteropError(str(exc)) from None


def adapter(info: FormatInfo) -> ModuleType:
    """The module that reads and writes ``info``'s files (loaded when a command uses it)."""
    return importlib.import_module(info.module)


def _world_up(info: FormatInfo, world_up: str | None, where: str, *, export: bool) -> str:
    if world_up is not None and world_up not in UP_AXES:
        raise InteropError(f"{where}: --world-up {world_up!r}: expected one of {', '.join(UP_AXES)}")
    if info.fixed_up and world_up is not None:
        raise InteropError(f"{where}: {info.name} worlds are {info.export_up} up by the format (recorded in its "
                           "files); --world-up does not apply")
    return world_up or (info.export_up if export else info.import_up)


def _export_unit(info: FormatInfo, unit: str | None, where: str) -> str:
    if info.fixed_unit is not None and unit not in (None, info.fixed_unit):
        raise InteropError(f"{where}: {info.name} files are in {info.fixed_unit} by the format's definition; "
                           f"--unit {unit} is not possible")
    unit = unit or info.fixed_unit or info.default_unit
    if unit == "squares":
        raise InteropError(f"{where}: --unit squares is for import only (the bundle is in cm)")
    cm_per_unit(unit, None, where)
    return unit


def _not_carried(bundle: Bundle, info: FormatInfo) -> list[str]:
    lines = []
    if bundle.kinect is not None:
        lines.append(f"Kinect depth-colour calibration (kcalibration, {len(bundle.kinect.sensors)} sensors): no place "
                     f"in {info.name}, not written")
    if bundle.sync is not None:
        lines.append(f"sync tables: no place in {info.name}, not written")
    return lines


def camera_subset(bundle: Bundle, cameras: list[str] | None, where: str) -> Bundle:
    """``bundle`` with only ``cameras`` (its own order kept; None: all); InteropError naming a camera it lacks."""
    if cameras is None:
        return bundle
    unknown = [c for c in cameras if c not in bundle.cameras]
    if unknown:
        raise InteropError(f"{where}: --cameras: no camera {unknown[0]!r} in the bundle (cameras: "
                           f"{', '.join(list(bundle.cameras)[:12])}{' ...' if len(bundle.cameras) > 12 else ''})")
    keep = set(cameras)
    return replace(bundle, cameras={n: c for n, c in bundle.cameras.items() if n in keep})


def export_bundle(bundle_folder: str | Path, fmt: str, out: str | Path,
                  options: ExportOptions | None = None) -> ExportResult:
    """Write the bundle in ``bundle_folder`` as ``fmt`` to ``out`` (a folder for folder formats, else a file).

    Returns what was written, the unit, and what the format could not carry (with the corner shift, px, of a
    dropped distortion term per camera).
    """
    options = options or ExportOptions()
    info = _info(fmt, "export")
    out = Path(out)
    claim = claim_folder if info.folder else claim_file
    claim(out, inputs=[bundle_folder, *Path(bundle_folder).glob("*")])  # ours only, and no input
    unit = _export_unit(info, options.unit, str(out))
    up = _world_up(info, options.world_up, str(out), export=True)
    bundle = camera_subset(load_bundle(bundle_folder), options.cameras, str(bundle_folder))
    cams = to_foreign(bundle, options, unit, up, str(bundle_folder))
    module = adapter(info)
    with (replace_folder(out) if info.folder else replace_file(out)) as staging:
        written = module.write(cams, staging, unit, options)
    return ExportResult(format=info.name, out=out, unit=unit, world_up=up, cameras=len(cams),
                        dropped=_not_carried(bundle, info) + written.dropped,
                        corner_shift_px=written.corner_shift_px)


def _source(info: FormatInfo, src: Path) -> Path:
    """The file (or folder) to read: a folder given for a file format means its ``default_file``."""
    if info.folder or not src.is_dir():
        return src
    if info.default_file is not None and (src / info.default_file).is_file():
        return src / info.default_file
    want = f" (or a folder holding {info.default_file})" if info.default_file else ""
    raise InteropError(f"{src}: a folder; give the {info.name} file itself: {info.files}{want}")


def read_foreign(src: str | Path, fmt: str, options: ImportOptions | None = None) -> tuple[Bundle, str]:
    """Read another tool's calibration into a bundle (nothing written; translations converted to cm, the file's up
    axis turned to Panoptic -y) and name the source's length unit."""
    options = options or ImportOptions()
    info = _info(fmt, "import")
    src = _source(info, Path(src))
    up = _world_up(info, options.world_up, str(src), export=False)
    read = adapter(info).read(src, options)
    stated = read.unit or info.fixed_unit
    if stated is not None and options.unit is not None and options.unit != stated:
        raise InteropError(f"{read.path}: the file states its unit ({stated}); --unit {options.unit} contradicts it")
    unit = stated or options.unit
    if unit is None:
        raise InteropError(f"{read.path}: a {info.name} calibration does not record its length unit; give --unit "
                           "(mm, cm, m, or squares with --square-size-mm)")
    scale = cm_per_unit(unit, options.square_size_mm, str(read.path))
    source = import_record(info.name, read.path.name, unit, up)
    bundle = to_bundle(read.cameras, scale, up, options, read.path, source)
    warn_implausible_size(bundle, read.path, unit, fixed=stated is not None)
    return bundle, unit


#: The sizes a rig has: its cameras span more than 1 cm (a stereo pair's baseline) and less than 100 m (a stadium).
RIG_SPAN_CM = (1.0, 1e4)


def warn_implausible_size(bundle: Bundle, path: Path, unit: str, *, fixed: bool) -> None:
    """One warning naming ``--unit`` when the cameras span a size no rig has (:data:`RIG_SPAN_CM`): a file in m
    read as mm is 1000x too small, in mm read as m 1000x too large (a 5 km dome), and both still load."""
    centres = np.array([c.center_cm for c in bundle.cameras.values()])
    if len(centres) < 2:
        return
    span = float(np.linalg.norm(centres.max(0) - centres.min(0)))
    low, high = RIG_SPAN_CM
    if low <= span <= high:
        return
    said = f"{span / 1e5:.3g} km" if span >= 1e5 else f"{span / 100:.3g} m" if span >= 100 else f"{span * 10:.3g} mm"
    fix = ("the file or its format states it, so --unit cannot change it: is the file in that unit?" if fixed else
           "if the file is in another unit, give --unit (mm, cm, m)")
    logger.warning("%s: the %d cameras span %s, %s than any rig (%g cm to %g m), read in %s: %s", path, len(centres),
                   said, "larger" if span > high else "smaller", low, high / 100, unit, fix)


def check_import_output(out: Path, seq: str, src: str | Path) -> None:
    """Before anything is read: the sequence name makes a file name, and the output folder is new, empty, or what
    dome-calib wrote (:func:`dome_calib.ownership.claim_folder`), holding no input: it is replaced whole."""
    if not _SEQ.fullmatch(seq):
        raise InteropError(f"--seq {seq!r}: a sequence name is part of the file name calibration_<seq>.json: no "
                           "'/', '\\' or control characters, not starting with '.', at most 128 characters (without "
                           "--seq: the output folder's name)")
    claim_folder(out, inputs=[src])


def import_calibration(src: str | Path, fmt: str, out: str | Path,
                       options: ImportOptions | None = None) -> ImportResult:
    """Import ``src`` as ``fmt`` into the bundle folder ``out`` (new, empty, or an earlier import's: replaced)."""
    options = options or ImportOptions()
    out = Path(out)
    info = _info(fmt, "import")
    check_import_output(out, options.seq, src)
    bundle, unit = read_foreign(src, info.name, options)
    up = _world_up(info, options.world_up, str(src), export=False)
    with replace_folder(out) as staging:
        try:
            write_bundle(bundle, staging)
            load_bundle(staging)  # the loader every stage uses accepts it, or nothing is replaced
        except InteropError:
            raise
        except BundleFormatError as exc:  # a value the format's reader let through: said of the file read
            detail = str(exc).split(": ", 1)[-1]
            raise InteropError(f"{src}: read as {info.name}, gives what a bundle may not hold: {detail}") from None
    return ImportResult(out=out, format=info.name, cameras=len(bundle.cameras), unit=unit, world_up=up)
