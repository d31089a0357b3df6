"""The Panoptic ``body3DScene_<frame>.json`` file, in one place: its names, its schema, its writer and its reader.

Every body3DScene file the toolkit writes (``dome-calib reconstruct``, ``dome-calib triangulate``) or reads (the
people export, the people page, the group's judge) goes through this module: the reconstruction room writes and the
people-out room reads, so it lives on the foundation floor below both.

A file (the Panoptic toolbox's README, "Skeleton Output Format"; mmpose's ``body3d_mview_direct_panoptic_dataset.py``
reads the same fields)::

    {"version": 0.7, "univTime": 53541.542, "fpsType": "hd_29_97",
     "bodies": [{"id": 0, "joints19": [x, y, z, c] * 19, "inlierViews19": [n] * 19}, ...]}

x, y, z: world cm (the Panoptic frame, y down); c: the joint's confidence, ``-1`` (and ``0, 0, 0``) where it was not
reconstructed; ``inlierViews19``: the views behind each joint (ours; read, not used). ``joints15`` (the older "mpi15"
layout) in place of ``joints19``. dome-calib's own fields beside them: ``bodyModel`` (the detector's model),
``extraJointNames`` and per body ``extraJoints`` / ``inlierViewsExtra`` (the detector's joints that joints19 lacks, the
same conventions), ``labUp`` (the up axis of the lab world the bundle was imported from) and ``fps`` (the exact rate of
a ``custom`` fpsType). Other fields are none of our business and are ignored. The frame is the number in the file
name. ``dome-calib triangulate`` (one body, any joint count J) writes ``joints<J>`` / ``inlierViews<J>``.

A problem is one line naming the file and the field (``error``, :class:`~dome_calib.errors.PeopleFileError` by
default).
"""
from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterable
from fractions import Fraction
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from dome_calib.errors import PeopleFileError
from dome_calib.ownership import replace_folder
from dome_calib.schema import Finite, NonNegInt, OpenSchema, parse_json

SCENE_FILE = re.compile(r"body3DScene_(-?\d+)\.json")
#: The largest frame number of a file name (12 digits, as OpenPose numbers its files).
MAX_SCENE_FRAME = 10**12 - 1
#: The ``fpsType`` of output times taken from a stream's frames (another stream, or explicit times: ``custom``).
FPS_TYPE = {"vga": "vga_25", "hd": "hd_29_97"}
#: Exact frame rates of the Panoptic ``fpsType`` values (VGA 25 fps, HD 29.97 fps, Kinect 30 fps).
FPS_OF_TYPE = {"vga_25": Fraction(25), "hd_29_97": Fraction(30000, 1001), "kinect_30": Fraction(30)}

#: joints19 names, in file order.
JOINTS19 = ("neck", "nose", "body_center", "l_shoulder", "l_elbow", "l_wrist", "l_hip", "l_knee", "l_ankle",
            "r_shoulder", "r_elbow", "r_wrist", "r_hip", "r_knee", "r_ankle", "l_eye", "l_ear", "r_eye", "r_ear")
#: joints15 ("mpi15") names, in file order.
JOINTS15 = ("neck", "head_top") + JOINTS19[2:15]
LAYOUTS = {"joints19": JOINTS19, "joints15": JOINTS15}
#: The detector's extra joints a file may carry beside its layout (``extraJointNames``).
EXTRA_NAMES = ("upper_neck", "head_top", "l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel")

#: The largest joint coordinate (cm) or confidence taken: 10 km, far beyond any dome (larger values are no position:
#: a 20-digit integer would pass as finite and be exported as it is).
MAX_JOINT_VALUE = 1e6
JointValue = Annotated[float, Field(ge=-MAX_JOINT_VALUE, le=MAX_JOINT_VALUE, allow_inf_nan=False)]


class SceneBody(OpenSchema):
    """One person at one time: ``id`` (the same person keeps it over time) and 19 (or 15) joints ``[x, y, z, c]``."""

    id: NonNegInt
    joints19: Annotated[list[JointValue], Field(min_length=76, max_length=76)] | None = None
    joints15: Annotated[list[JointValue], Field(min_length=60, max_length=60)] | None = None
    inlierViews19: Annotated[list[NonNegInt], Field(min_length=19, max_length=19)] | None = Field(
        None, description="dome-calib's: the views behind each joint (read, not used)")
    extraJoints: Annotated[list[JointValue], Field(max_length=4 * len(EXTRA_NAMES))] | None = Field(
        None, description="dome-calib's: [x, y, z, c] of each of the file's extraJointNames")
    inlierViewsExtra: Annotated[list[NonNegInt], Field(max_length=len(EXTRA_NAMES))] | None = Field(
        None, description="dome-calib's: the views behind each extra joint (read, not used)")

    @model_validator(mode="after")
    def _one_layout(self) -> SceneBody:
        if (self.joints19 is None) == (self.joints15 is None):
            raise ValueError("expected joints19 or joints15 (one of them)")
        return self


class SceneFile(OpenSchema):
    """A body3DScene file: the universal time (ms), the frame rate's name and the bodies at that time."""

    version: Finite | str | None = None
    univTime: Finite = Field(description="universal time of the frame, ms")
    fpsType: str | None = Field(None, description='"vga_25", "hd_29_97", "kinect_30" or "custom"')
    fps: Annotated[str, Field(pattern=r"^[1-9]\d{0,9}(/[1-9]\d{0,9})?$")] | None = Field(
        None, description="dome-calib's: the exact frame rate of a custom fpsType, e.g. \"60\", \"30000/1001\"")
    bodyModel: str | None = Field(None, description="dome-calib's: the detector's model (BODY_25B, HALPE_26, ...)")
    labUp: Literal["+x", "-x", "+y", "-y", "+z", "-z"] | None = Field(
        None, description="dome-calib's: the up axis of the lab world the bundle was imported from")
    extraJointNames: Annotated[list[Literal[EXTRA_NAMES]], Field(max_length=len(EXTRA_NAMES))] | None = Field(
        None, description="dome-calib's: the detector's joints beside joints19, in the bodies' extraJoints order")
    bodies: list[SceneBody]

    @model_validator(mode="after")
    def _extra_lengths(self) -> SceneFile:
        names = self.extraJointNames or []
        if len(set(names)) != len(names):
            raise ValueError("extraJointNames: a name is given twice")
        for b, body in enumerate(self.bodies):
            if len(body.extraJoints or []) != 4 * len(names) and (body.extraJoints is not None or names):
                raise ValueError(f"bodies[{b}].extraJoints: {len(body.extraJoints or [])} numbers but extraJointNames "
                                 f"has {len(names)} joints ([x, y, z, c] each)")
        return self


# ---- writing ---------------------------------------------------------------------------------------------------
def scene_name(frame: int) -> str:
    """The file name of frame ``frame``: ``body3DScene_<frame:08d>.json``."""
    return f"body3DScene_{int(frame):08d}.json"


def fps_type_of(stream: str, explicit_times: bool = False) -> str:
    """Panoptic ``fpsType`` label for output times taken from ``stream`` (``custom`` for explicit times)."""
    return "custom" if explicit_times else FPS_TYPE.get(stream, "custom")


def joints_json(X_cm: np.ndarray, confidence: np.ndarray) -> list[float]:
    """(J, 3), (J,) -> ``[x, y, z, c] * J`` (4 decimals; ``0, 0, 0, -1`` where not reconstructed: not finite or
    c < 0)."""
    flat: list[float] = []
    for X, c in zip(X_cm, confidence):
        if np.all(np.isfinite(X)) and c >= 0:
            flat += [round(float(v), 4) for v in X] + [round(float(c), 4)]
        else:
            flat += [0.0, 0.0, 0.0, -1.0]
    return flat


def scene_json(time_ms: float, ids: np.ndarray, X_cm: np.ndarray, confidence: np.ndarray, n_inliers: np.ndarray,
               fps_type: str, *, body_model: str | None = None,
               extra: tuple[list[str], np.ndarray, np.ndarray, np.ndarray] | None = None,
               lab_up: str | None = None, fps: Fraction | None = None) -> dict:
    """One body3DScene object: the P bodies ``ids`` (P,), X_cm (P, J, 3), confidence (P, J), n_inliers (P, J), sorted
    by id (``joints<J>``, ``inlierViews<J>``); ``extra``: (names, X_cm (P, E, 3), confidence (P, E), n_inliers
    (P, E)) of the bodies in their order here; ``fps`` is written with a ``custom`` fpsType only."""
    J = np.shape(X_cm)[1] if len(ids) else 19
    out = []
    for p in np.argsort(ids, kind="stable"):
        body = {"id": int(ids[p]), f"joints{J}": joints_json(X_cm[p], confidence[p]),
                f"inlierViews{J}": [int(n) for n in n_inliers[p]]}
        if extra is not None:
            body["extraJoints"] = joints_json(extra[1][p], extra[2][p])
            body["inlierViewsExtra"] = [int(n) for n in extra[3][p]]
        out.append(body)
    scene = {"version": 0.7, "univTime": round(float(time_ms), 4), "fpsType": fps_type}
    if fps is not None and fps_type == "custom":
        scene["fps"] = str(fps)
    if body_model is not None:
        scene["bodyModel"] = body_model
    if lab_up is not None:
        scene["labUp"] = lab_up
    if extra is not None:
        scene["extraJointNames"] = list(extra[0])
    return scene | {"bodies": out}


def write_scene_folder(folder: str | Path, frames: Iterable[int], scenes: Iterable[dict],
                       also: Callable[[Path], None] | None = None) -> list[Path]:
    """Write ``scene_name(frame)`` of every (frame, scene object) into ``folder``, replacing it as a whole (staged
    beside it, then renamed: a reader sees the earlier run's files or this run's, never a mix); ``also(staging)``
    adds the caller's files to the staged folder before the rename."""
    folder = Path(folder)
    names = []
    with replace_folder(folder) as staging:
        for frame, scene in zip(frames, scenes):
            names.append(scene_name(frame))
            (staging / names[-1]).write_text(json.dumps(scene, allow_nan=False) + "\n", encoding="utf-8")
        if also is not None:
            also(staging)
    return [folder / n for n in names]


# ---- reading ---------------------------------------------------------------------------------------------------
def scene_files(folder: str | Path, error: type[Exception] = PeopleFileError) -> list[tuple[int, Path]]:
    """(frame, path) of every ``body3DScene_<frame>.json`` of ``folder``, in frame order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise error(f"{folder}: not a folder (expected a folder of body3DScene_<frame>.json files)")
    found = sorted((int(m.group(1)), p) for p in folder.iterdir() if (m := SCENE_FILE.fullmatch(p.name)))
    if not found:
        raise error(f"{folder}: no body3DScene_<frame>.json file")
    for frame, path in (found[0], found[-1]):
        if abs(frame) > MAX_SCENE_FRAME:
            raise error(f"{path}: frame number {frame}: more than the {len(str(MAX_SCENE_FRAME))} digits a frame "
                        "number has (OpenPose's 12)")
    for (a, pa), (b, pb) in zip(found, found[1:]):
        if a == b:
            raise error(f"{pb}: frame {b} is also {pa.name}: one file per frame (move one away)")
    return found


def read_scene_file(path: str | Path, error: type[Exception] = PeopleFileError) -> SceneFile:
    """One body3DScene file through :class:`SceneFile`."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror})") from None
    return parse_json(path, data, SceneFile, error=error)


def read_scene(path: str | Path) -> tuple[float, dict[int, np.ndarray]]:
    """One body3DScene file in the joints19 layout (as ``reconstruct`` writes) -> (univTime ms, {id: (19, 4)
    [x, y, z, c]})."""
    scene = read_scene_file(path)
    if any(b.joints19 is None for b in scene.bodies):
        raise PeopleFileError(f"{path}: bodies: expected joints19, got joints15")
    return float(scene.univTime), {b.id: np.asarray(b.joints19, dtype=float).reshape(19, 4) for b in scene.bodies}
