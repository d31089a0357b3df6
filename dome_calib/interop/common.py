"""What every interop format shares: the neutral camera record, units, name mapping, checks, the dropped-k3 figure.

A :class:`ForeignCamera` is one camera as another tool's file holds it: OpenCV pixel convention (the top-left
pixel's centre at (0, 0)), ``x_cam = R @ X + t`` with ``t`` in the FILE's length unit, distortion
``[k1, k2, p1, p2, k3]``. Each format module converts between this record and its own fields (axes, pixel
offset, rotation encoding); :func:`to_foreign` and :func:`to_bundle` convert between it and our bundle (units,
names). Errors are :class:`InteropError` of one line: ``<file>: camera <name>: field '<field>': <what>``.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import numpy as np

from dome_calib import panoptic_io as pio
from dome_calib.bundle import Bundle, Camera, camera_type_from_name
from dome_calib.camera import distort, pixels_to_normalized
from dome_calib.errors import BundleFormatError
from dome_calib.options import Field, options
from dome_calib.schema import PosFinite

#: Length units a file may use -> centimetres per unit.
CM_PER_UNIT = {"mm": 0.1, "cm": 1.0, "m": 100.0}
#: ``--unit`` choices: a length unit, or the calibration board's squares (needs the square size).
UNIT_CHOICES = (*CM_PER_UNIT, "squares")
_PANOPTIC_NAME = re.compile(r"(\d\d)_(\d\d)")
#: A file world whose up axis is the key -> the rotation M (det +1) with ``X_panoptic = M @ X_file``: the axis
#: becomes -y (Panoptic up), and x stays x where it can (z up: the usual z-up-to-y-down turn about x).
PANOPTIC_FROM_UP = {
    "-y": np.eye(3),
    "+y": np.diag([1.0, -1.0, -1.0]),
    "+z": np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]),
    "-z": np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]),
    "+x": np.array([[0, 1.0, 0], [-1.0, 0, 0], [0, 0, 1.0]]),
    "-x": np.array([[0, -1.0, 0], [1.0, 0, 0], [0, 0, 1.0]]),
}


class InteropError(BundleFormatError):
    """A file of another tool cannot be read or written as asked (names file, camera and field)."""


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
    """``unit``: length unit of the written translations (None: the format's default); ``names``: our name ->
    the name written; ``binary``: COLMAP binary (else text) files."""

    unit: str | None = None
    world_up: str | None = None  # the written world's up axis ("+z", "-y", ...); None: the format's default
    names: dict[str, str] = field(default_factory=dict)
    binary: bool = True


@options
class ImportOptions:
    """``unit``: length unit of the file when the format does not state it ("squares" needs
    ``square_size_mm``); ``names``: name in the file -> our name; ``seq``: the bundle's sequence name."""

    unit: str | None = None
    square_size_mm: PosFinite | None = None
    world_up: str | None = None  # the file world's up axis, turned into Panoptic -y; None: the format's default
    names: dict[str, str] = field(default_factory=dict)
    seq: Annotated[str, Field(min_length=1)] = "imported"


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
    """``"old=new,old2=new2"`` -> {old: new}. ValueError on a malformed pair or a name given twice."""
    mapping: dict[str, str] = {}
    for pair in filter(None, (p.strip() for p in (text or "").split(","))):
        old, sep, new = (s.strip() for s in pair.partition("="))
        if not sep or not old or not new:
            raise InteropError(f"--names: '{pair}' is not OLD=NEW")
        if old in mapping:
            raise InteropError(f"--names: '{old}' mapped twice")
        mapping[old] = new
    return mapping


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
            raise InteropError(f"{where}: camera {old}: field 'name': '{new}' would be a duplicate name")
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


def exact_rotation(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The nearest rotation to ``R`` (3, 3) and the translation that keeps the camera centre where it was.

    A bundle's R is orthonormal only to the digits its file keeps (~1e-10 for the real Panoptic files); every other
    format stores a true rotation (quaternion, Rodrigues vector). Keeping the centre makes the change an angle of
    that size (~1e-7 px) at every depth, instead of an offset of |R' - R| |X| that grows near the camera.
    """
    U, _, Vt = np.linalg.svd(R)
    R_exact = U @ Vt
    centre = -np.linalg.solve(R, t)
    return R_exact, -R_exact @ centre


def panoptic_from_up(world_up: str, where: str) -> np.ndarray:
    """(3, 3) rotation ``X_panoptic = M @ X_file`` for a file world whose up axis is ``world_up``."""
    key = world_up if world_up[0] in "+-" else f"+{world_up}"
    if key not in PANOPTIC_FROM_UP:
        raise InteropError(f"{where}: --world-up {world_up!r}: expected one of x, -x, y, -y, z, -z")
    return PANOPTIC_FROM_UP[key]


def to_foreign(bundle: Bundle, options: ExportOptions, unit: str, world_up: str, where: str) -> list[ForeignCamera]:
    """Our cameras, in the bundle's order, as foreign records in a world whose up axis is ``world_up``, with
    translations in ``unit`` and names mapped (rotations made exact, centres kept: :func:`exact_rotation`)."""
    names = rename(list(bundle.cameras), options.names, where)
    scale = 1.0 / cm_per_unit(unit, None, where)
    M = panoptic_from_up(world_up, where)
    out = []
    for new, c in zip(names, bundle.cameras.values()):
        R, t_cm = exact_rotation(c.R, c.t_cm)
        out.append(ForeignCamera(name=new, size=c.resolution, K=c.K.copy(), dist=c.dist.copy(), R=R @ M,
                                 t=t_cm * scale))
    return out


def checked(cam: ForeignCamera, path: Path) -> ForeignCamera:
    """Validate a camera read from ``path`` with the bundle reader's own checks (the same messages): finite
    numbers, positive focal lengths, zero skew, a rotation (orthonormal, det +1; re-orthonormalised with a warning
    when written with ~6 decimals)."""
    w = pio._Where(path).at(f"camera {pio._label(cam.name)}")
    K = w.numbers(np.asarray(cam.K).tolist(), "K", ((3, 3),), pio.LIMITS["K_px"])
    R = w.rotation(w.numbers(np.asarray(cam.R).tolist(), "R", ((3, 3),), 2.0), "R")
    out = ForeignCamera(
        name=cam.name,
        size=w.size(list(cam.size), "size"),
        K=w.camera_matrix(K, "K"),
        dist=w.numbers(np.asarray(cam.dist).tolist(), "dist", ((5,),), pio.LIMITS["dist"]),
        R=R,
        t=w.numbers(np.asarray(cam.t).tolist(), "t", ((3,),), pio.LIMITS["t_cm"]),
    )
    w.warn_repaired()
    return out


def to_bundle(cams: list[ForeignCamera], cm_per_file_unit: float, world_up: str, options: ImportOptions,
              path: Path, source: str) -> Bundle:
    """Foreign cameras (already :func:`checked`) -> a bundle in their order, translations in cm, the file's up axis
    ``world_up`` turned to -y (Panoptic), names mapped. Camera type, panel and node come from Panoptic names
    (``PP_NN``); other names are VGA, panel 0, node 0."""
    M = panoptic_from_up(world_up, str(path))
    seen: set[str] = set()
    for cam in cams:
        if cam.name in seen:
            raise InteropError(f"{path}: camera {pio._label(cam.name)}: field 'name': duplicate camera name")
        seen.add(cam.name)
    names = rename([c.name for c in cams], options.names, str(path))
    cameras: dict[str, Camera] = {}
    for name, cam in zip(names, cams):
        m = _PANOPTIC_NAME.fullmatch(name)
        cameras[name] = Camera(name=name, type=camera_type_from_name(name), resolution=cam.size, K=cam.K,
                               dist=cam.dist, R=cam.R @ M.T, t_cm=cam.t * cm_per_file_unit,
                               panel=int(m.group(1)) if m else 0, node=int(m.group(2)) if m else 0)
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
