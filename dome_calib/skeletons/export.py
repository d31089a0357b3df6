"""``dome-calib export-people``: a body3DScene folder -> TRC (one file per person), C3D (one file for the capture)
or BVH (one file per person) in a new folder, staged and renamed into place (nothing half-written, nothing stale).

Each format's layout, units and axes: :mod:`~dome_calib.skeletons.trc`, :mod:`~dome_calib.skeletons.c3d`,
:mod:`~dome_calib.skeletons.bvh`; the folder is read by :func:`~dome_calib.skeletons.scenes.read_people`.
"""
from __future__ import annotations

import logging
import re
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from fractions import Fraction
from pathlib import Path
from typing import Literal

from dome_calib.io_utils import atomic_folder, foreign_names, output_folder, refuse_output_among_inputs
from dome_calib.options import AtLeast, PosFraction, options
from dome_calib.schema import NonNegFinite
from dome_calib.skeletons.bvh import write_bvh
from dome_calib.skeletons.c3d import write_c3d
from dome_calib.skeletons.errors import PeopleFileError
from dome_calib.skeletons.scenes import People, read_people
from dome_calib.skeletons.trc import write_trc

logger = logging.getLogger(__name__)

C3D_FILE = "people.c3d"
_OURS = re.compile(r".+_P\d+_-?\d+--?\d+\.trc|person\d+\.bvh|people\.c3d")


class PeopleFormat(StrEnum):
    trc = "trc"
    c3d = "c3d"
    bvh = "bvh"


@options
class ExportPeopleOptions:
    """``min_confidence``: joints below it are written as missing (default 0: every reconstructed joint);
    ``fps``: the frame rate to write (default: the files' ``fpsType``, else measured from their times);
    ``ids``: only these people (default: everybody); ``trial``: the TRC files' name before ``_P<id>_<first>-<last>``
    (default: the folder's name); ``fill_gaps``: TRC markers missing for at most this many frames are filled as
    Pose2Sim fills its own (:func:`~dome_calib.skeletons.trc.fill_gaps`; 0: every missing joint stays missing);
    ``unit``: the BVH files' length unit (metres: one Blender unit)."""

    min_confidence: NonNegFinite = 0.0
    fps: PosFraction | None = None
    ids: list[AtLeast(0)] | None = None
    trial: str | None = None
    fill_gaps: AtLeast(0) = 20
    unit: Literal["m", "cm", "mm"] = "m"


@dataclass(frozen=True)
class ExportSummary:
    out: Path
    files: list[Path]
    people: int
    frames: int
    fps: Fraction
    joints_written: int
    joints_missing: int


def check_export_folder(folder: str | Path) -> Path:
    """The output folder may be absent, empty or hold only an earlier export's files: it is replaced whole."""
    target = output_folder(folder)
    other = foreign_names(target, _OURS.fullmatch)
    if other:
        raise PeopleFileError(f"{folder}: holds {other[0]!r}, which export-people did not write; the folder is "
                              "replaced as a whole, so give a new folder or an earlier export's")
    return target


def trial_name(trial: str | None, folder: Path) -> str:
    """The TRC files' trial name: given (a file name's part: no path separator, not empty), else the folder's name."""
    name = Path(folder).resolve().name if trial is None else trial
    if not name or name in (".", "..") or "/" in name or "\\" in name or "\0" in name:
        raise PeopleFileError(f"--trial {trial!r}: expected a name for the files (no path separator)")
    return name


def parse_ids(text: str | None) -> list[int] | None:
    """``"0,3,7"`` -> [0, 3, 7]; None -> None (everybody)."""
    if not text:
        return None
    try:
        return sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise PeopleFileError(f"--ids {text!r}: expected person ids such as 0,3,7") from None


def parse_fps(text: str | None) -> Fraction | None:
    """``"25"``, ``"30000/1001"`` -> Fraction; None -> None (the files' rate)."""
    if text is None:
        return None
    try:
        fps = Fraction(text)
    except (ValueError, ZeroDivisionError):
        raise PeopleFileError(f"--fps {text!r}: not a frame rate (e.g. 25, 30 or 30000/1001)") from None
    if fps <= 0:
        raise PeopleFileError(f"--fps {text!r}: a frame rate must be > 0")
    return fps


def selected(people: People, options: ExportPeopleOptions) -> People:
    """``people`` with only the asked ids and the asked frame rate; PeopleFileError for an id nobody has."""
    tracks = people.tracks
    if options.ids is not None:
        unknown = sorted(set(options.ids) - set(tracks))
        if unknown:
            known = ", ".join(map(str, list(tracks)[:20])) + (" ..." if len(tracks) > 20 else "")
            raise PeopleFileError(f"{people.folder}: --ids: no person {unknown[0]} (ids: {known})")
        tracks = {i: tracks[i] for i in options.ids}
    return People(folder=people.folder, frames=people.frames, times_ms=people.times_ms, fps_type=people.fps_type,
                  fps=options.fps or people.fps, layout=people.layout, tracks=tracks, extra=people.extra,
                  body_model=people.body_model, lab_up=people.lab_up)


def export_people(folder: str | Path, to: PeopleFormat | str, out: str | Path,
                  options: ExportPeopleOptions | None = None, *,
                  progress: Callable[[int, int], None] | None = None) -> ExportSummary:
    """Write the people of the body3DScene ``folder`` to ``out`` (a folder, replaced whole) in format ``to``.

    Progress: ``progress(done, total)`` over the files read, then over those read and written.
    """
    options = options or ExportPeopleOptions()
    to = PeopleFormat(to)
    trial = trial_name(options.trial, Path(folder))
    refuse_output_among_inputs(out, [folder], whole_folder=True)
    check_export_folder(out)
    people = selected(read_people(folder, progress=progress), options)  # progress: files read
    ok = {pid: t.confidence >= max(options.min_confidence, 0.0) for pid, t in people.tracks.items()}
    n_files = len(people.frames)
    total = n_files + (1 if to is PeopleFormat.c3d else len(people.tracks))  # then the files written
    files: list[Path] = []
    with atomic_folder(out) as staging:
        if to is PeopleFormat.c3d:
            files.append(write_c3d(staging / C3D_FILE, people, ok))
        else:
            for k, (pid, track) in enumerate(people.tracks.items()):
                if to is PeopleFormat.trc:
                    files.append(write_trc(staging, people, track, ok[pid], trial=trial,
                                           fill_frames=options.fill_gaps))
                else:
                    files.append(write_bvh(staging, people, track, ok[pid], unit=options.unit))
                if progress is not None:
                    progress(n_files + k + 1, total)
    if progress is not None:
        progress(total, total)
    written = sum(int(v.sum()) for v in ok.values())
    missing = sum(int(v.size - v.sum()) for v in ok.values())
    logger.info("%s: %d people, %d files", to.value, len(people.tracks), len(files))
    return ExportSummary(out=Path(out), files=[Path(out) / f.name for f in files], people=len(people.tracks),
                         frames=len(people.frames), fps=people.fps, joints_written=written, joints_missing=missing)
