"""``dome-calib export-people``: a body3DScene folder -> TRC (one file per person), C3D (one file for the capture)
or BVH (one file per person) in a new folder, staged and renamed into place (nothing half-written, nothing stale).

Each format's layout, units and axes: :mod:`~dome_calib.skeletons.trc`, :mod:`~dome_calib.skeletons.c3d`,
:mod:`~dome_calib.skeletons.bvh`; the folder is read by :func:`~dome_calib.skeletons.scenes.read_people`.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import StrEnum
from fractions import Fraction
from pathlib import Path
from typing import Literal

from dome_calib.ownership import claim_folder, replace_folder
from dome_calib.options import AtLeast, PosFraction, options
from dome_calib.schema import NonNegFinite
from dome_calib.skeletons.bvh import write_bvh
from dome_calib.skeletons.c3d import write_c3d
from dome_calib.skeletons.errors import PeopleFileError
from dome_calib.skeletons.scenes import MAX_DENSE_VALUES, People, rate_problem, read_people, with_rate
from dome_calib.skeletons.trc import write_trc

logger = logging.getLogger(__name__)

C3D_FILE = "people.c3d"


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


def check_export_folder(folder: str | Path, inputs: list[str | Path] = ()) -> Path:
    """The output folder is replaced whole: absent, empty or what dome-calib wrote, unchanged, and holding no
    input (:func:`dome_calib.ownership.claim_folder`)."""
    return claim_folder(folder, inputs=inputs)


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
    problem = rate_problem(fps)
    if problem is not None:
        raise PeopleFileError(f"--fps {text[:40]!r}: {problem}")
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
    return with_rate(replace(people, tracks=tracks), options.fps)


def check_dense(people: People, to: PeopleFormat) -> None:
    """C3D holds every point at every frame number from the first file's to the last's, BVH every joint of a
    person from its first frame to its last: refuse before work a span that no memory holds (frame numbers 0 and
    999999999999 in one folder), naming the frames and the limit (:data:`MAX_DENSE_VALUES`)."""
    J = len(people.joints)
    if to is PeopleFormat.c3d:
        spans = [(int(people.frames[-1] - people.frames[0]) + 1, J * len(people.tracks), "the capture")]
    elif to is PeopleFormat.bvh:
        spans = [(int(people.frames[t.rows[-1]] - people.frames[t.rows[0]]) + 1, J, f"person {pid}")
                 for pid, t in people.tracks.items()]
    else:
        return  # TRC: one row per file
    for frames, points, who in spans:
        if frames * points > MAX_DENSE_VALUES:
            hours = frames / float(people.fps) / 3600
            raise PeopleFileError(f"{people.folder}: {who} spans {frames} frame numbers ({hours:.3g} h "
                                  f"at {float(people.fps):g} fps) x {points} points: a {to.value} file holds every "
                                  f"frame between, more than {MAX_DENSE_VALUES} values; export fewer people (--ids), "
                                  "a folder of one take, or --to trc")


def export_people(folder: str | Path, to: PeopleFormat | str, out: str | Path,
                  options: ExportPeopleOptions | None = None, *,
                  progress: Callable[[int, int], None] | None = None) -> ExportSummary:
    """Write the people of the body3DScene ``folder`` to ``out`` (a folder, replaced whole) in format ``to``.

    Progress: ``progress(done, total)`` over the files read, then over those read and written.
    """
    options = options or ExportPeopleOptions()
    to = PeopleFormat(to)
    trial = trial_name(options.trial, Path(folder))
    check_export_folder(out, [folder])
    people = selected(read_people(folder, progress=progress), options)  # progress: files read
    check_dense(people, to)
    ok = {pid: t.confidence >= max(options.min_confidence, 0.0) for pid, t in people.tracks.items()}
    n_files = len(people.frames)
    total = n_files + (1 if to is PeopleFormat.c3d else len(people.tracks))  # then the files written
    files: list[Path] = []
    with replace_folder(out) as staging:
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
