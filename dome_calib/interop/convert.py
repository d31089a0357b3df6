"""Export a bundle to another tool's calibration files, and import theirs into a bundle (the commands' stages).

Every output is staged and renamed into place (:mod:`dome_calib.io_utils`): on any error nothing is written.
An imported bundle is written by :func:`dome_calib.bundle_io.write_bundle` and read back with
:func:`dome_calib.bundle_io.load_bundle` (the loader every stage uses) before it replaces anything.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import bundle_seq, load_bundle, write_bundle
from dome_calib.interop import aniposelib, colmap, easymocap, nerfstudio, pose2sim
from dome_calib.interop.common import (ExportOptions, ExportResult, ForeignCamera, ImportOptions, InteropError,
                                       checked, cm_per_unit, to_bundle, to_foreign)
from dome_calib.io_utils import atomic_folder, atomic_path, refuse_output_among_inputs

logger = logging.getLogger(__name__)


class Format(StrEnum):
    COLMAP = "colmap"
    ANIPOSELIB = "aniposelib"
    POSE2SIM = "pose2sim"
    EASYMOCAP = "easymocap"
    NERFSTUDIO = "nerfstudio"


#: Length unit each format fixes (None: the file does not say it) and the export's default.
FIXED_UNIT = {Format.POSE2SIM: pose2sim.UNIT, Format.EASYMOCAP: easymocap.UNIT}
DEFAULT_UNIT = {Format.COLMAP: "m", Format.ANIPOSELIB: aniposelib.DEFAULT_UNIT, Format.POSE2SIM: pose2sim.UNIT,
                Format.EASYMOCAP: easymocap.UNIT, Format.NERFSTUDIO: nerfstudio.DEFAULT_UNIT}
#: The world's up axis in each format's files: Pose2Sim's is z (its TRC writer turns z-up into OpenSim's y-up,
#: ``common.py: zup2yup``); nerfstudio's z up is written as its own ``applied_transform`` (see nerfstudio.py);
#: the others have no convention: our world is kept (up = -y).
DEFAULT_UP = {Format.POSE2SIM: "+z"}
#: Files a folder output may already hold and still be replaced whole (anything else: refused).
_FOLDER_FILES = {Format.COLMAP: {f"{k}.{e}" for k in colmap.MODEL_FILES for e in ("bin", "txt")},
                 Format.EASYMOCAP: set(easymocap.FILES)}


@dataclass(kw_only=True)
class ImportResult:
    out: Path
    format: str
    cameras: int
    unit: str  # the source file's length unit (stated by it, or given with --unit)
    world_up: str  # the source world's up axis, turned to Panoptic -y


def _replaceable_folder(out: Path, allowed: set[str] | None, what: str) -> None:
    """Refuse to replace a folder that holds anything but ``allowed`` files (None: a bundle or nothing)."""
    if not out.is_dir():
        return
    entries = sorted(p.name for p in out.iterdir())
    if allowed is None:
        if entries and bundle_seq(out) is None:
            raise InteropError(f"{out}: a folder that holds no bundle ({', '.join(entries[:3])}, ...); give a new or "
                               "empty folder, or a bundle folder to replace")
        return
    other = [e for e in entries if e not in allowed]
    if other:
        raise InteropError(f"{out}: holds {other[0]}, which is not part of {what}; give a new or empty folder")


def _export_unit(fmt: Format, unit: str | None, where: str) -> str:
    if fmt in FIXED_UNIT and unit not in (None, FIXED_UNIT[fmt]):
        raise InteropError(f"{where}: {fmt} files are in {FIXED_UNIT[fmt]} by the format's definition; "
                           f"--unit {unit} is not possible")
    unit = unit or DEFAULT_UNIT[fmt]
    if unit == "squares":
        raise InteropError(f"{where}: --unit squares is for import only (the bundle is in cm)")
    cm_per_unit(unit, None, where)
    return unit


def _world_up(fmt: Format, world_up: str | None, where: str) -> str:
    if fmt is Format.NERFSTUDIO and world_up is not None:
        raise InteropError(f"{where}: nerfstudio worlds are z up, recorded in the file's applied_transform; "
                           "--world-up does not apply")
    return world_up or DEFAULT_UP.get(fmt, "-y")


def _not_carried(bundle: Bundle, fmt: Format) -> list[str]:
    lines = []
    if bundle.kinect is not None:
        lines.append(f"Kinect depth-colour calibration (kcalibration, {len(bundle.kinect.sensors)} sensors): no place "
                     f"in {fmt}, not written")
    if bundle.sync is not None:
        lines.append(f"sync tables: no place in {fmt}, not written")
    if fmt is Format.COLMAP:
        lines.append("points3D written empty: the bundle keeps its residuals, not the observed points")
    return lines


def export_bundle(bundle_folder: str | Path, fmt: Format | str, out: str | Path,
                  options: ExportOptions | None = None) -> ExportResult:
    """Write the bundle in ``bundle_folder`` as ``fmt`` to ``out`` (a folder for colmap / easymocap, else a file).

    Returns what was written, the unit, and what the format could not carry (with the corner shift, px, of a
    dropped k3 per camera).
    """
    options = options or ExportOptions()
    fmt = Format(fmt)
    out = Path(out)
    refuse_output_among_inputs(out, [bundle_folder, *Path(bundle_folder).glob("*")], whole_folder=True)
    bundle = load_bundle(bundle_folder)
    unit = _export_unit(fmt, options.unit, str(out))
    up = _world_up(fmt, options.world_up, str(out))
    cams = to_foreign(bundle, options, "cm" if fmt is Format.NERFSTUDIO else unit, up, str(bundle_folder))
    up = "+z" if fmt is Format.NERFSTUDIO else up
    result = ExportResult(format=str(fmt), out=out, unit=unit, world_up=up, cameras=len(cams),
                          dropped=_not_carried(bundle, fmt))
    if fmt in _FOLDER_FILES:
        _replaceable_folder(out, _FOLDER_FILES[fmt], f"a {fmt} export")
        with atomic_folder(out) as staging:
            if fmt is Format.COLMAP:
                colmap.write_colmap(cams, staging, binary=options.binary)
            else:
                easymocap.write_easymocap(cams, staging)
        return result
    with atomic_path(out) as tmp:
        if fmt is Format.ANIPOSELIB:
            aniposelib.write_aniposelib(cams, tmp, unit)
        elif fmt is Format.POSE2SIM:
            clash = [c.name for c in cams if c.name in aniposelib.NOT_CAMERAS]
            if clash:
                raise InteropError(f"camera {clash[0]}: field 'name': Pose2Sim reads a table of that name as "
                                   "settings, not a camera; rename it with --names")
            result.corner_shift_px = pose2sim.write_pose2sim(cams, tmp)
            if result.corner_shift_px:
                worst = max(result.corner_shift_px, key=result.corner_shift_px.get)
                result.dropped.append(
                    f"k3 dropped for {len(result.corner_shift_px)} camera(s) (Pose2Sim holds [k1, k2, p1, p2]): the "
                    f"point seen at the image corner moves by up to {result.corner_shift_px[worst]:.3f} px "
                    f"(camera {worst})")
        else:
            nerfstudio.write_nerfstudio(cams, tmp, unit=unit, cm_per_unit=cm_per_unit(unit, None, str(out)))
    return result


def _read(fmt: Format, src: Path) -> tuple[list[ForeignCamera], str | None, Path]:
    """The file's cameras, the unit it states (None: it does not), and the path to name in messages."""
    if fmt is Format.COLMAP:
        return colmap.read_colmap(src), None, src
    if fmt is Format.EASYMOCAP:
        return easymocap.read_easymocap(src), easymocap.UNIT, src
    if src.is_dir():
        default = {Format.ANIPOSELIB: "calibration.toml", Format.NERFSTUDIO: "transforms.json"}.get(fmt)
        if default is None or not (src / default).is_file():
            raise InteropError(f"{src}: a folder; give the {fmt} calibration file itself")
        src = src / default
    if fmt is Format.ANIPOSELIB:
        cams, unit = aniposelib.read_aniposelib(src)
        return cams, unit, src
    if fmt is Format.POSE2SIM:
        return pose2sim.read_pose2sim(src), pose2sim.UNIT, src
    cams, unit = nerfstudio.read_nerfstudio(src)
    return cams, unit, src


def read_foreign(src: str | Path, fmt: Format | str, options: ImportOptions | None = None) -> tuple[Bundle, str]:
    """Read another tool's calibration into a bundle (nothing written; translations converted to cm, the file's up
    axis turned to Panoptic -y) and name the source's length unit."""
    options = options or ImportOptions()
    fmt = Format(fmt)
    cams, stated, path = _read(fmt, Path(src))
    if stated is not None and options.unit is not None and options.unit != stated:
        raise InteropError(f"{path}: the file states its unit ({stated}); --unit {options.unit} contradicts it")
    unit = stated or options.unit
    if unit is None:
        raise InteropError(f"{path}: a {fmt} calibration does not record its length unit; give --unit "
                           "(mm, cm, m, or squares with --square-size-mm)")
    scale = cm_per_unit(unit, options.square_size_mm, str(path))
    up = _world_up(fmt, options.world_up, str(path))
    cams = [checked(c, path) for c in cams]
    turned = "" if up == "-y" else f", its up axis {up} turned to -y"
    source = f"imported from {fmt} ({path.name}, unit {unit}{turned})"
    return to_bundle(cams, scale, up, options, path, source), unit


def import_calibration(src: str | Path, fmt: Format | str, out: str | Path,
                       options: ImportOptions | None = None) -> ImportResult:
    """Import ``src`` as ``fmt`` into the bundle folder ``out`` (replaced whole; a non-bundle folder refused)."""
    options = options or ImportOptions()
    out = Path(out)
    refuse_output_among_inputs(out, [src], whole_folder=True)
    bundle, unit = read_foreign(src, fmt, options)
    up = _world_up(Format(fmt), options.world_up, str(src))
    _replaceable_folder(out, None, "a bundle")
    with atomic_folder(out) as staging:
        write_bundle(bundle, staging)
        load_bundle(staging)  # the loader every stage uses accepts it, or nothing is replaced
    return ImportResult(out=out, format=str(Format(fmt)), cameras=len(bundle.cameras), unit=unit,
                        world_up=up)
