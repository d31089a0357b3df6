"""``dome-calib people-page``: the people page of a body3DScene folder (:mod:`dome_calib.skeletons.page`), with the
calibration's cameras (the dome, the reprojected bodies) and the cameras' OpenPose detections on universal time
when a bundle and a detections folder are given. A pipeline: it joins the reconstruction room (the detections
reader, the cameras' streams) and the people-out room (the folder, the page).

Detections: the folder ``dome-calib reconstruct`` reads (one sub-folder per camera, ``--camera-map``,
``--body-model``); each camera's frames are put on universal time by the bundle's sync tables (without them, frame /
the folder's frame rate, as reconstruct does with ``--fps``); only the frames within the people's span are read.
The page ``reconstruct`` writes shows the detections as the run used them (its kept float32 values,
:class:`~dome_calib.recon.people.detection_cache.KeptDetections`: no file is read again); ``dome-calib people-page``
reads the files.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import load_bundle
from dome_calib.ownership import claim_file
from dome_calib.recon.errors import ReconError
from dome_calib.recon.openpose_io import body_model_of, index_openpose_folder, parse_camera_map, read_openpose_files
from dome_calib.recon.people.detection_cache import KeptDetections
from dome_calib.recon.people.scene_io import StagedPeople, offset_words, read_camera_report
from dome_calib.recon.streams import stream_of_camera
from dome_calib.skeletons.errors import PeopleFileError
from dome_calib.skeletons.page import MAX_DETECTED_PEOPLE, PAGE_FILE, CameraDetections, write_people_page
from dome_calib.skeletons.scenes import People, people_of_scenes, read_people, with_rate

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PeoplePageSummary:
    page: Path
    people: int
    frames: int
    cameras: int
    detection_cameras: list[str]
    notes: list[str]


def camera_times_ms(bundle: Bundle, camera: str, frames: np.ndarray, people: People) -> np.ndarray:
    """Universal time (ms) of a camera's frames: its stream's sync table (NaN for a frame the table lacks), or
    frame / the people's frame rate for a bundle without sync tables."""
    if bundle.sync is None:
        return frames * (1000.0 / float(people.fps))
    _, table = stream_of_camera(bundle, camera)
    inside = np.isin(frames, table.index)
    out = np.full(len(frames), np.nan)
    out[inside] = table.times_of(frames[inside])
    return out


def camera_flags(report: dict | None) -> list[dict]:
    """cameras.json's report (:func:`~dome_calib.recon.people.scene_io.camera_report`) -> one row per camera for the
    page, flagged cameras first, then in name order: ``camera``, ``reprojection_px``, ``outvoted_share``, ``offset`` ("15 px to the left
    (-15.0, 0.3)", or "" without an offset), ``flagged`` and ``verdict`` (the camera's offset note where the report
    has one, "flagged" for the report's other criteria, "agrees" otherwise, with its note where ``--correct-offsets``
shifted it). Plain data: the page puts every string
    in as text."""
    if not report:
        return []
    flagged = set(report.get("flagged", []))
    rows = []
    for name in sorted(report.get("cameras", {}), key=lambda n: (n not in flagged, n)):
        cam = report["cameras"][name]
        said = f"camera {name}: "
        notes = [n[len(said):] for n in report.get("notes", []) if n.startswith(said)]
        off = cam.get("median_offset_px")
        offset = "" if off is None else f"{offset_words(np.asarray(off, float))} ({off[0]:+.1f}, {off[1]:+.1f})"
        rows.append({"camera": name, "reprojection_px": cam.get("median_reprojection_px"),
                     "outvoted_share": cam.get("outvoted_share"), "offset": offset, "flagged": name in flagged,
                     "verdict": ("flagged: " + "; ".join(notes) if notes else "flagged") if name in flagged
                     else "; ".join(["agrees"] + notes)})  # a camera --correct-offsets shifted says so
    return rows


def read_detections(folder: str | Path, bundle: Bundle, people: People, *, camera_map: str | None = None,
                    body_model: str | None = None, cameras: list[str] | None = None,
                    max_people: int = MAX_DETECTED_PEOPLE, files: dict[str, dict[int, Path]] | None = None,
                    kept: KeptDetections | None = None) -> tuple[list[CameraDetections], list[str]]:
    """The detections of ``cameras`` (default: in name order while at most ``max_people`` detected people, at least
    one camera) at frames within the people's span -> (per camera, notes for the page). ``files``: the folder's
    index (camera -> frame -> file) when the caller has already made it (reconstruct's plan); ``kept``: the
    detections a run kept (reconstruct's), taken as the run used them (float32) where it kept the frame, the file
    read only where it did not."""
    if files is None:
        files = index_openpose_folder(folder, camera_map=parse_camera_map(camera_map), cameras=set(bundle.cameras))
    if cameras:
        unknown = [c for c in cameras if c not in files]
        if unknown:
            raise ReconError(f"{folder}: --cameras: no detections of camera {unknown[0]} (cameras: "
                             f"{', '.join(sorted(files))})")
    # told and checked where files are read (a run's kept detections were read with the run's checked model)
    model = body_model_of(files, body_model) if kept is None else None
    t0, t1 = float(people.times_ms[0]), float(people.times_ms[-1])
    margin = 1000.0 / float(people.fps)
    out, total, notes = [], 0, []
    names = cameras or sorted(files)
    for k, cam in enumerate(names):
        frames = np.array(sorted(files[cam]), dtype=np.int64)
        t = camera_times_ms(bundle, cam, frames, people)
        keep = np.isfinite(t) & (t >= t0 - margin) & (t <= t1 + margin)
        if not keep.any():
            continue
        read = kept.of_camera(cam, frames[keep]) if kept is not None else {}
        unkept = {int(f): files[cam][int(f)] for f in frames[keep] if int(f) not in read}
        if unkept:
            model = model or body_model_of(files, body_model)
            read.update(read_openpose_files({cam: unkept}, model)[cam])
        det = CameraDetections(camera=cam, times_ms=t[keep], people=[read[int(f)] for f in frames[keep]])
        n = sum(len(p) for p in det.people)
        if out and not cameras and total + n > max_people:
            rest = names[k:]
            notes.append(f"detections of {len(out)} of {len(names)} cameras are on this page (it holds at most "
                         f"{max_people:,} detected people); the others ({', '.join(rest[:6])}"
                         f"{' ...' if len(rest) > 6 else ''}): rebuild with `dome-calib people-page --cameras`")
            break
        out.append(det)
        total += n
    return out, notes


def build_people_page(people_folder: str | Path, *, out: str | Path | None = None,
                      bundle: str | Path | Bundle | None = None, detections: str | Path | None = None,
                      camera_map: str | None = None, body_model: str | None = None, cameras: list[str] | None = None,
                      progress: Callable[[int, int], None] | None = None,
                      shown_as: str | Path | None = None,
                      files: dict[str, dict[int, Path]] | None = None,
                      staged: StagedPeople | None = None) -> PeoplePageSummary:
    """Write the people page of ``people_folder`` to ``out`` (default ``people_folder/index.html``); ``shown_as``:
    the folder the page names (default ``people_folder``); ``staged``: the files ``reconstruct`` has just staged in
    ``people_folder``, in memory (their scenes are not read back; its bundle, when it has one, is not loaded
    again; its camera report is the table's). Without ``staged`` the table is the folder's cameras.json, read
    through its schema (:func:`~dome_calib.recon.people.scene_io.read_camera_report`; none without the file)."""
    if detections is not None and bundle is None:
        raise PeopleFileError(f"{detections}: detections need the calibration bundle (--bundle) to be put on "
                              "universal time and compared with the reprojected bodies")
    page = Path(out) if out is not None else Path(people_folder) / PAGE_FILE
    claim_file(page, inputs=_inputs(people_folder, bundle, detections))  # before any reading
    report = staged.report if staged is not None else read_camera_report(people_folder)  # the run's, or its file
    people = (people_of_scenes(people_folder, staged.files, staged.scenes()) if staged is not None
              else read_people(people_folder, progress=progress))
    people = with_rate(people,  # the page plays at the folder's rate
                       remedy="the page plays the files at their fpsType's rate or their times' (give an fpsType)")
    if staged is not None and staged.bundle is not None:
        bundle = staged.bundle
    cal = load_bundle(bundle) if isinstance(bundle, (str, Path)) else bundle
    det, notes = ([], [])
    if detections is not None and cal is not None:
        det, notes = read_detections(detections, cal, people, camera_map=camera_map, body_model=body_model,
                                     cameras=cameras, files=files,
                                     kept=staged.detections if staged is not None else None)
    write_people_page(page, people, bundle=cal, detections=det, notes=notes,
                      folder=Path(shown_as) if shown_as is not None else None,
                      patches=staged.patches if staged is not None else None,
                      camera_flags=camera_flags(report))
    return PeoplePageSummary(page=page, people=len(people.tracks), frames=len(people.frames),
                             cameras=len(cal.cameras) if cal is not None else 0,
                             detection_cameras=[d.camera for d in det], notes=notes)


def _inputs(people_folder: str | Path, bundle: str | Path | Bundle | None,
            detections: str | Path | None) -> list[Path]:
    """Every file the page is made from (the page may be none of them): the body3DScene folder's JSON files, the
    bundle's files, the detection files."""
    files = [p for p in Path(people_folder).glob("*.json")]
    if isinstance(bundle, (str, Path)) and Path(bundle).is_dir():
        files += [p for p in Path(bundle).iterdir()]
    if detections is not None and Path(detections).is_dir():
        files += [p for p in Path(detections).rglob("*")]
    return files


def people_page_writer(out: str | Path, bundle: str | Path, detections: str | Path, *,
                       camera_map: str | dict[str, str] | None = None,
                       body_model: str | None = None,
                       files: dict[str, dict[int, Path]] | None = None) -> Callable[[Path], None]:
    """What ``reconstruct`` (writing ``out``) is given to add its page: ``write(staging, staged)`` builds
    ``staging/index.html`` from the body3DScene files just staged there as the run holds them
    (:class:`~dome_calib.recon.people.scene_io.StagedPeople`: not read back; the run's bundle, else ``bundle``),
    with the detections reconstruct read (``files``: its index of the detections folder, so the folder is not
    scanned twice; ``staged.detections``: what the run kept of them, so no file is read twice)."""
    mapping = ",".join(f"{k}={v}" for k, v in camera_map.items()) if isinstance(camera_map, dict) else camera_map

    def write(staging: Path, staged: StagedPeople | None = None) -> None:
        build_people_page(staging, bundle=bundle, detections=detections, camera_map=mapping, body_model=body_model,
                          shown_as=out, files=files, staged=staged)

    return write
