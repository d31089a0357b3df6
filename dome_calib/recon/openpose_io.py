"""Read a folder of OpenPose output: one sub-folder per camera, one JSON file per frame, several people per file.

Layout::

    DETECTIONS/<camera folder>/<anything><frame>[_keypoints].json    e.g. 00_01/00_01_000000000042_keypoints.json
                                                                           cam01_json/cam01.0042.json

The last number of the file name (before ``_keypoints``) is the frame: that camera's own stream frame index. A
camera folder is the bundle's camera name, or is mapped to one (:func:`parse_camera_map`: ``cam01=00_01,...`` or a
JSON file ``{"cam01": "00_01"}``). Each file is OpenPose's ``{"people": [{"pose_keypoints_2d": [x, y, c] * J}]}``;
people carry no identity. Keypoints are mapped to Panoptic joints19 (:mod:`dome_calib.recon.body_models`).

Every problem is one line naming the file, the camera and the frame (:class:`ReconError`).
"""
from __future__ import annotations

import json
import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dome_calib.recon.body_models import JOINT_NAMES, BodyModel, models_with_joints, parse_body_model, to_joints19
from dome_calib.recon.errors import ReconError

logger = logging.getLogger(__name__)

_LAST_NUMBER = re.compile(r"(\d+)(?!.*\d)")


@dataclass(frozen=True)
class OpenPoseDetections:
    """People detected per camera and frame, no identity.

    people: camera name -> {frame index -> (N, 19, 3) joints19 ``[x_px, y_px, c]`` (c = 0: not detected)};
    files: camera name -> {frame index -> the file it came from} (for messages); body_model: the model read.
    """

    people: dict[str, dict[int, np.ndarray]]
    files: dict[str, dict[int, Path]]
    body_model: BodyModel


def parse_camera_map(text: str | None) -> dict[str, str]:
    """``"cam01=00_01,cam02=00_02"`` or the path of a JSON object ``{"cam01": "00_01"}`` -> {folder: camera}."""
    if not text:
        return {}
    path = Path(text)
    if text.endswith(".json") or path.is_file():
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise ReconError(f"{path}: camera map cannot be read ({exc.strerror})") from None
        except json.JSONDecodeError as exc:
            raise ReconError(f"{path}: camera map is not valid JSON ({exc.msg} at line {exc.lineno})") from None
        if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
            raise ReconError(f"{path}: camera map must be a JSON object {{\"folder\": \"camera name\"}}")
        return dict(data)
    out = {}
    for item in text.split(","):
        folder, sep, camera = item.strip().partition("=")
        if not sep or not folder.strip() or not camera.strip():
            raise ReconError(f"camera map entry {item.strip()!r} is not FOLDER=CAMERA (e.g. cam01=00_01)")
        out[folder.strip()] = camera.strip()
    return out


def frame_of_file(path: Path) -> int:
    """The frame index in a file name: its last number (``cam01.0042.json`` -> 42, ``x_000000000042_keypoints``
    -> 42)."""
    stem = path.name[: -len(".json")]
    stem = stem[: -len("_keypoints")] if stem.endswith("_keypoints") else stem
    match = _LAST_NUMBER.search(stem)
    if match is None:
        raise ReconError(f"{path}: no frame number in the file name (expected e.g. cam01.0042.json or "
                         "cam01_000000000042_keypoints.json)")
    return int(match.group(1))


def _people_of_file(path: Path, camera: str, frame: int,
                    model: BodyModel | None) -> tuple[np.ndarray, BodyModel | None]:
    """One OpenPose file -> ((N, J, 3) keypoints in the file's model order, the model: given or told by J)."""
    where = f"{path}: camera {camera}: frame {frame}"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise ReconError(f"{where}: not a UTF-8 text file") from None
    except json.JSONDecodeError as exc:
        raise ReconError(f"{where}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict) or not isinstance(data.get("people"), list):
        raise ReconError(f"{where}: expected OpenPose's {{\"people\": [{{\"pose_keypoints_2d\": [x, y, c, ...]}}]}}")
    rows = []
    for k, person in enumerate(data["people"]):
        kp = person.get("pose_keypoints_2d") if isinstance(person, dict) else None
        if not isinstance(kp, list) or not all(type(v) in (int, float) or v is None for v in kp):
            raise ReconError(f"{where}: person {k}: pose_keypoints_2d must be a list of numbers")
        if not kp:
            continue  # OpenPose writes an empty list when the body network was off for this person
        if len(kp) % 3:
            raise ReconError(f"{where}: person {k}: pose_keypoints_2d has {len(kp)} numbers, not a multiple of 3 "
                             "([x, y, c] per joint)")
        rows.append(np.array([np.nan if v is None else v for v in kp], dtype=float).reshape(-1, 3))
    if not rows:
        return np.zeros((0, len(JOINT_NAMES[model]) if model else 0, 3)), model
    counts = sorted({len(r) for r in rows})
    if len(counts) > 1:
        raise ReconError(f"{where}: people have different joint counts {counts}")
    J = counts[0]
    fits = models_with_joints(J)
    if not fits:
        known = ", ".join(f"{m.value} {len(JOINT_NAMES[m])}" for m in BodyModel)
        raise ReconError(f"{where}: {J} joints per person fits no body model ({known})")
    if model is None:
        if len(fits) > 1:
            raise ReconError(f"{where}: {J} joints per person fits {' and '.join(m.value for m in fits)}: give "
                             "--body-model")
        model = fits[0]
    elif model not in fits:
        raise ReconError(f"{where}: {J} joints per person but body model {model.value} has "
                         f"{len(JOINT_NAMES[model])}")
    kp = np.stack(rows)
    conf = kp[..., 2]
    bad = np.isinf(kp).any(axis=-1) | (conf < 0) | (conf > 1)
    if np.any(bad):
        p, j = np.argwhere(bad)[0]
        raise ReconError(f"{where}: person {p}: joint {j}: {kp[p, j].tolist()} is not a pixel and a confidence in "
                         "[0, 1]")
    missing = np.isnan(kp).any(axis=-1)
    kp[missing] = 0.0
    return kp, model


def index_openpose_folder(folder: str | Path, *, camera_map: dict[str, str] | None = None,
                          cameras: set[str] | None = None) -> dict[str, dict[int, Path]]:
    """The files of ``folder`` without reading them: camera -> {frame -> path} (see the module docstring).

    Args:
        camera_map: sub-folder name -> camera name (sub-folders not in it keep their own name).
        cameras: the bundle's camera names; a sub-folder naming another camera is refused.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ReconError(f"{folder}: detections folder not found (expected one sub-folder per camera)")
    camera_map = camera_map or {}
    files: dict[str, dict[int, Path]] = {}
    subfolders = sorted(p for p in folder.iterdir() if p.is_dir())
    unknown_map = sorted(set(camera_map) - {p.name for p in subfolders})
    if unknown_map:
        raise ReconError(f"{folder}: camera map names folder {unknown_map[0]!r}, which is not there")
    for sub in subfolders:
        camera = camera_map.get(sub.name, sub.name)
        json_files = sorted(sub.glob("*.json"))
        if not json_files:
            continue
        if cameras is not None and camera not in cameras:
            hint = "" if sub.name in camera_map else " (map folder names to cameras with --camera-map)"
            raise ReconError(f"{sub}: camera {camera} is not in the bundle's calibration{hint}")
        if camera in files:
            raise ReconError(f"{sub}: camera {camera} has a second folder")
        files[camera] = {}
        for path in json_files:
            frame = frame_of_file(path)
            if frame in files[camera]:
                raise ReconError(f"{path}: camera {camera}: frame {frame}: a second file for this frame "
                                 f"({files[camera][frame].name})")
            files[camera][frame] = path
    if not files:
        raise ReconError(f"{folder}: no camera sub-folder with OpenPose .json files")
    return files


def body_model_of(files: dict[str, dict[int, Path]], body_model: BodyModel | str | None) -> BodyModel:
    """The given model, or the one told by the first file with a person (in camera, frame order); a joint count
    that fits two models (25: BODY_25, BODY_25B) is refused naming that file."""
    if body_model is not None:
        return parse_body_model(body_model) if isinstance(body_model, str) else body_model
    for camera in sorted(files):
        for frame, path in sorted(files[camera].items()):
            kp, model = _people_of_file(path, camera, frame, None)
            if model is not None:
                return model
    first = next(iter(files.values()))
    raise ReconError(f"{next(iter(first.values())).parent.parent}: no person detected in any file, so the body "
                     "model is unknown (give --body-model)")


def read_openpose_files(files: dict[str, dict[int, Path]], model: BodyModel) -> dict[str, dict[int, np.ndarray]]:
    """Read the files (camera -> {frame -> path}) -> camera -> {frame -> (N, 19, 3) joints19}."""
    n_joints = len(JOINT_NAMES[model])
    out: dict[str, dict[int, np.ndarray]] = {}
    for camera, frames in files.items():
        out[camera] = {}
        for frame, path in frames.items():
            kp, _ = _people_of_file(path, camera, frame, model)
            out[camera][frame] = to_joints19(kp.reshape(-1, n_joints, 3), model)
    return out


def read_openpose_folder(folder: str | Path, *, body_model: BodyModel | str | None = None,
                         camera_map: dict[str, str] | None = None, cameras: set[str] | None = None
                         ) -> OpenPoseDetections:
    """Read every camera sub-folder of ``folder`` (see the module docstring; :func:`index_openpose_folder` for the
    arguments). body_model: the detector's model; None: told by the joint count, refused where it is ambiguous."""
    files = index_openpose_folder(folder, camera_map=camera_map, cameras=cameras)
    model = body_model_of(files, body_model)
    people = read_openpose_files(files, model)
    logger.info("read %d cameras, %d files, body model %s", len(people), sum(len(f) for f in people.values()), model)
    return OpenPoseDetections(people=people, files=files, body_model=model)
