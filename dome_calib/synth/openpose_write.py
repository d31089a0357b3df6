"""OpenPose's own files (``--write_json``) of synthetic detections: one sub-folder per camera, one JSON document
per frame (version 1.3, every array OpenPose writes, missed joints as ``0, 0, 0``), in any body model's joint order."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from dome_calib.io_utils import atomic_folder
from dome_calib.recon.body_models import EXTRA_JOINTS, JOINT_NAMES, from_joints19, parse_body_model
from dome_calib.schema import path_of_name
from dome_calib.synth.detector_model import DetectorError

logger = logging.getLogger(__name__)

OPENPOSE_VERSION = 1.3
NAMINGS = ("openpose", "dotted")


def openpose_file_name(camera: str, frame: int, naming: str = "openpose") -> str:
    """``<camera>_<frame:012d>_keypoints.json`` (OpenPose's ``--write_json``) or ``<camera>.<frame:04d>.json``."""
    if naming == "openpose":
        return f"{camera}_{frame:012d}_keypoints.json"
    if naming == "dotted":
        return f"{camera}.{frame:04d}.json"
    raise DetectorError(f"naming {naming!r} is unknown (known: {', '.join(NAMINGS)})")


def openpose_document(people: np.ndarray, body_model: str = "BODY_25", extras: np.ndarray | None = None) -> dict:
    """(N, 19, 3) joints19 detections of one image -> OpenPose's JSON document (``--write_json``, version 1.3) in
    the body model's joint order (joints the model has and joints19 lacks, and missed joints: 0, 0, 0). extras
    (N, E, 3): the model's :data:`~dome_calib.recon.body_models.EXTRA_JOINTS` (e.g. BODY_25's feet), in that order."""
    model = parse_body_model(body_model)
    kp = from_joints19(np.asarray(people, dtype=float).reshape(-1, 19, 3), model)
    if extras is not None:
        names = JOINT_NAMES[model]
        kp[:, [names.index(n) for n in EXTRA_JOINTS[model]]] = np.asarray(extras, dtype=float).reshape(
            len(kp), len(EXTRA_JOINTS[model]), 3)
    empty = {k: [] for k in ("face_keypoints_2d", "hand_left_keypoints_2d", "hand_right_keypoints_2d",
                             "pose_keypoints_3d", "face_keypoints_3d", "hand_left_keypoints_3d",
                             "hand_right_keypoints_3d")}
    return {"version": OPENPOSE_VERSION, "people": [
        {"person_id": [-1], "pose_keypoints_2d": [0 if v == 0 else float(v) for v in person.reshape(-1)]} | empty
        for person in kp]}


def write_openpose_folder(folder: str | Path, detections: dict[str, dict[int, np.ndarray]], *,
                          body_model: str = "BODY_25", naming: str = "openpose",
                          extras: dict[str, dict[int, np.ndarray]] | None = None) -> Path:
    """Write detections as OpenPose writes them: one sub-folder per camera, one JSON file per frame.

    Args:
        detections: as :func:`synth_detections` returns (camera -> frame -> (N, 19, 3) joints19).
        body_model: "BODY_25", "BODY_25B", "COCO_18" or "PANOPTIC19" (:mod:`dome_calib.recon.body_models`).
        naming: "openpose" (``<camera>_<frame:012d>_keypoints.json``) or "dotted" (``<camera>.<frame:04d>.json``).
        extras: in the same shape, each detection's joints of the model that joints19 lacks (``(N, E, 3)``,
            :func:`~dome_calib.synth.detector.feet_detections` for BODY_25's feet); default: none (0, 0, 0).
    Returns:
        ``folder``, written as a whole (staged beside it, then renamed; an old folder is replaced).
    Example:
        >>> write_openpose_folder(tmp / "detections", synth_detections(bundle, truth), body_model="COCO_18")
    """
    parse_body_model(body_model)
    openpose_file_name("x", 0, naming)
    target = Path(folder)
    with atomic_folder(target) as staging:
        for camera in sorted(detections):
            sub = path_of_name(staging, camera)
            sub.mkdir()
            for frame, people in sorted(detections[camera].items()):
                doc = openpose_document(people, body_model,
                                        None if extras is None else extras[camera][frame])
                (sub / openpose_file_name(camera, int(frame), naming)).write_text(
                    json.dumps(doc, separators=(",", ":")) + "\n", encoding="utf-8")
    logger.info("wrote %d cameras of %s detections to %s", len(detections), body_model, target)
    return target
