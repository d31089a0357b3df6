"""A synthetic group session on disk, for `dome-calib reconstruct`, the demo and benches:

    FOLDER/detections/<camera>/<camera>_<frame:012d>_keypoints.json   OpenPose's own output of every colour camera
                                                                      at its own stream's frames (synth.detector)
    FOLDER/group_truth.json                                           the people's true joints19 (world cm) at the
                                                                      reference stream's frame times
    FOLDER/depth/KINECTNODE<n>/depth_<k>.png                          with ``depth``: every Kinect's depth frames of
                                                                      the people (synth.depth_people)

``group_truth.json``: ``{"version": 1, "scenario", "seed", "n_people", "roles": {id: role}, "reference_stream":
"vga" (or "shared" for a bundle without sync tables), "detector": the observed failure rates, "frames":
[{"univ_time_ms", "frame", "bodies": [{"id", "joints19": [[x, y, z] * 19]}]}]}``; only people inside the dome
are listed at a time.
"""
from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.io_utils import atomic_write_text
from dome_calib.synth.detector import (DetectionCounts, DetectorError, DetectorModel, shared_clock,
                                       synth_detections, write_openpose_folder)
from dome_calib.synth.depth_people import write_group_depth
from dome_calib.synth.group import GroupOptions, GroupTruth, make_group

logger = logging.getLogger(__name__)

TRUTH_FILE = "group_truth.json"
DETECTIONS = "detections"
DEPTH = "depth"


@dataclass(kw_only=True)
class GroupSessionOptions:
    """The group, the detector, how the files are written, which cameras (default: every colour camera)."""

    group: GroupOptions = field(default_factory=GroupOptions)
    detector: DetectorModel = field(default_factory=DetectorModel)
    body_model: str = "BODY_25"
    naming: str = "openpose"
    cameras: list[str] | None = None
    depth: bool = False  # also the Kinects' depth frames (the bundle's calibrated Kinects with depth sync tables)


def session_span_ms(bundle: Bundle, margin_ms: float = 100.0) -> tuple[float, float]:
    """(start_ms, duration_ms): the universal times every colour stream of ``bundle`` covers (VGA, HD and each
    Kinect colour camera's table), less ``margin_ms`` at both ends; DetectorError if they do not overlap."""
    if bundle.sync is None:
        raise DetectorError(f"bundle {bundle.seq}: no sync tables, so no span of universal time to fill")
    tables = [*bundle.sync.streams.values(), *bundle.sync.kinect_color.values()]
    start = max(float(t.univ_time_ms[0]) for t in tables if len(t.index)) + margin_ms
    end = min(float(t.univ_time_ms[-1]) for t in tables if len(t.index)) - margin_ms
    if end <= start:
        raise DetectorError(f"bundle {bundle.seq}: the streams' sync tables share no span of universal time")
    return start, end - start


def truth_document(truth: GroupTruth, times_ms: np.ndarray, frames: np.ndarray, *, stream: str,
                   options: GroupOptions, counts: DetectionCounts | None = None) -> dict:
    """The ``group_truth.json`` document of ``truth`` at ``times_ms`` (frames: the reference stream's indices)."""
    X, present = truth.joints_cm(times_ms)
    return {
        "version": 1, "scenario": options.scenario, "seed": options.seed, "n_people": options.n_people,
        "roles": {str(p.id): p.role for p in truth.plans}, "reference_stream": stream, "units": "cm",
        "detector": {k: (None if np.isnan(v) else round(v, 4)) for k, v in counts.rates().items()} if counts else None,
        "frames": [{"univ_time_ms": round(float(t), 4), "frame": int(f),
                    "bodies": [{"id": truth.ids[p], "joints19": np.round(X[k, p], 3).tolist()}
                               for p in range(len(truth.ids)) if present[k, p]]}
                   for k, (t, f) in enumerate(zip(times_ms, frames))],
    }


def make_group_session(folder: str | Path, bundle: Bundle, options: GroupSessionOptions | None = None
                       ) -> GroupTruth:
    """Write a group's detections as OpenPose folders and its truth into ``folder``; returns the truth.

    The group's span (``options.group.start_ms``, ``duration_ms``) must lie within the bundle's sync tables.
    Example:
        >>> truth = make_group_session(tmp / "group", bundle, GroupSessionOptions(group=GroupOptions(
        ...     n_people=5, start_ms=1000.0)))
    """
    o = options or GroupSessionOptions()
    folder = Path(folder)
    truth = make_group(o.group)
    span = (o.group.start_ms, o.group.start_ms + o.group.duration_ms)
    counts = DetectionCounts()
    det = synth_detections(bundle, truth, cameras=o.cameras, univ_time_ms=span, model=o.detector, counts=counts)
    if counts.images == 0:
        raise DetectorError(f"bundle {bundle.seq}: no camera frame between {span[0]:g} and {span[1]:g} ms "
                            "(the group's span is outside the sync tables)")
    if bundle.sync is None:
        stream, table = "shared", shared_clock(*span)
    else:
        stream = "vga" if "vga" in bundle.sync.streams else sorted(bundle.sync.streams)[0]
        table = bundle.sync.streams[stream]
    keep = (table.univ_time_ms >= span[0]) & (table.univ_time_ms <= span[1])
    write_openpose_folder(folder / DETECTIONS, det, body_model=o.body_model, naming=o.naming)
    if o.depth:
        write_group_depth(folder / DEPTH, bundle, truth, span, seed=o.group.seed)
    doc = truth_document(truth, table.univ_time_ms[keep], table.index[keep], stream=stream, options=o.group,
                         counts=counts)
    doc["options"] = json.loads(json.dumps(asdict(o)))
    atomic_write_text(folder / TRUTH_FILE, json.dumps(doc, separators=(",", ":")) + "\n")
    logger.info("group session: %d people, %d images, %s", o.group.n_people, counts.images, folder)
    return truth
