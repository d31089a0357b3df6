"""JSON in/out of ``dome-calib triangulate`` (documented in docs/recon.md, "Detections file").

In: a detections file (2D joints per camera per frame of that camera's own stream)::

    {"joints": 19, "body_id": 0, "reference": "vga", "times_ms": [...],      (all optional)
     "cameras": {"01_01": {"frames": [100, 101], "joints": [[[u, v, c], ... J], ...]}, ...}}

Out: one Panoptic ``body3DScene`` file per time, ``body3DScene_<k:08d>.json``, one body (``joints<J>``,
``inlierViews<J>``), written by the one body3DScene module (:mod:`dome_calib.body3d_scene`): x, y, z in cm (Panoptic
world), c = mean detection confidence of the supporting views, -1 (and x = y = z = 0) where the joint could not be
reconstructed.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import model_validator

from dome_calib.arrays import per_row
from dome_calib.bundle import Bundle
from dome_calib.body3d_scene import scene_json, write_scene_folder
from dome_calib.bundle_schema import FrameIndex
from dome_calib.recon.errors import ReconError
from dome_calib.schema import INT64_MAX, CameraName, Field, FieldError, FileSchema, Finite, Vec, read_json
from dome_calib.recon.streams import SkeletonSequence, StreamTracks, group_by_stream

logger = logging.getLogger(__name__)

#: u, v or c of one joint: a finite number, or null (not detected). NaN is refused as in every file (JSON has no
#: NaN; Python's json writes it for a float NaN: write None).
Value = Finite | None


class CameraDetections(FileSchema):
    """One camera's detections: ``frames`` its own stream's frame indices, increasing; ``joints`` per frame the
    body's joints ``[u, v, c]`` (px, OpenCV pixel centres; c in [0, 1]; null in any of them: not detected)."""

    frames: Annotated[list[FrameIndex], Field(min_length=1)] = Field(description="frame indices, increasing")
    joints: list[list[Vec(3, Value)]] = Field(description="frames x joints x [u, v, c]")

    @model_validator(mode="after")
    def _shaped(self) -> CameraDetections:
        for k in range(1, len(self.frames)):
            if self.frames[k] <= self.frames[k - 1]:
                raise FieldError(("frames", k), f"frame {self.frames[k]} after {self.frames[k - 1]}: frame indices "
                                                "must increase")
        if len(self.joints) != len(self.frames):
            raise FieldError(("joints",), f"{len(self.joints)} frames of joints for {len(self.frames)} frames "
                                          "(expected one per frame)")
        for f, row in enumerate(self.joints):
            if len(row) != len(self.joints[0]):
                raise FieldError(("joints", f), f"{len(row)} joints, frame {self.frames[0]} has "
                                                f"{len(self.joints[0])} (one body model per file)")
            for j, (_, _, c) in enumerate(row):
                if c is not None and not 0.0 <= c <= 1.0:
                    raise FieldError(("joints", f, j, 2), f"confidence {c:g} outside [0, 1] (null means not "
                                                          "detected)")
        return self


class DetectionsFile(FileSchema):
    """``triangulate``'s detections file: one body's 2D joints per camera per frame of that camera's own stream;
    ``joints`` (default: the files'), ``body_id`` (the id written), ``reference`` (the stream whose frames are the
    output times: vga, hd, KINECTNODE<n>; default vga, else hd), ``times_ms`` (universal times to reconstruct
    instead, ms)."""

    joints: Annotated[int, Field(ge=1)] | None = Field(None, description="joints per body (all cameras alike)")
    body_id: Annotated[int, Field(ge=0, le=INT64_MAX)] = 0
    reference: Annotated[str, Field(min_length=1)] | None = None
    times_ms: Annotated[list[Finite], Field(min_length=1)] | None = Field(None, description="universal times, ms")
    cameras: Annotated[dict[CameraName, CameraDetections], Field(min_length=1)]

    @model_validator(mode="after")
    def _one_body_model(self) -> DetectionsFile:
        want = self.joints
        for name, cam in self.cameras.items():
            have = len(cam.joints[0]) if cam.joints else want
            if want is None:
                want = have
            if have != want:
                raise FieldError(("cameras", name, "joints", 0), f"{have} joints but expected {want}"
                                 + (" (field joints)" if self.joints is not None else " (as the cameras before)"))
        return self


def read_detections(path: str | Path) -> dict:
    """A detections file (:class:`DetectionsFile`) -> {"cameras": {name: (frames (F,), uv (F, J, 2), conf (F, J))},
    "joints", "body_id", "reference", "times_ms"}; null (in u, v or c) = not detected, returned as c = 0."""
    path = Path(path)
    data = read_json(path, DetectionsFile, error=ReconError)
    out: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    n_joints = data.joints
    for name, cam in data.cameras.items():
        joints = np.array([[[np.nan if x is None else x for x in j] for j in row] for row in cam.joints],
                          dtype=float).reshape(len(cam.frames), -1, 3) if cam.joints else np.zeros((0, 0, 3))
        uv, conf = joints[..., :2], joints[..., 2]
        conf = np.where(np.isnan(conf) | np.any(np.isnan(uv), axis=-1), 0.0, conf)
        out[name] = (np.asarray(cam.frames, dtype=np.int64), uv, conf)
        n_joints = n_joints or joints.shape[1]
    times = None if data.times_ms is None else np.asarray(data.times_ms, dtype=float)
    return {"cameras": out, "joints": int(n_joints), "body_id": data.body_id, "reference": data.reference,
            "times_ms": times}


def default_times(streams: list[StreamTracks], reference: str | None) -> tuple[np.ndarray, np.ndarray, str]:
    """Universal times to reconstruct when none are given: the reference stream's frames that have detections
    (reference: given, else "vga", else "hd", else the stream with most cameras) -> (times_ms, frame index, name)."""
    by_name = {s.stream: s for s in streams}
    if reference is not None and reference not in by_name:
        raise ReconError(f"reference stream {reference!r} has no detections (streams: {', '.join(sorted(by_name))})")
    name = reference or next((n for n in ("vga", "hd") if n in by_name),
                             max(streams, key=lambda s: len(s.cameras)).stream)
    s = by_name[name]
    frames = s.frame_index[np.any(per_row(s.conf) > 0, axis=1)]  # NaN: not detected
    try:
        return s.table.times_of(frames), frames, name
    except KeyError as exc:
        raise ReconError(f"stream {name}: {exc.args[0]}") from None


def load_detection_streams(bundle: Bundle, path: str | Path) -> tuple[list[StreamTracks], dict]:
    """Detections file -> (streams grouped with the bundle's sync tables, parsed header)."""
    parsed = read_detections(path)
    missing = [n for n in parsed["cameras"] if n not in bundle.cameras]
    if missing:
        raise ReconError(f"{path}: camera {missing[0]} is not in the bundle's calibration")
    return group_by_stream(bundle, parsed["cameras"]), parsed


def check_times(path: str | Path, streams: list[StreamTracks], times_ms: np.ndarray) -> list[str]:
    """Times against the detections on the sync tables -> the streams whose detected frames reach some of the
    times. None covered: ReconError; some not: one warning with the counts (their skeletons have no joints); a
    stream that reaches none: one warning naming it (its cameras contribute nothing: another session's table?).
    Detected frames missing from their stream's sync table: one warning per stream."""
    covered = np.zeros(len(times_ms), bool)
    spans, used = [], []
    for s in streams:
        detected = s.frame_index[np.any(per_row(s.conf) > 0, axis=1)]
        timed = np.isin(detected, s.table.index)
        if not np.all(timed):
            logger.warning("%s: stream %s: %d of %d frames with detections are not in the sync table (first: frame "
                           "%d): they are not used", path, s.stream, int((~timed).sum()), len(detected),
                           int(detected[~timed][0]))
        if not np.any(timed):
            continue
        t0, t1 = s.table.times_of(detected[timed][[0, -1]])
        reach = (times_ms >= t0) & (times_ms <= t1)
        covered |= reach
        spans.append(f"{s.stream} {t0:.1f}..{t1:.1f} ms")
        if reach.any():
            used.append(s.stream)
        else:
            logger.warning("%s: stream %s (cameras %s): its detected frames lie at %.1f..%.1f ms, none of the %d "
                           "times: its cameras contribute nothing (is its sync table the one of this session?)",
                           path, s.stream, ", ".join(s.cameras[:4]) + (", ..." if len(s.cameras) > 4 else ""),
                           t0, t1, len(times_ms))
    span_text = "; ".join(spans) or "no detected frame is in a sync table"
    if not covered.any():
        raise ReconError(f"{path}: times_ms: none of the {len(times_ms)} times lies within the detected "
                         f"frames' universal times ({span_text})")
    if not covered.all():
        logger.warning("%s: %d of %d times lie outside the detected frames' universal times (%s): their skeletons "
                       "have no joints (c = -1)", path, int((~covered).sum()), len(times_ms), span_text)
    return used


def write_skeletons(folder: str | Path, seq: SkeletonSequence, numbers: np.ndarray, *, body_id: int = 0,
                    fps_type: str = "custom") -> list[Path]:
    """Write ``body3DScene_<number:08d>.json`` per time into ``folder`` (one body, ``body_id``), replacing it as a
    whole (:func:`dome_calib.body3d_scene.write_scene_folder`)."""
    ids = np.array([body_id])
    return write_scene_folder(folder, numbers, (
        scene_json(seq.times_ms[k], ids, seq.X_cm[k][None], seq.confidence[k][None], seq.n_inliers[k][None], fps_type)
        for k in range(len(numbers))))
