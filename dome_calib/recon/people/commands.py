"""The file-level stage behind ``dome-calib reconstruct``: an OpenPose folder + a bundle -> body3DScene files."""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from dome_calib.bundle_io import load_bundle
from dome_calib.io_utils import refuse_output_among_inputs
from dome_calib.recon.errors import ReconError
from dome_calib.recon.formats import FPS_TYPE
from dome_calib.recon.depth import depth_folder_reader
from dome_calib.recon.openpose_io import body_model_of, index_openpose_folder, parse_camera_map
from dome_calib.recon.people.chunks import reconstruct_people_chunked
from dome_calib.recon.people.depth_witness import DepthWitness, DepthWitnessOptions
from dome_calib.recon.people.proposals import AssociationOptions
from dome_calib.recon.people.run import PeopleOptions
from dome_calib.recon.people.scene_io import camera_report, check_people_folder, write_people
from dome_calib.recon.people.sources import FileSource, StreamLayout, stream_layouts
from dome_calib.recon.people.temporal import TemporalOptions
from dome_calib.recon.people.tracking import TrackingOptions
from dome_calib.recon.project import view_set

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReconstructSummary:
    out: Path
    times: int
    cameras: int
    body_model: str
    reference: str
    people: int
    body_frames: int
    flagged_cameras: list[str]
    median_reprojection_px: float | None


def people_options(*, min_views: int = 3, smooth: int = 0, fps: str = "30", per_frame: bool = False
                   ) -> PeopleOptions:
    """The command's options: people need ``min_views`` cameras, ``smooth`` observations either side (0 = off),
    ``fps`` (e.g. "30", "30000/1001") for a bundle without sync tables; ``per_frame``: the joints of each time's
    own triangulation, without the body over time. ReconError names a bad value."""
    try:
        shared_fps = Fraction(fps)
    except (ValueError, ZeroDivisionError):
        raise ReconError(f"--fps {fps!r}: not a frame rate (e.g. 30, 60 or 30000/1001)") from None
    if shared_fps <= 0:
        raise ReconError(f"--fps {fps!r}: a frame rate must be > 0")
    return PeopleOptions(association=AssociationOptions(min_person_views=min_views),
                         tracking=TrackingOptions(smooth_half_window=smooth), shared_fps=shared_fps,
                         temporal=TemporalOptions(enabled=not per_frame))


def reference_times(streams: list[StreamLayout], reference: str | None) -> tuple[np.ndarray, np.ndarray, str]:
    """The times to reconstruct: the reference stream's frames that have detection files -> (times_ms, frame
    numbers, stream). Reference: given, else "vga", else "hd", else the stream with most cameras."""
    by_name = {s.stream: s for s in streams}
    if reference is not None and reference not in by_name:
        raise ReconError(f"reference stream {reference!r} has no detections (streams: {', '.join(sorted(by_name))})")
    name = reference or next((n for n in ("vga", "hd") if n in by_name),
                             max(streams, key=lambda s: (len(s.cameras), s.stream)).stream)
    s = by_name[name]
    return s.table.times_of(s.frame_index), s.frame_index, name


def reconstruct_folder(detections: str | Path, bundle_folder: str | Path, out: str | Path, *,
                       body_model: str | None = None, camera_map: str | dict[str, str] | None = None,
                       reference: str | None = None, options: PeopleOptions | None = None, executor=None,
                       depth_folder: str | Path | None = None, depth_options: DepthWitnessOptions | None = None,
                       progress: Callable[[int, int], None] | None = None,
                       page: Callable[[Path], None] | None = None) -> ReconstructSummary:
    """Detections folder (OpenPose JSON per camera) + bundle -> ``out`` (body3DScene per time, cameras.json; and
    ``page(staging)``'s files: the caller's people page, dome_calib.pipeline.people_page.people_page_writer).

    The folder's names and frames are checked before any work; each chunk of times reads its own files (a long
    session is never in memory at once; a bad file stops the run when its chunk is read). ``out`` is written only
    at the end (staged, then renamed): bad input leaves nothing behind. ``depth_folder``: Kinect depth frames
    (``KINECTNODE<n>/depth_<k>.png``) whose sensors witness the joints (:mod:`~dome_calib.recon.people.
    depth_witness`); the bundle must then hold the Kinects' calibration and depth sync tables.
    """
    options = options or PeopleOptions()
    inputs = [detections, bundle_folder] + ([depth_folder] if depth_folder is not None else [])
    refuse_output_among_inputs(out, inputs, whole_folder=True)  # OUT is replaced whole
    check_people_folder(out)
    bundle = load_bundle(bundle_folder)
    depth = (DepthWitness.of(bundle, depth_folder_reader(depth_folder), depth_options)
             if depth_folder is not None else None)
    mapping = camera_map if isinstance(camera_map, dict) else parse_camera_map(camera_map)
    files = index_openpose_folder(detections, camera_map=mapping, cameras=set(bundle.cameras))
    model = body_model_of(files, body_model)
    layouts = stream_layouts(bundle, files, files, shared_fps=options.shared_fps)
    times, numbers, ref = reference_times(layouts, reference)
    source = FileSource(layouts=layouts, files=files, body_model=model)
    names = source.cameras
    views = view_set(bundle, names)
    seq = reconstruct_people_chunked(views, source, times, options, executor=executor, depth=depth,
                                     progress=progress)
    write_people(out, seq, numbers, FPS_TYPE.get(ref, "custom"), also=page)
    report = camera_report(seq.cameras)
    ids = {int(i) for b in seq.bodies for i in b.ids}
    return ReconstructSummary(out=Path(out), times=len(times), cameras=len(names), body_model=model.value,
                              reference=ref, people=len(ids), body_frames=sum(len(b.ids) for b in seq.bodies),
                              flagged_cameras=report["flagged"],
                              median_reprojection_px=report["median_reprojection_px"])
