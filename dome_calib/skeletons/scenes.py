"""Read a folder of Panoptic ``body3DScene_<frame>.json`` files (as ``dome-calib reconstruct`` writes them and as
the Panoptic dataset ships them) into one track per person.

A file (the Panoptic toolbox's README, "Skeleton Output Format"; mmpose's
``body3d_mview_direct_panoptic_dataset.py`` reads the same fields)::

    {"version": 0.7, "univTime": 53541.542, "fpsType": "hd_29_97",
     "bodies": [{"id": 0, "joints19": [x, y, z, c] * 19}, ...]}

``joints15`` ([x, y, z, c] * 15, the older "mpi15" layout) in place of ``joints19``; dome-calib's ``bodyModel``,
``extraJointNames`` and per body ``extraJoints`` (the detector's joints beside joints19, the same conventions:
:mod:`dome_calib.recon.people.scene_io`; carried after the layout's joints), ``labUp`` (the imported lab world's up
axis) and ``fps`` (the exact rate of a custom ``fpsType``) are read too; ``inlierViews19`` (ours: the views behind
each joint) is read and not used; other fields are none of our business and are ignored. x, y, z:
world cm (the Panoptic frame, y down); c: the joint's confidence, ``-1`` where it was not reconstructed (and ``0,
0, 0`` then). The frame is the number in the file name. Every problem is one line naming the file and the field
(:class:`~dome_calib.skeletons.errors.PeopleFileError`).
"""
from __future__ import annotations

import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from dome_calib.schema import Finite, NonNegInt, OpenSchema, parse_json, show
from dome_calib.skeletons.errors import PeopleFileError
from dome_calib.skeletons.joints import EXTRA_NAMES, LAYOUTS

logger = logging.getLogger(__name__)

SCENE_FILE = re.compile(r"body3DScene_(-?\d+)\.json")
#: The largest frame number of a file name (12 digits, as OpenPose numbers its files).
MAX_SCENE_FRAME = 10**12 - 1
#: The frame rates a capture can have (the rate every writer puts in its file): 1 frame in 1000 s .. 100,000 fps.
FPS_RANGE = (Fraction(1, 1000), Fraction(100_000))
#: The most values a dense file (C3D: every point at every frame number of the span; BVH: every joint of a person)
#: may hold: 2^25 (a 512 MB C3D; 36 people over 33 min at 25 fps). Frame numbers far apart in one folder would
#: otherwise ask for an array of every frame between them.
MAX_DENSE_VALUES = 2**25
#: Exact frame rates of the Panoptic ``fpsType`` values (VGA 25 fps, HD 29.97 fps, Kinect 30 fps).
FPS_OF_TYPE = {"vga_25": Fraction(25), "hd_29_97": Fraction(30000, 1001), "kinect_30": Fraction(30)}


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


@dataclass(frozen=True)
class Track:
    """One person over time: ``rows`` (K,) indices into the folder's frames where the person is in a file,
    ``X_cm`` (K, J, 3) world cm (NaN where a joint was not reconstructed), ``confidence`` (K, J) (-1 there)."""

    id: int
    rows: np.ndarray
    X_cm: np.ndarray
    confidence: np.ndarray


@dataclass(frozen=True)
class People:
    """A body3DScene folder: ``frames`` (T,) the file numbers in order, ``times_ms`` (T,) their universal times,
    ``layout`` "joints19" or "joints15" (``joints``: its names), ``fps``: the frame rate (exact; from ``fpsType``
    or the times; None: the times give none a capture can have), ``tracks``: one per id, in id order."""

    folder: Path
    frames: np.ndarray
    times_ms: np.ndarray
    fps_type: str
    fps: Fraction | None
    layout: str
    tracks: dict[int, Track]
    extra: tuple[str, ...] = ()
    body_model: str | None = None
    lab_up: str | None = None

    @property
    def joints(self) -> tuple[str, ...]:
        """The layout's joints, then the detector's extra joints (``extraJointNames``): the tracks' columns."""
        return LAYOUTS[self.layout] + self.extra


def scene_files(folder: str | Path) -> list[tuple[int, Path]]:
    """(frame, path) of every ``body3DScene_<frame>.json`` of ``folder``, in frame order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise PeopleFileError(f"{folder}: not a folder (expected a folder of body3DScene_<frame>.json files)")
    found = sorted((int(m.group(1)), p) for p in folder.iterdir() if (m := SCENE_FILE.fullmatch(p.name)))
    if not found:
        raise PeopleFileError(f"{folder}: no body3DScene_<frame>.json file")
    for frame, path in (found[0], found[-1]):
        if abs(frame) > MAX_SCENE_FRAME:
            raise PeopleFileError(f"{path}: frame number {frame}: more than the {len(str(MAX_SCENE_FRAME))} digits a "
                                  "frame number has (OpenPose's 12)")
    for (a, pa), (b, pb) in zip(found, found[1:]):
        if a == b:
            raise PeopleFileError(f"{pb}: frame {b} is also {pa.name}: one file per frame (move one away)")
    return found


def rate_problem(fps: Fraction) -> str | None:
    """Why ``fps`` cannot be written as a capture's frame rate (None: it can): :data:`FPS_RANGE`."""
    low, high = FPS_RANGE
    if not low <= fps <= high:
        return f"a frame rate is between {float(low):g} and {float(high):g} fps"
    return None


def _read_scene(path: Path) -> SceneFile:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PeopleFileError(f"{path}: cannot be read ({exc.strerror})") from None
    return parse_json(path, data, SceneFile, error=PeopleFileError)


def read_scene(path: str | Path) -> tuple[float, dict[int, np.ndarray]]:
    """One body3DScene file in the joints19 layout (as ``reconstruct`` writes) -> (univTime ms, {id: (19, 4)
    [x, y, z, c]})."""
    scene = _read_scene(Path(path))
    if any(b.joints19 is None for b in scene.bodies):
        raise PeopleFileError(f"{path}: bodies: expected joints19, got joints15")
    return float(scene.univTime), {b.id: np.asarray(b.joints19, dtype=float).reshape(19, 4) for b in scene.bodies}


def with_rate(people: People, fps: Fraction | None = None, remedy: str = "give --fps") -> People:
    """``people`` at the rate ``fps`` (default: the folder's), checked (:func:`rate_problem`); PeopleFileError of
    one line ending in ``remedy`` when the folder's times give none and none is given."""
    fps = fps or people.fps
    if fps is None:
        span_s = (people.times_ms[-1] - people.times_ms[0]) / 1000.0
        raise PeopleFileError(f"{people.folder}: univTime: frames {people.frames[0]}..{people.frames[-1]} over "
                              f"{span_s:.6g} s give no frame rate a capture has ({rate_problem(Fraction(0))}): "
                              f"{remedy}")
    problem = rate_problem(fps)
    if problem is not None:
        raise PeopleFileError(f"fps {float(fps):.6g}: {problem}")
    return replace(people, fps=fps)


def frame_rate(fps_type: str, frames: np.ndarray, times_ms: np.ndarray,
               stated: Fraction | None = None) -> Fraction | None:
    """The frame rate: the ``fpsType``'s (exact), else the files' own ``fps`` (exact), else frames per second of the
    times (rounded to 1/1000 fps); None when the times give none a capture can have (:func:`rate_problem`: frames
    hours apart, a rate rounded to 0)."""
    if fps_type in FPS_OF_TYPE:
        return FPS_OF_TYPE[fps_type]
    if stated is not None:
        return stated if rate_problem(stated) is None else None
    if len(frames) < 2 or times_ms[-1] <= times_ms[0]:
        return Fraction(30)
    fps = Fraction(round(1000.0 * 1000.0 * float(frames[-1] - frames[0]) / (times_ms[-1] - times_ms[0]))) / 1000
    return fps if rate_problem(fps) is None else None


def read_people(folder: str | Path, *, progress: Callable[[int, int], None] | None = None) -> People:
    """Every body3DScene file of ``folder`` -> :class:`People`; PeopleFileError naming the file and field of the
    first problem (a bad field, two bodies with one id, two layouts or two ``fpsType`` in one folder, times that go
    back)."""
    files = scene_files(folder)
    frames = np.array([f for f, _ in files], dtype=np.int64)
    times = np.empty(len(files))
    layout = fps_type = None
    stated: str | None = None
    extra: tuple[str, ...] | None = None
    body_model: str | None = None
    lab_up: str | None = None
    per_id: dict[int, tuple[list[int], list[list[float]]]] = {}
    for k, (_, path) in enumerate(files):
        scene = _read_scene(path)
        times[k] = scene.univTime
        kind = scene.fpsType or "custom"
        if fps_type is None:
            fps_type = kind
        elif kind != fps_type:
            raise PeopleFileError(f"{path}: fpsType: {show(kind)}, but earlier files have {show(fps_type)}")
        if k == 0:
            stated = scene.fps
        elif scene.fps != stated:
            raise PeopleFileError(f"{path}: fps: {show(scene.fps)}, but earlier files have {show(stated)}")
        names = tuple(scene.extraJointNames or ())
        if extra is None:
            extra, body_model, lab_up = names, scene.bodyModel, scene.labUp
        elif names != extra:
            raise PeopleFileError(f"{path}: extraJointNames: {show(list(names))}, but earlier files have "
                                  f"{show(list(extra))}")
        if k and times[k] <= times[k - 1]:
            raise PeopleFileError(f"{path}: univTime: {times[k]:g} ms is not after the previous file's "
                                  f"{times[k - 1]:g} ms ({files[k - 1][1].name})")
        seen: set[int] = set()
        for b, body in enumerate(scene.bodies):
            this = "joints19" if body.joints19 is not None else "joints15"
            if layout is None:
                layout = this
            elif this != layout:
                raise PeopleFileError(f"{path}: bodies[{b}].{this}: earlier files have {layout}; one folder holds "
                                      "one layout")
            if body.id in seen:
                raise PeopleFileError(f"{path}: bodies[{b}].id: {body.id} is given to two bodies")
            seen.add(body.id)
            rows, values = per_id.setdefault(body.id, ([], []))
            rows.append(k)
            values.append((body.joints19 if body.joints19 is not None else body.joints15) + (body.extraJoints or []))
        if progress is not None:
            progress(k + 1, len(files))
    layout = layout or "joints19"
    extra = extra or ()
    n_joints = len(LAYOUTS[layout]) + len(extra)
    tracks = {}
    for pid in sorted(per_id):
        rows, values = per_id[pid]
        a = np.asarray(values, dtype=float).reshape(len(rows), n_joints, 4)
        missing = a[..., 3] < 0
        tracks[pid] = Track(id=pid, rows=np.asarray(rows, dtype=np.int64),
                            X_cm=np.where(missing[..., None], np.nan, a[..., :3]),
                            confidence=np.where(missing, -1.0, a[..., 3]))
    fps_type = fps_type or "custom"
    logger.info("read %d files, %d people (%s)", len(files), len(tracks), layout)
    return People(folder=Path(folder), frames=frames, times_ms=times, fps_type=fps_type,
                  fps=frame_rate(fps_type, frames, times, Fraction(stated) if stated else None), layout=layout,
                  tracks=tracks, extra=extra, body_model=body_model, lab_up=lab_up)
