"""JSON in/out of ``dome-calib triangulate`` (documented in docs/recon.md, "Detections file").

In: a detections file (2D joints per camera per frame of that camera's own stream)::

    {"joints": 19, "body_id": 0, "reference": "vga", "times_ms": [...],      (all optional)
     "cameras": {"01_01": {"frames": [100, 101], "joints": [[[u, v, c], ... J], ...]}, ...}}

Out: one Panoptic ``body3DScene`` file per time, ``body3DScene_<k:08d>.json``::

    {"version": 0.7, "univTime": t_ms, "fpsType": "vga_25", "bodies": [{"id": 0, "joints19": [x, y, z, c, ...],
     "inlierViews19": [n, ...]}]}

x, y, z in cm (Panoptic world), c = mean detection confidence of the supporting views, -1 (and x = y = z = 0)
where the joint could not be reconstructed.
"""
from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from dome_calib.arrays import per_row
from dome_calib.bundle import Bundle
from dome_calib.io_utils import atomic_folder, foreign_names, output_folder
from dome_calib.recon.errors import ReconError
from dome_calib.recon.streams import SkeletonSequence, StreamTracks, group_by_stream

FPS_TYPE = {"vga": "vga_25", "hd": "hd_29_97"}
KNOWN_KEYS = {"joints", "body_id", "reference", "times_ms", "cameras"}
SKELETON_FILE = re.compile(r"body3DScene_-?\d+\.json")

logger = logging.getLogger(__name__)


def _fail(path: Path, where: str, problem: str) -> ReconError:
    return ReconError(f"{path}: {where}: {problem}")


def _numbers(value: object) -> np.ndarray | None:
    """A JSON list of numbers -> float array, null read as NaN; None if it holds strings, booleans or objects, or
    is ragged."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError, OverflowError):
        return None
    if arr.dtype.kind == "O" and all(v is None or type(v) in (int, float) for v in arr.flat):
        try:
            return np.array([np.nan if v is None else v for v in arr.flat], dtype=float).reshape(arr.shape)
        except OverflowError:
            return None
    return arr.astype(float) if arr.dtype.kind in "iuf" else None


def _confidence(path: Path, where: str, frames: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Confidences (F, J) of ``[u, v, c]`` joints: NaN in u, v or c means not detected (c = 0); c outside [0, 1]
    or an infinite pixel is refused, naming the frame and joint."""
    uv, conf = joints[..., :2], joints[..., 2]
    bad = (conf < 0) | (conf > 1) | np.any(np.isinf(uv), axis=-1)
    if np.any(bad):
        f, j = np.argwhere(bad)[0]
        u, v, c = joints[f, j]
        problem = f"confidence {c:g} outside [0, 1]" if not 0 <= c <= 1 else f"pixel ({u:g}, {v:g}) is not finite"
        raise _fail(path, f"{where}: frame {int(frames[f])}: joint {int(j)}",
                    f"{problem} (NaN means not detected){f'; {int(bad.sum())} such values' if bad.sum() > 1 else ''}")
    return np.where(np.isnan(conf) | np.any(np.isnan(uv), axis=-1), 0.0, conf)


def read_detections(path: str | Path) -> dict:
    """Parse and validate a detections file -> {"cameras": {name: (frames (F,), uv (F, J, 2), conf (F, J))},
    "joints", "body_id", "reference", "times_ms"}. Confidences are in [0, 1]; NaN or null (in u, v or c) = not
    detected, returned as c = 0."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ReconError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise _fail(path, "top level", "expected an object with 'cameras'")
    unknown = set(data) - KNOWN_KEYS
    if unknown:
        raise _fail(path, "top level", f"unknown key {sorted(unknown)[0]!r} (known: {', '.join(sorted(KNOWN_KEYS))})")
    cams = data.get("cameras")
    if not isinstance(cams, dict) or not cams:
        raise _fail(path, "field 'cameras'", "missing or empty (expected {camera name: {frames, joints}})")
    out: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    n_joints = data.get("joints")
    if n_joints is not None and (type(n_joints) is not int or n_joints < 1):
        raise _fail(path, "field 'joints'", f"expected a positive integer (joints per body), got "
                    f"{json.dumps(n_joints)[:40]}")
    if data.get("reference") is not None and not isinstance(data["reference"], str):
        raise _fail(path, "field 'reference'", f"expected a stream name (vga, hd, KINECTNODE<n>), got "
                    f"{json.dumps(data['reference'])[:40]}")
    body_id = data.get("body_id", 0)
    if not isinstance(body_id, int) or isinstance(body_id, bool):
        raise _fail(path, "field 'body_id'", f"expected an integer, got {json.dumps(body_id)[:40]}")
    for name, entry in cams.items():
        where = f"camera {name}"
        if not isinstance(entry, dict) or "frames" not in entry or "joints" not in entry:
            raise _fail(path, where, "expected {\"frames\": [...], \"joints\": [[[u, v, c], ...], ...]}")
        frames, joints = _numbers(entry["frames"]), _numbers(entry["joints"])
        if frames is None or joints is None:
            raise _fail(path, where, "frames and joints must be numbers")
        if (frames.ndim != 1 or not np.all(np.abs(frames) < 2**53) or np.any(frames != np.round(frames))
                or np.any(np.diff(frames) <= 0)):
            raise _fail(path, f"{where}: field 'frames'", "expected increasing integer frame indices")
        if joints.ndim != 3 or joints.shape[0] != len(frames) or joints.shape[2] != 3:
            raise _fail(path, f"{where}: field 'joints'",
                        f"shape {joints.shape} but expected ({len(frames)}, J, 3) = frames x joints x [u, v, c]")
        if n_joints is None:
            n_joints = joints.shape[1]
        if joints.shape[1] != n_joints:
            raise _fail(path, f"{where}: field 'joints'", f"{joints.shape[1]} joints but expected {n_joints}")
        conf = _confidence(path, where, frames, joints)
        out[name] = (frames.astype(np.int64), joints[..., :2], conf)
    times = data.get("times_ms")
    if times is not None:
        times = _numbers(times)
        if times is None or times.ndim != 1 or not times.size:
            raise _fail(path, "field 'times_ms'", "expected a list of numbers (ms), not empty")
        if not np.all(np.isfinite(times)):
            raise _fail(path, "field 'times_ms'", "contains NaN or infinity")
    return {"cameras": out, "joints": int(n_joints), "body_id": body_id,
            "reference": data.get("reference"), "times_ms": times}


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


def check_times(path: str | Path, streams: list[StreamTracks], times_ms: np.ndarray) -> np.ndarray:
    """Times against the detections on the sync tables -> (T,) bool, True where some stream has detected frames
    on both sides (or at) the time. None covered: ReconError; some not: one warning with the counts (their
    skeletons have no joints). Detected frames missing from their stream's sync table: one warning per stream."""
    covered = np.zeros(len(times_ms), bool)
    spans = []
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
        covered |= (times_ms >= t0) & (times_ms <= t1)
        spans.append(f"{s.stream} {t0:.1f}..{t1:.1f} ms")
    span_text = "; ".join(spans) or "no detected frame is in a sync table"
    if not covered.any():
        raise _fail(Path(path), "field 'times_ms'", f"none of the {len(times_ms)} times lies within the detected "
                    f"frames' universal times ({span_text})")
    if not covered.all():
        logger.warning("%s: %d of %d times lie outside the detected frames' universal times (%s): their skeletons "
                       "have no joints (c = -1)", path, int((~covered).sum()), len(times_ms), span_text)
    return covered


def check_output_folder(folder: str | Path) -> Path:
    """The skeleton folder ``-o`` may replace: absent, empty or holding only body3DScene files (an earlier run's);
    anything else is refused before any work."""
    target = output_folder(folder)
    other = foreign_names(target, SKELETON_FILE.fullmatch)
    if other:
        raise ReconError(f"{folder}: holds {other[0]!r}, which is not a body3DScene file: the skeleton folder is "
                         "replaced as a whole, so give a new folder or one of an earlier run")
    return target


def skeleton_json(seq: SkeletonSequence, k: int, *, body_id: int = 0, fps_type: str = "custom") -> dict:
    """One Panoptic body3DScene object for time ``k`` of the sequence."""
    J = seq.X_cm.shape[1]
    flat: list[float] = []
    for j in range(J):
        X, c = seq.X_cm[k, j], float(seq.confidence[k, j])
        if not (np.all(np.isfinite(X)) and c >= 0):
            flat += [0.0, 0.0, 0.0, -1.0]
        else:
            flat += [round(float(v), 4) for v in X] + [round(c, 4)]
    return {"version": 0.7, "univTime": round(float(seq.times_ms[k]), 4), "fpsType": fps_type,
            "bodies": [{"id": body_id, f"joints{J}": flat, f"inlierViews{J}": [int(n) for n in seq.n_inliers[k]]}]}


def write_skeletons(folder: str | Path, seq: SkeletonSequence, numbers: np.ndarray, *, body_id: int = 0,
                    fps_type: str = "custom") -> list[Path]:
    """Write ``body3DScene_<number:08d>.json`` per time into ``folder``, replacing it as a whole (staged beside it,
    then renamed): a reader sees the earlier run's files or this run's, never a mix."""
    folder = check_output_folder(folder)
    names = []
    with atomic_folder(folder) as staging:
        for k, number in enumerate(numbers):
            obj = skeleton_json(seq, k, body_id=body_id, fps_type=fps_type)
            names.append(f"body3DScene_{int(number):08d}.json")
            (staging / names[-1]).write_text(json.dumps(obj, allow_nan=False) + "\n", encoding="utf-8")
    return [folder / n for n in names]


def read_skeleton(path: str | Path) -> tuple[float, np.ndarray, np.ndarray]:
    """A body3DScene file -> (univTime ms, X_cm (J, 3) NaN where c < 0, confidence (J,)) of its first body."""
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    body = data["bodies"][0]
    key = next(k for k in body if k.startswith("joints"))
    arr = np.asarray(body[key], dtype=float).reshape(-1, 4)
    X = np.where(arr[:, 3:4] < 0, np.nan, arr[:, :3])
    return float(data["univTime"]), X, arr[:, 3]


def fps_type_of(stream: str, explicit_times: bool) -> str:
    """Panoptic ``fpsType`` label for output times taken from ``stream`` (``custom`` for explicit times)."""
    return "custom" if explicit_times else FPS_TYPE.get(stream, "custom")


