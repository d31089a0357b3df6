"""File-level stages behind ``dome-calib triangulate`` and ``dome-calib pointcloud`` (paths in, files out)."""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dome_calib.body3d_scene import fps_type_of
from dome_calib.bundle_io import load_bundle
from dome_calib.errors import require_finite
from dome_calib.layout import check_dome_scale
from dome_calib.recon.errors import ReconError
from dome_calib.ownership import claim_file, claim_folder
from dome_calib.recon.depth import depth_folder_reader, pointcloud_at, write_ply
from dome_calib.recon.formats import check_times, default_times, load_detection_streams, write_skeletons
from dome_calib.recon.project import view_set
from dome_calib.recon.streams import triangulate_streams
from dome_calib.recon.triangulate import TriangulationOptions

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TriangulateSummary:
    out: Path
    times: int
    joints: int
    reconstructed: int
    median_inlier_views: float
    streams: list[str]


def triangulate_file(bundle_folder: str | Path, detections: str | Path, out: str | Path, *,
                     options: TriangulationOptions | None = None,
                     progress: Callable[[int, int], None] | None = None) -> TriangulateSummary:
    """Detections JSON + bundle -> Panoptic body3DScene files in ``out`` (see :mod:`dome_calib.recon.formats`).

    ``out`` is replaced as a whole; it is checked before any work. Explicit times outside every stream's detected
    frames: all of them -> ReconError (nothing written), some -> a warning with the count (no joints there).
    """
    claim_folder(out, inputs=[detections, bundle_folder])  # OUT is replaced whole: ours only, no input in it
    bundle = load_bundle(bundle_folder)
    check_dome_scale(bundle.cameras, f"--bundle {bundle_folder}")
    streams, parsed = load_detection_streams(bundle, detections)
    if parsed["times_ms"] is not None:
        times = parsed["times_ms"]
        numbers = np.arange(len(times))
        fps_type = "custom"
    else:
        times, numbers, ref = default_times(streams, parsed["reference"])
        fps_type = fps_type_of(ref, explicit_times=False)
    used = check_times(detections, streams, times)  # the streams that reach the times (the others said once)
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    total = len(times)
    seq = triangulate_streams(views, streams, times, options,
                              progress=(lambda done: progress(done, total)) if progress else None)
    write_skeletons(out, seq, numbers, body_id=parsed["body_id"], fps_type=fps_type)
    ok = seq.confidence >= 0
    inl = seq.n_inliers[ok]
    return TriangulateSummary(out=Path(out), times=total, joints=seq.X_cm.shape[1], reconstructed=int(ok.sum()),
                              median_inlier_views=float(np.median(inl)) if inl.size else 0.0,
                              streams=used)


@dataclass(frozen=True)
class PointCloudSummary:
    out: Path
    points: int
    sensors: list[str]
    time_offsets_ms: list[float]


def pointcloud_file(bundle_folder: str | Path, time_ms: float, depth_folder: str | Path, out: str | Path, *,
                    max_offset_ms: float | None = None, correct_bias: bool = True,
                    progress: Callable[[int, int], None] | None = None) -> PointCloudSummary:
    """Depth frames nearest to ``time_ms`` of every Kinect -> one world point cloud PLY at ``out`` (checked first)."""
    require_finite(ReconError, **{"--time-ms": time_ms, "--max-offset-ms": max_offset_ms})
    claim_file(out, inputs=[*Path(bundle_folder).glob("*"), *Path(depth_folder).glob("*/*")])
    bundle = load_bundle(bundle_folder)
    check_dome_scale(bundle.cameras, f"--bundle {bundle_folder}")
    cloud = pointcloud_at(bundle, time_ms, depth_folder_reader(depth_folder), max_offset_ms=max_offset_ms,
                          correct_bias=correct_bias, progress=progress)
    write_ply(out, cloud)
    offsets = [float(cloud.time_offset_ms[cloud.sensor == i][0]) for i in range(len(cloud.sensors))]
    return PointCloudSummary(out=Path(out), points=len(cloud.xyz_cm), sensors=cloud.sensors, time_offsets_ms=offsets)
