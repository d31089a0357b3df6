"""The file-level stage behind ``dome-calib reconstruct``: an OpenPose folder + a bundle -> body3DScene files.

:func:`plan_reconstruction` checks everything the command reads and writes before any work (the options as the
user typed them, the output place, the bundle, the camera map, the detections folder's names and frames, the body
model's joint order, the streams' clocks); :func:`run_reconstruction` does the work and writes; the CLI opens its
executor (a local pool, a Dask cluster) between the two. :func:`reconstruct_folder` is both in one call.
"""
from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path

import numpy as np

from dome_calib.body3d_scene import fps_type_of
from dome_calib.bundle import FRAME_TIME_TOLERANCE_MS, Bundle
from dome_calib.bundle_io import load_bundle
from dome_calib.executor import is_remote
from dome_calib.lab_world import imported_up
from dome_calib.io_utils import (refuse_output_among_inputs, refuse_output_inside_inputs, remove_stale_staging,
                                run_temp_folder)
from dome_calib.recon.body_models import BodyModel, parse_body_model
from dome_calib.recon.errors import ReconError
from dome_calib.recon.depth import depth_folder_reader
from dome_calib.recon.openpose_io import body_model_of, file_digests, index_openpose_folder, parse_camera_map
from dome_calib.recon.people.agreement import CameraAgreement
from dome_calib.recon.people.camera_offsets import shifted_bundle, with_offsets_corrected
from dome_calib.recon.people.chunks import reconstruct_people_chunked
from dome_calib.recon.people.depth_witness import DepthWitness, DepthWitnessOptions
from dome_calib.recon.people.detection_cache import PREFIX as KEPT_PREFIX
from dome_calib.recon.people.extras import extra_joints
from dome_calib.recon.people.proposals import AssociationOptions
from dome_calib.recon.people.run import PeopleOptions, PeopleSequence, refit_over_time
from dome_calib.recon.people.scene_io import StagedPeople, camera_report, check_people_folder, write_people
from dome_calib.recon.people.sources import FileSource, StreamLayout, stream_layouts
from dome_calib.recon.people.temporal import TemporalOptions
from dome_calib.recon.people.tracking import TrackingOptions
from dome_calib.recon.project import ViewSet, view_set
from dome_calib.recon.video_rate import videos_rate

logger = logging.getLogger(__name__)

#: ``--fps`` range: one frame a day to a million a second (universal times are float milliseconds).
FPS_RANGE = (Fraction(1, 86400), Fraction(10**6))
#: The exact rate of the streams that have one (Panoptic VGA 25 fps, HD 29.97 fps).
FPS_OF_STREAM = {"vga": Fraction(25), "hd": Fraction(30000, 1001)}
#: ``--workers`` range.
MAX_WORKERS = 1024


@dataclass(frozen=True)
class ReconstructSummary:
    """What a run gave; ``nobody``: why no person was reconstructed (None when someone was)."""

    out: Path
    times: int
    cameras: int
    body_model: str
    reference: str
    people: int
    body_frames: int
    flagged_cameras: list[str]
    median_reprojection_px: float | None
    nobody: str | None = None
    fps: Fraction | None = None
    fps_from: str = ""
    camera_notes: tuple[str, ...] = ()  # cameras.json's ``notes``: why a camera is flagged, where the report says


@dataclass(frozen=True)
class FurtherStage:
    """What a further stage on the people (``after_people``: the patches of ``--images``) gives back: ``write``
    adds its files to the staged output folder; ``ties`` (None: none), the part motions the body over time is
    fitted again with (:class:`~dome_calib.recon.patches.body.JointTies`); ``refined(first, final)`` is told both
    people sequences once that is done (the stage's report); ``page_layer`` (None: none), what it adds to the people
    page (the patches coloured by part: :func:`~dome_calib.recon.patches.page_layer.patch_layer`); ``again`` (None:
    none), told the people fitted with the ties, gives the stage a second time (the patches' ``reseed_hidden``):
    its ties are fitted instead, from the same people, and its files written."""

    write: Callable[[Path], None]
    ties: object | None = None
    refined: Callable[[PeopleSequence, PeopleSequence], None] | None = None
    page_layer: dict | None = None
    again: Callable[[PeopleSequence], FurtherStage] | None = None


@dataclass(frozen=True)
class ReconstructPlan:
    """Everything checked, nothing computed: the run :func:`run_reconstruction` will make."""

    out: Path
    views: ViewSet
    source: FileSource
    times_ms: np.ndarray
    numbers: np.ndarray
    reference: str
    model: BodyModel
    options: PeopleOptions
    depth: DepthWitness | None = None
    fps: Fraction | None = None
    fps_from: str = ""
    lab_up: str | None = None
    bundle: Bundle | None = None  # the calibration read once, handed to the files written beside the people
    images: Path | None = None  # --images: the cameras' frames for the patch stream, checked as an input place


def people_options(*, min_views: int = 3, smooth: int = 0, fps: str | None = None, per_frame: bool = False
                   ) -> PeopleOptions:
    """The command's options from its flags: people need ``min_views`` cameras (``--min-views``), ``smooth``
    observations either side (``--smooth``, 0 = off), ``fps`` (``--fps``, e.g. "30", "30000/1001"; None: not
    given) for a bundle without sync tables; ``per_frame`` (``--per-frame``): each time's own triangulation, without
    the body over time. A bad value is one ReconError naming the flag as the user typed it."""
    if min_views < 2:
        raise ReconError(f"--min-views {min_views}: a person must be seen by at least 2 cameras (a joint is "
                         "triangulated from two views or more)")
    if smooth < 0:
        raise ReconError(f"--smooth {smooth}: expected 0 (off) or a number of frames either side")
    shared_fps = None if fps is None else check_fps(fps)
    return PeopleOptions(association=AssociationOptions(min_person_views=min_views),
                         tracking=TrackingOptions(smooth_half_window=smooth), shared_fps=shared_fps,
                         temporal=TemporalOptions(enabled=not per_frame))


def check_fps(fps: str | Fraction, flag: str = "--fps") -> Fraction:
    """A frame rate as the user gave it -> Fraction in :data:`FPS_RANGE`; ReconError naming ``flag``."""
    try:
        rate = Fraction(fps)
    except (ValueError, ZeroDivisionError):
        raise ReconError(f"{flag} {fps!r}: not a frame rate (e.g. 30, 60 or 30000/1001)") from None
    if not FPS_RANGE[0] <= rate <= FPS_RANGE[1]:
        raise ReconError(f"{flag} {str(fps)!r}: expected a frame rate from 1/86400 (one frame a day) to 1000000")
    return rate


def shared_rate(bundle, options: PeopleOptions, videos: str | Path | None) -> tuple[Fraction | None, str]:
    """The frame rate of the detections of a bundle without sync tables, and where it came from: ``--fps``, else
    the videos (:func:`~dome_calib.recon.video_rate.videos_rate`; both given: they must agree); (None, "") with sync
    tables (each stream's own clock). Neither: None, and the streams refuse it
    (:func:`~dome_calib.recon.people.sources.stream_layouts`), as no rate is ever assumed."""
    if bundle.sync is not None:
        return None, ""
    from_videos = check_fps(videos_rate(videos), "--videos") if videos is not None else None
    given = options.shared_fps
    if given is not None and from_videos is not None and given != from_videos:
        raise ReconError(f"--fps {given} but the videos of --videos {videos} run at {from_videos} fps: give one")
    if given is not None:
        return given, "--fps"
    if from_videos is not None:
        return from_videos, "the videos"
    return None, ""


def check_workers(workers: int) -> None:
    """``--workers N``: 1 to :data:`MAX_WORKERS` processes."""
    if not 1 <= workers <= MAX_WORKERS:
        raise ReconError(f"--workers {workers}: expected 1 to {MAX_WORKERS} processes")


def check_correct_offsets(correct_offsets: bool, images: str | Path | None) -> None:
    """``--correct-offsets`` with ``--images`` is refused: the patch stream would project with the bundle as
    given, the people with their cameras shifted."""
    if correct_offsets and images is not None:
        raise ReconError("--correct-offsets with --images: the patch stream would use the bundle as given, the "
                         "people the shifted cameras; run them apart")


def default_output(detections: str | Path) -> Path:
    """``<DETECTIONS>_people`` beside the detections folder, named from the folder itself (``.`` and ``..``
    resolved: ``reconstruct ..`` inside a camera folder writes beside the detections, not into the camera)."""
    folder = Path(detections).resolve()
    if folder == folder.parent:
        raise ReconError(f"{detections}: the detections folder is the file system's root; give -o")
    return folder.parent / f"{folder.name}_people"


def reference_times(streams: list[StreamLayout], reference: str | None) -> tuple[np.ndarray, np.ndarray, str]:
    """The times to reconstruct: the reference stream's frames that have detection files -> (times_ms, frame
    numbers, stream). Reference: given, else "vga", else "hd", else the stream with most cameras."""
    by_name = {s.stream: s for s in streams}
    if reference is not None and reference not in by_name:
        raise ReconError(f"--reference {reference}: that stream has no detections (streams: "
                         f"{', '.join(sorted(by_name))})")
    name = reference or next((n for n in ("vga", "hd") if n in by_name),
                             max(streams, key=lambda s: (len(s.cameras), s.stream)).stream)
    s = by_name[name]
    return s.table.times_of(s.frame_index), s.frame_index, name


def streams_at(layouts: list[StreamLayout], times_ms: np.ndarray) -> list[StreamLayout]:
    """The streams whose detected frames reach any of the reference times (a stream is interpolated between its
    frames, never beyond): one warning naming each other stream and its cameras, which are then not used, nor
    counted in the summary (before, they were counted and contributed nothing)."""
    kept = []
    for s in layouts:
        t = s.table.times_of(s.frame_index)
        tol = FRAME_TIME_TOLERANCE_MS
        if len(t) and np.any((times_ms >= t[0] - tol) & (times_ms <= t[-1] + tol)):
            kept.append(s)
            continue
        shown = ", ".join(s.cameras[:4]) + (", ..." if len(s.cameras) > 4 else "")
        logger.warning("stream %s (%d cameras: %s): its detected frames lie at %.6g..%.6g ms on its sync table, none "
                       "of the %d reference times (%.6g..%.6g ms): its cameras are not used (is its sync table the "
                       "one of this session?)", s.stream, len(s.cameras), shown, t[0] if len(t) else np.nan,
                       t[-1] if len(t) else np.nan, len(times_ms), times_ms[0], times_ms[-1])
    return kept


def plan_reconstruction(detections: str | Path, bundle_folder: str | Path, out: str | Path | None = None, *,
                        body_model: str | BodyModel | None = None, camera_map: str | dict[str, str] | None = None,
                        reference: str | None = None, options: PeopleOptions | None = None,
                        depth_folder: str | Path | None = None,
                        depth_options: DepthWitnessOptions | None = None,
                        videos: str | Path | None = None, images: str | Path | None = None) -> ReconstructPlan:
    """Check every input and the output place, in seconds, before any work (see the module docstring); the paths
    are resolved (``.``, ``..``, links), ``out`` defaults to :func:`default_output` and may lie inside none of the
    input places (detections, bundle, depth frames, videos, images), nor be or hold one. ``images``: the cameras'
    frames of the patch stream (``--images``), only checked here as a place; their contents are checked by
    :func:`~dome_calib.recon.patches.stage.plan_patches`. ``depth_folder``: Kinect depth frames (``KINECTNODE<n>/depth_<k>.png``)
    whose sensors witness the joints (:mod:`~dome_calib.recon.people.depth_witness`); the bundle must then hold the
    Kinects' calibration and depth sync tables. ``videos``: the folder of the cameras' videos, whose frame rate is
    the detections' when the bundle has no sync tables and ``options.shared_fps`` is not given
    (:func:`shared_rate`)."""
    options = options or PeopleOptions()
    if isinstance(body_model, str):
        try:
            body_model = parse_body_model(body_model)
        except ReconError:
            raise ReconError(f"--body-model {body_model}: unknown (known: "
                             f"{', '.join(m.value for m in BodyModel)})") from None
    detections = Path(detections).resolve()
    out = Path(out) if out is not None else default_output(detections)
    images = Path(images).resolve() if images is not None else None
    inputs = [detections, bundle_folder] + [p for p in (depth_folder, videos, images) if p is not None]
    refuse_output_among_inputs(out, inputs, whole_folder=True)  # OUT is replaced whole
    refuse_output_inside_inputs(out, inputs)
    check_people_folder(out)
    remove_stale_staging(out)  # of earlier runs killed while writing OUT (SIGKILL, power cut)
    bundle = load_bundle(bundle_folder)
    depth = (DepthWitness.of(bundle, depth_folder_reader(depth_folder), depth_options)
             if depth_folder is not None else None)
    mapping = camera_map if isinstance(camera_map, dict) else parse_camera_map(camera_map)
    files = index_openpose_folder(detections, camera_map=mapping, cameras=set(bundle.cameras))
    model = body_model_of(files, body_model)
    fps, fps_from = shared_rate(bundle, options, videos)
    options = replace(options, shared_fps=fps)
    layouts = stream_layouts(bundle, files, files, shared_fps=options.shared_fps)
    times, numbers, ref = reference_times(layouts, reference)
    layouts = streams_at(layouts, times)
    source = FileSource(layouts=layouts, files=files, body_model=model)
    need = options.association.min_person_views
    if need > len(source.cameras):
        raise ReconError(f"--min-views {need}: only {len(source.cameras)} cameras have detections, so nobody could "
                         "be reconstructed")
    if fps is None:  # the reference stream's own rate, where it has a name
        fps, fps_from = FPS_OF_STREAM.get(ref), "the sync tables"
    return ReconstructPlan(out=out, views=view_set(bundle, source.cameras), source=source, times_ms=times,
                           numbers=numbers, reference=ref, model=model, options=options, depth=depth, fps=fps,
                           fps_from=fps_from if fps is not None else "",
                           lab_up=imported_up(bundle.calib_data_source), bundle=bundle, images=images)


#: ``--correct-offsets``: at most this many corrections (each one a run of the people again). A camera turned by 1 or
#: 2 degrees on the few-camera rig (``bench/camera_offsets.py``) is measured short (the bodies it pulls, its inliers
#: only): 55-73 % of its shift at the first round, 91-97 % after the fourth.
OFFSET_ROUNDS = 4


#: The share of the joints the cameras agreed on that the Kinects' depth may see through before the run says so:
#: measured on a rendered group (4 people, 5 Kinects, 3 times): 1 of 228 with this session's depth frames, 70 of
#: 228 (and a person gone) with another session's.
DEPTH_SUSPECT_SHARE = 0.1


def depth_removed(agreement: CameraAgreement) -> str:
    """What the Kinects' depth removed, as it is: the joints the cameras agreed on that it saw through."""
    return (f"the Kinect depth frames (--depth) saw through {agreement.depth_rejected} of the "
            f"{agreement.depth_joints} joints the cameras agreed on and removed them as free space: are they the "
            "depth frames of this session (and its depth sync tables)? Without --depth they are kept")


def why_nobody(agreement: CameraAgreement, options: PeopleOptions, times: int) -> str:
    """What dropped every person, from the cameras' tallies (taken before tracking)."""
    a, tr = options.association, options.tracking
    if agreement.detected.sum() == 0:
        return (f"no camera detected a person ({a.min_common_joints} joints above confidence {a.min_joint_conf:g}) "
                f"at the {times} times")
    if agreement.depth_rejected and agreement.depth_rejected > DEPTH_SUSPECT_SHARE * agreement.depth_joints:
        return depth_removed(agreement)
    if agreement.used.sum() == 0:
        return (f"the cameras detected {int(agreement.detected.sum())} people but none was seen alike by "
                f"--min-views {a.min_person_views} cameras: is the bundle the calibration of these cameras, and are "
                "the camera folders named (or --camera-map'ped) right?")
    return (f"bodies were found ({int(agreement.used.sum())} detections used) but none was tracked over "
            f"{tr.min_frames_for(times)} times (a track ends unseen for {tr.max_missed_ms:g} ms or "
            f"{tr.max_missed_steps:g} time steps)")


@contextlib.contextmanager
def kept_detections(source, executor=None) -> Iterator:
    """``source`` with a folder to keep what it reads (a :class:`~dome_calib.recon.people.sources.FileSource`, on
    this machine's executors), removed at the end; on a cluster, with the digest of every file as this machine
    reads it, which each worker checks what it reads against (a worker reading another copy turned 9 people into
    none, exit 0); any other source as it is."""
    if not isinstance(source, FileSource):
        yield source
        return
    if is_remote(executor):
        yield replace(source, digests=file_digests(source.files))
        return
    with run_temp_folder(KEPT_PREFIX) as folder:
        yield replace(source, cache_dir=folder)


def run_reconstruction(plan: ReconstructPlan, *, executor=None, progress: Callable[[int, int], None] | None = None,
                       page: Callable[[Path, StagedPeople], None] | None = None,
                       after_people: Callable[[PeopleSequence], FurtherStage] | None = None,
                       offset_rounds: int = 0) -> ReconstructSummary:
    """The work of a checked plan: people at every time (chunks on ``executor``), then the files, written only at
    the end (staged, then renamed); ``page(staging, staged)`` adds the caller's files to the staged folder from the
    run's own results (:class:`~dome_calib.recon.people.scene_io.StagedPeople`: the scenes written, cameras.json's
    report, the plan's bundle, the detections the run kept (the page shows those, as the run used them, and reads
    no detection file again); the people page: dome_calib.pipeline.people_page.people_page_writer);
    ``after_people(people)``, a further stage on the people (the patches of ``--images``), returns a
    :class:`FurtherStage`: what adds its files there and, with ties, the body over time is fitted again from the
    same tracks with them (:func:`~dome_calib.recon.people.run.refit_over_time`, the same windows on the same
    executor) and those people are written. The camera report of the people written is computed once, for
    cameras.json and the summary (each ``--correct-offsets`` round reads its own run's). ``offset_rounds`` (``--correct-offsets``: :data:`OFFSET_ROUNDS`; 0: off): up to that many times, the
    cameras flagged for their offset get their principal point moved by it and the people are made again
    (:func:`~dome_calib.recon.people.camera_offsets.with_offsets_corrected`: its rules for stopping and undoing a
    round); cameras.json says the shifts."""
    with kept_detections(plan.source, executor) as source:  # later passes take what the first one read
        def people(shifts: dict[str, np.ndarray]) -> tuple[PeopleSequence, ReconstructPlan]:
            p = plan
            if shifts:
                shifted = shifted_bundle(plan.bundle, shifts)
                p = replace(plan, views=view_set(shifted, list(plan.views.names)), bundle=shifted)
            return reconstruct_people_chunked(p.views, source, p.times_ms, p.options, executor=executor,
                                              depth=p.depth, progress=progress), p

        def report_of(run: tuple[PeopleSequence, ReconstructPlan]) -> dict:
            return camera_report(run[0].cameras, run[1].views.subset(run[0].cameras.names).resolution,
                                 plan.options.temporal.min_noise_px)

        (seq, plan), correction = with_offsets_corrected(people, report_of, offset_rounds)  # --correct-offsets
        more = after_people(seq) if after_people is not None else None
        if more is not None and more.ties is not None:
            first, seq = seq, refit_over_time(plan.views, source, seq, plan.options, more.ties, depth=plan.depth,
                                              executor=executor)
            if more.again is not None:  # the stage again from the people fitted with its ties, fitted instead
                more = more.again(seq)
                seq = refit_over_time(plan.views, source, first, plan.options, more.ties, depth=plan.depth,
                                      executor=executor)
            if more.refined is not None:
                more.refined(first, seq)
        extras = (extra_joints(plan.views, source, seq, plan.options)
                  if isinstance(source, FileSource) else None)  # the detector's joints beside joints19
        kept = source.kept() if isinstance(source, FileSource) else None  # the page's detections: read once

        def also(staging: Path, staged: StagedPeople) -> None:
            if more is not None:
                more.write(staging)
            if page is not None:
                page(staging, replace(staged, detections=kept, patches=more.page_layer if more is not None else None))

        report = camera_report(seq.cameras, plan.views.subset(seq.cameras.names).resolution,
                               plan.options.temporal.min_noise_px, corrected_px=correction.shifts_px,
                               diverged=correction.diverged,
                               undone=(correction.undone_shifted, correction.undone))
        write_people(plan.out, seq, plan.numbers, fps_type_of(plan.reference),
                     also=also if more is not None or page is not None else None, body_model=plan.model.value,
                     extras=extras, lab_up=plan.lab_up, fps=plan.fps, report=report, bundle=plan.bundle)
    ids = {int(i) for b in seq.bodies for i in b.ids}
    nobody = None if ids else why_nobody(seq.cameras, plan.options, len(plan.times_ms))
    if ids and seq.cameras.depth_rejected > DEPTH_SUSPECT_SHARE * seq.cameras.depth_joints:
        logger.warning("%s", depth_removed(seq.cameras))  # people are left, but most of their joints are gone
    return ReconstructSummary(out=plan.out, times=len(plan.times_ms), cameras=len(plan.source.cameras),
                              body_model=plan.model.value, reference=plan.reference, people=len(ids),
                              body_frames=sum(len(b.ids) for b in seq.bodies), flagged_cameras=report["flagged"],
                              median_reprojection_px=report["median_reprojection_px"], nobody=nobody,
                              fps=plan.fps, fps_from=plan.fps_from, camera_notes=tuple(report["notes"]))


def reconstruct_folder(detections: str | Path, bundle_folder: str | Path, out: str | Path | None = None, *,
                       body_model: str | None = None, camera_map: str | dict[str, str] | None = None,
                       reference: str | None = None, options: PeopleOptions | None = None, executor=None,
                       depth_folder: str | Path | None = None, depth_options: DepthWitnessOptions | None = None,
                       progress: Callable[[int, int], None] | None = None,
                       page: Callable[[Path, StagedPeople], None] | None = None,
                       videos: str | Path | None = None, correct_offsets: bool = False) -> ReconstructSummary:
    """Detections folder (OpenPose JSON per camera) + bundle -> ``out`` (body3DScene per time, cameras.json, and
    ``page(staging)``'s files).

    Every input is checked before any work (:func:`plan_reconstruction`); each chunk of times reads its own files
    (a long session is never in memory at once; a bad file stops the run when its chunk is read). ``out`` is
    written only at the end (staged, then renamed): bad input leaves nothing behind. ``correct_offsets``
    (``--correct-offsets``): :func:`run_reconstruction`'s ``offset_rounds`` = :data:`OFFSET_ROUNDS`.
    """
    plan = plan_reconstruction(detections, bundle_folder, out, body_model=body_model, camera_map=camera_map,
                               reference=reference, options=options, depth_folder=depth_folder,
                               depth_options=depth_options, videos=videos)
    return run_reconstruction(plan, executor=executor, progress=progress, page=page,
                              offset_rounds=OFFSET_ROUNDS if correct_offsets else 0)


def format_summary(summary: ReconstructSummary) -> str:
    """The command's one line: what was reconstructed, or that nobody was and why."""
    rate = (f", {float(summary.fps):g} fps from {summary.fps_from}" if summary.fps is not None else
            ", each stream's rate from the sync tables")
    head = f"{summary.times} times ({summary.reference}{rate}) from {summary.cameras} cameras ({summary.body_model}): "
    if summary.nobody:
        return f"{head}no person reconstructed: {summary.nobody} -> {summary.out}"
    err = "n/a" if summary.median_reprojection_px is None else f"{summary.median_reprojection_px:.1f} px"
    flagged = ", ".join(summary.flagged_cameras) or "none"
    notes = "".join(f" ({note})" for note in summary.camera_notes)
    return (f"{head}{summary.people} people, {summary.body_frames} body-frames, median reprojection {err}; cameras "
            f"that disagree: {flagged}{notes} -> {summary.out}")
