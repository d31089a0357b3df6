"""Read a folder of OpenPose output: one sub-folder per camera, one JSON file per frame, several people per file.

Layout::

    DETECTIONS/<camera folder>/<anything><frame>[_keypoints].json    e.g. 00_01/00_01_000000000042_keypoints.json
                                                                           cam01_json/cam01.0042.json

The last number of the file name (before ``_keypoints``) is the frame: that camera's own stream frame index, at most
12 digits as OpenPose writes it (:data:`MAX_FRAME`). ``.json`` is matched in any case (``.JSON``); a sub-folder
without one is said (a camera left out), not skipped in silence. A camera folder is the bundle's camera name, or is
mapped to one (:func:`parse_camera_map`: ``cam01=00_01,...`` or a
JSON file ``{"cam01": "00_01"}``). Each file is OpenPose's ``{"people": [{"pose_keypoints_2d": [x, y, c] * J}]}``;
people carry no identity. Keypoints are mapped to Panoptic joints19 (:mod:`dome_calib.recon.body_models`).

Every problem is one line naming the file, the camera and the frame (:class:`ReconError`).
"""
from __future__ import annotations

import hashlib
import logging
import os
import re
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import AfterValidator, ConfigDict, RootModel

from dome_calib.recon.body_models import (JOINT_NAMES, BodyModel, models_with_joints, parse_body_model, to_joints19,
                                          with_extras)
from dome_calib.recon.errors import ReconError
from dome_calib.recon.joint_order import better_order, order_fits
from dome_calib.schema import Field, FileSchema, Finite, parse_json, read_json, show

logger = logging.getLogger(__name__)

_LAST_NUMBER = re.compile(r"(\d+)(?!.*\d)")
#: The largest frame number: OpenPose writes 12 digits (a trillion frames, 1,000 years at 30 fps); larger ones
#: are no frame index (and would overflow the int64 frame tables and lose the times' precision).
MAX_FRAME = 10**12 - 1
#: The largest pixel coordinate or confidence taken: no image is a million pixels across (larger values overflow
#: the float32 keypoint arrays and the lens model's arithmetic).
MAX_ABS_VALUE = 1e6
#: OpenPose files read to tell the body model from the joint order (spread over cameras and frames).
ORDER_SAMPLE_FILES = 120


def _check_keypoints(values: list[float]) -> list[float]:
    """``[x, y, c] * J``: a multiple of 3 numbers, every confidence >= 0 (pixels: any finite number)."""
    if len(values) % 3:
        raise ValueError(f"{len(values)} numbers, not a multiple of 3 ([x, y, c] per joint)")
    a = np.asarray(values, dtype=float)  # one pass in numpy: this runs for every person of every file
    big = np.flatnonzero(np.abs(a) > MAX_ABS_VALUE)
    if big.size:
        k = int(big[0])
        raise ValueError(f"joint {k // 3}: {'xyc'[k % 3]} = {values[k]:g} is beyond +-{MAX_ABS_VALUE:g} (pixels of "
                         "an image, a confidence)")
    negative = np.flatnonzero(a[2::3] < 0)
    if negative.size:
        j = int(negative[0])
        raise ValueError(f"joint {j}: confidence {show(values[3 * j + 2])} is negative (expected [x_px, y_px, c] with "
                         "c >= 0)")
    return values


#: ``[x_px, y_px, c] * J``, finite, c >= 0 (above 1 allowed: OpenPose's confidences are heatmap peaks).
Keypoints = Annotated[list[Finite], AfterValidator(_check_keypoints)]


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
        return dict(read_json(path, CameraMapFile, error=ReconError).root)
    out = {}
    for item in text.split(","):
        folder, sep, camera = item.strip().partition("=")
        if not sep or not folder.strip() or not camera.strip():
            raise ReconError(f"camera map entry {item.strip()!r} is not FOLDER=CAMERA (e.g. cam01=00_01)")
        out[folder.strip()] = camera.strip()
    return out


def _json_files(folder: Path) -> tuple[list[Path], int]:
    """The ``.json`` files of a folder, the suffix in any case (``.JSON``), sorted, and how many entries it has
    (one directory scan: no stat per file)."""
    with os.scandir(folder) as scan:
        entries = list(scan)
    names = sorted(e.name for e in entries if e.name[-5:].lower() == ".json" and e.is_file())
    return [folder / name for name in names], len(entries)  # sorted as strings: Path comparisons are slow


def frame_of_file(path: Path) -> int:
    """The frame index in a file name: its last number (``cam01.0042.json`` -> 42, ``x_000000000042_keypoints``
    -> 42), at most :data:`MAX_FRAME`."""
    stem = path.name[: -len(".json")]
    stem = stem[: -len("_keypoints")] if stem.lower().endswith("_keypoints") else stem
    match = _LAST_NUMBER.search(stem)
    if match is None:
        raise ReconError(f"{path}: no frame number in the file name (expected e.g. cam01.0042.json or "
                         "cam01_000000000042_keypoints.json)")
    digits = match.group(1).lstrip("0") or "0"
    if len(digits) > len(str(MAX_FRAME)):
        raise ReconError(f"{path}: frame number {digits[:16]}... ({len(digits)} digits) is beyond {MAX_FRAME} "
                         "(OpenPose numbers frames with 12 digits)")
    return int(digits)


class CameraMapFile(RootModel[dict[str, Annotated[str, Field(min_length=1)]]]):
    """A camera map file: ``{"cam01": "00_01", ...}``, detections sub-folder -> the bundle's camera name."""

    model_config = ConfigDict(strict=True)


class OpenPosePerson(FileSchema):
    """One person of an OpenPose file: every field OpenPose has written (1.0 to 1.7); only the body is read.

    ``pose_keypoints_2d`` (1.1 and later; ``pose_keypoints`` in 1.0): ``[x_px, y_px, c] * J``. ``c`` is the
    detector's heatmap peak, not a probability: real output holds values a little above 1 (seen up to 1.04), which
    are read as they are. A joint not detected is ``0, 0, 0``. Face, hands and 3D arrays are accepted, present or
    empty, and not used.
    """

    person_id: list[int] | int = -1
    pose_keypoints_2d: Keypoints | None = None
    pose_keypoints: Keypoints | None = Field(None, description="OpenPose 1.0's name of pose_keypoints_2d")
    face_keypoints_2d: list[Finite] = []
    hand_left_keypoints_2d: list[Finite] = []
    hand_right_keypoints_2d: list[Finite] = []
    pose_keypoints_3d: list[Finite] = []
    face_keypoints_3d: list[Finite] = []
    hand_left_keypoints_3d: list[Finite] = []
    hand_right_keypoints_3d: list[Finite] = []
    face_keypoints: list[Finite] = []
    hand_left_keypoints: list[Finite] = []
    hand_right_keypoints: list[Finite] = []

    def body(self) -> list[float]:
        return self.pose_keypoints_2d if self.pose_keypoints_2d is not None else (self.pose_keypoints or [])


class OpenPoseFile(FileSchema):
    """An OpenPose JSON file (``--write_json``): ``{"version": 1.3, "people": [...], "part_candidates": [...]}``."""

    people: list[OpenPosePerson]
    version: Finite | str | None = None
    part_candidates: list[dict[str, list[Finite]]] = []


def file_digest(data: bytes) -> bytes:
    """What a file's bytes are, in 16 bytes (BLAKE2b): the head and each worker of a cluster compare them."""
    return hashlib.blake2b(data, digest_size=16).digest()


def file_digests(files: dict[str, dict[int, Path]]) -> dict[str, dict[int, bytes]]:
    """camera -> {frame -> :func:`file_digest`} of the files as this machine reads them (the head of a run on a
    cluster, before its workers read theirs)."""
    out: dict[str, dict[int, bytes]] = {}
    for camera, frames in files.items():
        out[camera] = {}
        for frame, path in frames.items():
            try:
                out[camera][frame] = file_digest(path.read_bytes())
            except OSError as exc:
                raise ReconError(f"{path}: camera {camera}: frame {frame}: cannot be read ({exc.strerror})") from None
    return out


def _raw_people(path: Path, camera: str, frame: int, digest: bytes | None = None) -> np.ndarray:
    """One OpenPose file -> (N, J, 3) keypoints in the file's own order; J fits a model ((0, 0, 3): nobody).
    ``digest``: what the file's bytes must be (:func:`file_digest` on the head): a worker reading another copy
    fails naming the file and the machine."""
    where = f"{path}: camera {camera}: frame {frame}"
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ReconError(f"{where}: cannot be read ({exc.strerror})") from None
    if digest is not None and file_digest(data) != digest:
        raise ReconError(f"{where}: its bytes on {socket.gethostname()} (a worker) differ from the file the run "
                         "indexed on its head: every worker must read the same detections at the same path (another "
                         "copy, or changed since?)")
    parsed = parse_json(where, data, OpenPoseFile, error=ReconError)
    rows = [np.asarray(body, dtype=float).reshape(-1, 3) for body in (p.body() for p in parsed.people) if body]
    # a person with an empty body (OpenPose's body network off for it) carries nothing
    if not rows:
        return np.zeros((0, 0, 3))
    counts = sorted({len(r) for r in rows})
    if len(counts) > 1:
        raise ReconError(f"{where}: people have different joint counts {counts}")
    if not models_with_joints(counts[0]):
        known = ", ".join(f"{m.value} {len(JOINT_NAMES[m])}" for m in BodyModel)
        raise ReconError(f"{where}: {counts[0]} joints per person fits no body model ({known})")
    return np.stack(rows)


def _people_of_file(path: Path, camera: str, frame: int, model: BodyModel | None,
                    digest: bytes | None = None) -> tuple[np.ndarray, BodyModel | None]:
    """One OpenPose file -> ((N, J, 3) keypoints in the file's model order, the model: given or told by J)."""
    kp = _raw_people(path, camera, frame, digest)
    if not len(kp):
        return np.zeros((0, len(JOINT_NAMES[model]) if model else 0, 3)), model
    J = kp.shape[1]
    fits = models_with_joints(J)
    if model is None:
        if len(fits) > 1:
            raise ReconError(f"{path}: camera {camera}: frame {frame}: {J} joints per person fits "
                             f"{' and '.join(m.value for m in fits)}: give --body-model")
        model = fits[0]
    elif model not in fits:
        raise ReconError(f"{path}: camera {camera}: frame {frame}: {J} joints per person but body model "
                         f"{model.value} has {len(JOINT_NAMES[model])}")
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
        json_files, n_entries = _json_files(sub)
        if not json_files:  # said, not skipped in silence: a camera the user expected may be missing
            what = "empty" if not n_entries else f"{n_entries} entries, none a .json file"
            logger.warning("%s: no OpenPose .json file (%s): camera %s left out", sub, what, camera)
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


def _order_sample(files: dict[str, dict[int, Path]], n_joints: int) -> np.ndarray:
    """(N, n_joints, 3) people of up to :data:`ORDER_SAMPLE_FILES` files spread evenly over the cameras and their
    frames (raw order: no model applied)."""
    per_camera = max(1, ORDER_SAMPLE_FILES // max(len(files), 1))
    rows = [np.zeros((0, n_joints, 3))]
    for camera in sorted(files):
        frames = sorted(files[camera])
        for k in np.unique(np.linspace(0, len(frames) - 1, min(per_camera, len(frames))).round().astype(int)):
            kp = _raw_people(files[camera][frames[k]], camera, frames[k])
            if kp.shape[1:] == (n_joints, 3):
                rows.append(kp)
    return np.concatenate(rows)


def _order_evidence(fits: list) -> str:
    return ", ".join(f"as {f.model.value} x{f.misfit:.2f}" for f in fits)


def body_model_of(files: dict[str, dict[int, Path]], body_model: BodyModel | str | None) -> BodyModel:
    """The given model, or the one told by the first file with a person (in camera, frame order); a joint count
    that fits two models (25: BODY_25, BODY_25B) is refused naming that file. Where two models have the files'
    joint count, a sample of the files is read to check the joint order (:mod:`~dome_calib.recon.joint_order`):
    a model whose order does not make bodies where the other's does is refused naming the one that fits."""
    folder = next(iter(next(iter(files.values())).values())).parent.parent
    named = parse_body_model(body_model) if isinstance(body_model, str) else body_model
    first = None
    for camera in sorted(files):
        for frame, path in sorted(files[camera].items()):
            kp = _people_of_file(path, camera, frame, named)[0] if named else _raw_people(path, camera, frame)
            if len(kp):
                first = (path, kp.shape[1])
                break
        if first:
            break
    if first is None:
        if named is not None:
            return named
        raise ReconError(f"{folder}: no person detected in any file, so the body model is unknown (give --body-model)")
    path, n_joints = first
    candidates = models_with_joints(n_joints)
    if len(candidates) == 1:
        return candidates[0]
    sample = _order_sample(files, n_joints)
    if named is None:
        fits = order_fits(sample)
        told = better_order(sample, fits[-1].model)
        hint = (f"; the joint order fits {told[1].model.value} (bones off a person's proportions "
                f"{_order_evidence(fits)}, {told[1].people} people)" if told else "")
        raise ReconError(f"{path}: {n_joints} joints per person fits {' and '.join(m.value for m in candidates)}: "
                         f"give --body-model{hint}")
    wrong = better_order(sample, named)
    if wrong is not None:
        mine, best = wrong
        raise ReconError(f"{folder}: --body-model {named.value} does not fit these detections: read in its joint "
                         f"order their bones are x{mine.misfit:.2f} off a person's proportions, in "
                         f"{best.model.value}'s order x{best.misfit:.2f} (median over {best.people} people of "
                         f"{len(files)} cameras): give --body-model {best.model.value}")
    return named


def read_openpose_files(files: dict[str, dict[int, Path]], model: BodyModel,
                        digests: dict[str, dict[int, bytes]] | None = None, *, extras: bool = False
                        ) -> dict[str, dict[int, np.ndarray]]:
    """Read the files (camera -> {frame -> path}) -> camera -> {frame -> (N, 19, 3) joints19}; ``digests``: what
    each file's bytes must be (:func:`file_digests` on the head of a cluster run); with ``extras`` (N, 19 + E, 3):
    the model's joints that joints19 lacks after them (:func:`~dome_calib.recon.body_models.with_extras`)."""
    n_joints = len(JOINT_NAMES[model])
    convert = with_extras if extras else to_joints19
    out: dict[str, dict[int, np.ndarray]] = {}
    for camera, frames in files.items():
        out[camera] = {}
        for frame, path in frames.items():
            digest = digests[camera][frame] if digests is not None else None
            kp, _ = _people_of_file(path, camera, frame, model, digest)
            out[camera][frame] = convert(kp.reshape(-1, n_joints, 3), model)
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
