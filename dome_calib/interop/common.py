"""What every interop format shares: the neutral camera record, options and results, units, axes, names, the
dropped-term figure.

A :class:`ForeignCamera` is one camera as another tool's file holds it: OpenCV pixel convention (the top-left
pixel's centre at (0, 0)), ``x_cam = R @ X + t`` with ``t`` in the FILE's length unit and ``X`` in the file's world,
distortion ``[k1, k2, p1, p2, k3]``. Each format module converts between this record and its own fields (pixel
offset, rotation encoding, camera axes); :func:`to_foreign` and :func:`to_bundle` convert between it and our bundle
(units, world axes, names). Errors are :class:`InteropError` of one line naming the file, the camera and the field.
"""
from __future__ import annotations

import logging
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from dome_calib.bundle import Bundle, Camera, camera_type_from_name
from dome_calib.camera import distort, pixels_to_normalized
from dome_calib.errors import BundleFormatError
from dome_calib.exact import matmul3, nearest_rotation, rotation_exact, transpose3
from dome_calib.interop.fields import ROTATION_EXACT_TOL, rotation_error
from dome_calib.interop.registry import UNIT_CHOICES
from dome_calib.lab_world import PANOPTIC_FROM_UP, import_record  # noqa: F401  (import_record: convert's, via here)
from dome_calib.options import AtLeast, Field, options
from dome_calib.schema import PLAIN_NAME_HELP, PosFinite, name_problem

logger = logging.getLogger(__name__)

#: Length units a file may use -> centimetres per unit.
CM_PER_UNIT = {"mm": 0.1, "cm": 1.0, "m": 100.0}
#: Largest plausible camera translation once in cm (10 km): beyond it the file's unit was not the one read.
LIMIT_T_CM = 1e6
_PANOPTIC_NAME = re.compile(r"(\d\d)_(\d\d)")
class InteropError(BundleFormatError):
    """A file of another tool cannot be read or written as asked (names file, camera and field)."""


def label(name: str) -> str:
    """A name from a file as messages show it: as is if short and printable, else quoted and cut."""
    return name if name.isprintable() and len(name) <= 40 else repr(name[:37] + "...")


@dataclass(kw_only=True)
class ForeignCamera:
    """One camera in another tool's terms. K (3, 3) px (OpenCV pixel centres); dist (5,) [k1, k2, p1, p2, k3];
    R (3, 3) cam_from_world; t (3,) in the file's unit; size (width_px, height_px)."""

    name: str
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray


@options
class ExportOptions:
    """``unit``: length unit of the written translations (None: the format's default); ``world_up``: the written
    world's up axis (None: the format's default); ``names``: our name -> the name written; ``binary``: COLMAP binary
    (else text) files; ``cameras``: only these cameras, in the bundle's order (None: every camera)."""

    unit: str | None = None
    world_up: str | None = None
    names: dict[str, str] = field(default_factory=dict)
    binary: bool = True
    cameras: list[Annotated[str, Field(min_length=1)]] | None = None


@options
class ImportOptions:
    """``unit``: length unit of the file when the format does not state it ("squares" needs ``square_size_mm``);
    ``world_up``: the file world's up axis, turned into ours (None: the format's default); ``names``: name in the
    file -> our name; ``seq``: the bundle's sequence name; ``image_size``: (width, height) px for files that do not
    record it (EasyMocap's calibration tools); ``binning``: pixels binned per image pixel along each axis (Qualisys
    video cameras filming in 540p on a 1080p sensor bin 2: Pose2Sim's ``binning_factor``; None: the file's own
    ``video_resolution`` where it has one, else 1)."""

    unit: str | None = None
    square_size_mm: PosFinite | None = None
    world_up: str | None = None
    names: dict[str, str] = field(default_factory=dict)
    seq: Annotated[str, Field(min_length=1)] = "imported"
    image_size: tuple[AtLeast(1), AtLeast(1)] | None = None
    binning: AtLeast(1) | None = None


@dataclass(kw_only=True)
class Read:
    """What a format module read: cameras in the file's order, the length unit the file states (None: it does
    not), the file to name in messages."""

    cameras: list[ForeignCamera]
    unit: str | None
    path: Path


@dataclass(kw_only=True)
class Written:
    """What a format module could not write: one line per loss, and per camera the pixels a dropped term moves the
    point seen at the image corner."""

    dropped: list[str] = field(default_factory=list)
    corner_shift_px: dict[str, float] = field(default_factory=dict)


@dataclass(kw_only=True)
class ExportResult:
    """What an export wrote and what it could not carry: ``dropped`` one line per loss, ``corner_shift_px`` the
    pixels a dropped term moves a point at the image corner, per camera (empty when nothing was dropped)."""

    format: str
    out: Path
    unit: str
    world_up: str
    cameras: int
    dropped: list[str] = field(default_factory=list)
    corner_shift_px: dict[str, float] = field(default_factory=dict)


def parse_names(text: str | None) -> dict[str, str]:
    """``"old=new,old2=new2"`` -> {old: new}. InteropError on a malformed pair or a name given twice."""
    mapping: dict[str, str] = {}
    for pair in filter(None, (p.strip() for p in (text or "").split(","))):
        old, sep, new = (s.strip() for s in pair.partition("="))
        if not sep or not old or not new:
            raise InteropError(f"--names: '{pair}' is not OLD=NEW")
        if old in mapping:
            raise InteropError(f"--names: '{old}' mapped twice")
        mapping[old] = new
    return mapping


def parse_image_size(text: str | None) -> tuple[int, int] | None:
    """``"1920x1080"`` -> (1920, 1080); InteropError naming the option otherwise."""
    if not text:
        return None
    match = re.fullmatch(r"\s*(\d{1,6})\s*[xX]\s*(\d{1,6})\s*", text)
    if match is None or not all(0 < int(v) <= 100_000 for v in match.groups()):
        raise InteropError(f"--image-size {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 1920x1080")
    return int(match.group(1)), int(match.group(2))


def rename(names: list[str], mapping: dict[str, str], where: str) -> list[str]:
    """Apply ``mapping`` to ``names`` (unmapped names kept); refuse unknown sources and duplicate results."""
    unknown = sorted(set(mapping) - set(names))
    if unknown:
        raise InteropError(f"{where}: --names maps '{unknown[0]}', which is not a camera there "
                           f"(cameras: {', '.join(names[:4])}{', ...' if len(names) > 4 else ''})")
    out = [mapping.get(n, n) for n in names]
    seen: set[str] = set()
    for old, new in zip(names, out):
        if new in seen:
            raise InteropError(f"{where}: camera {label(old)}: name '{new}' would be a duplicate name")
        seen.add(new)
    return out


def cm_per_unit(unit: str | None, square_size_mm: float | None, where: str) -> float:
    """Centimetres per file unit; "squares" needs the board's square size in mm."""
    if unit == "squares":
        if square_size_mm is None or not square_size_mm > 0:
            raise InteropError(f"{where}: --unit squares needs --square-size-mm (the board's square side, mm)")
        return 0.1 * square_size_mm
    if unit not in CM_PER_UNIT:
        raise InteropError(f"{where}: unknown unit {unit!r} (choose one of {', '.join(UNIT_CHOICES)})")
    return CM_PER_UNIT[unit]


def to_foreign(bundle: Bundle, options: ExportOptions, unit: str, world_up: str, where: str) -> list[ForeignCamera]:
    """Our cameras, in the bundle's order, as foreign records in a world whose up axis is ``world_up``, with
    translations in ``unit`` and names mapped (rotations made exact, centres kept:
    :func:`dome_calib.exact.rotation_exact`; every number through :mod:`~dome_calib.exact`'s
    basic operations, so every machine computes the same bits)."""
    names = rename(list(bundle.cameras), options.names, where)
    scale = 1.0 / cm_per_unit(unit, None, where)
    M = PANOPTIC_FROM_UP[world_up]
    out = []
    for new, c in zip(names, bundle.cameras.values()):
        R, t_cm = rotation_exact(c.R, c.t_cm)
        out.append(ForeignCamera(name=new, size=c.resolution, K=c.K.copy(), dist=c.dist.copy(), R=matmul3(R, M),
                                 t=t_cm * scale))
    return out


def to_bundle(cams: list[ForeignCamera], cm_per_file_unit: float, world_up: str, options: ImportOptions,
              path: Path, source: str) -> Bundle:
    """Foreign cameras (read through their format's schema) -> a bundle in their order, translations in cm, the
    file's up axis ``world_up`` turned to -y (Panoptic), names mapped. Camera type, panel and node come from
    Panoptic names (``PP_NN``); other names are VGA, panel 0, node 0. Rotations written with few decimals are
    replaced by the nearest rotation (one warning per file)."""
    M = PANOPTIC_FROM_UP[world_up]
    seen: set[str] = set()
    for cam in cams:
        if cam.name in seen:
            raise InteropError(f"{path}: camera {label(cam.name)}: name: duplicate camera name")
        seen.add(cam.name)
    names = rename([c.name for c in cams], options.names, str(path))
    for old, name in zip([c.name for c in cams], names):  # a camera's name becomes file names: one rule for all
        problem = name_problem(name)
        if problem is not None:
            raise InteropError(f"{path}: camera {label(old)}: name {label(name)} {problem}: a camera name is a plain "
                               f"name ({PLAIN_NAME_HELP}); give --names {label(old)}=NEW")
    cameras: dict[str, Camera] = {}
    repaired = []
    for name, cam in zip(names, cams):
        R = np.asarray(cam.R, dtype=float)
        if rotation_error(R) > ROTATION_EXACT_TOL:
            repaired.append(cam.name)
            R = nearest_rotation(R)
        t_cm = np.asarray(cam.t, dtype=float) * cm_per_file_unit
        if np.abs(t_cm).max() > LIMIT_T_CM:
            raise InteropError(f"{path}: camera {label(cam.name)}: translation {np.abs(t_cm).max() / 1e5:.3g} km "
                               "from the origin: not a calibration in the unit read (give the right --unit)")
        m = _PANOPTIC_NAME.fullmatch(name)
        cameras[name] = Camera(name=name, type=camera_type_from_name(name), resolution=cam.size,
                               K=np.asarray(cam.K, dtype=float), dist=np.asarray(cam.dist, dtype=float),
                               R=matmul3(R, transpose3(M)), t_cm=t_cm, panel=int(m.group(1)) if m else 0,
                               node=int(m.group(2)) if m else 0)
    if repaired:
        logger.warning("%s: %d rotation(s) orthonormal only to ~1e-6 (%s%s), as when written with few decimals: "
                       "replaced by the nearest rotation", path, len(repaired), ", ".join(repaired[:4]),
                       ", ..." if len(repaired) > 4 else "")
    return Bundle(seq=options.seq, cameras=cameras, calib_data_source=source)


def corner_shift_px(cam: ForeignCamera, kept: np.ndarray) -> float:
    """Largest pixel distance, over the four image corners, between where the full model and the model with only
    ``kept`` (5,) distortion terms put the point seen at that corner. The point is found by undistorting the
    corner with the full model; where that has no solution (beyond the lens's monotonic range) the corner's
    pinhole direction is used instead."""
    w, h = cam.size
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
    f, c = np.array([cam.K[0, 0], cam.K[1, 1]]), np.array([cam.K[0, 2], cam.K[1, 2]])
    xn = pixels_to_normalized(corners, np.concatenate([f, c]), cam.dist)
    pinhole = (corners - c) / f
    xn = np.where(np.isnan(xn), pinhole, xn)
    shift = (distort(xn, cam.dist) - distort(xn, np.asarray(kept, dtype=float))) * f
    return float(np.linalg.norm(shift, axis=1).max())


def five_terms(terms: Any) -> np.ndarray:
    """Distortion terms as a file writes them (OpenCV's order, k1 k2 p1 p2 [k3]: 4 or 5, its schema says which) ->
    :class:`ForeignCamera`'s (5,), k3 0 where not written."""
    dist = np.zeros(5)
    dist[: len(terms)] = terms
    return dist


def folder_files(path: Path, suffix: str, what: str) -> list[Path]:
    """The ``suffix`` files of a calibration written as a folder of one file per camera, in name order; one line
    naming ``path`` when it is no folder or holds none (``what``: the format's calibration, "a bioCV calibration")."""
    if not path.is_dir():
        raise InteropError(f"{path}: not a folder ({what} is a folder of {suffix} files)")
    files = sorted(p for p in path.iterdir() if p.suffix == suffix and p.is_file())
    if not files:
        raise InteropError(f"{path}: no {suffix} file")
    return files


def dropped_terms_line(shifts: dict[str, float], what: str) -> str:
    """One line saying what dropping ``what`` costs at the image corners (the worst camera named)."""
    worst = max(shifts, key=shifts.get)
    return (f"{what} dropped for {len(shifts)} camera(s): the point seen at the image corner moves by up to "
            f"{shifts[worst]:.3f} px (camera {worst})")


def xml_root(path: Path, kind: str) -> ET.Element:
    """The root element of an XML calibration file (``kind``: what it should be, e.g. "a Vicon .xcp"); InteropError
    of one line naming the file when it is missing, a folder or not XML."""
    try:
        return ET.fromstring(path.read_bytes())
    except FileNotFoundError:
        raise InteropError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise InteropError(f"{path}: is a folder, expected {kind} file") from None
    except ET.ParseError as exc:
        raise InteropError(f"{path}: not an XML file ({exc}); expected {kind} calibration") from None


def video_cameras(path: Path, cameras: list[Any], is_video: Callable[[Any], bool], name: Callable[[Any], str],
                  what: str) -> list[Any]:
    """The video cameras of a motion-capture calibration in Pose2Sim's order: natural order of their names (``cam2``
    before ``cam10``: digits compared as numbers, the rest without case). None is one line (``what``: how a video
    camera is told apart); marker-only cameras are left out in one warning, as Pose2Sim leaves them out."""
    def natural(text: str) -> list[Any]:
        return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", text)]

    video = sorted((c for c in cameras if is_video(c)), key=lambda c: natural(name(c)))
    if not video:
        raise InteropError(f"{path}: no video camera ({what}): nothing to import")
    left_out = [name(c) for c in cameras if not is_video(c)]
    if left_out:
        logger.warning("%s: %d marker-only camera(s) left out, as Pose2Sim does (%s)", path, len(left_out),
                       ", ".join(left_out[:4]))
    return video
