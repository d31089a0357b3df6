"""A folder of Panoptic ``body3DScene_<frame>.json`` files (as ``dome-calib reconstruct`` writes them and as the
Panoptic dataset ships them) as one track per person: :func:`read_people`.

The file itself (its names, its schema, its reader) is :mod:`dome_calib.body3d_scene`'s; here its scenes become
:class:`People`: the folder's frames and times, its layout (``joints19``, or ``joints15``, the older "mpi15"
layout), the detector's extra joints carried after the layout's, ``labUp``, and the frame rate (exact, from
``fpsType`` or ``fps``; else measured on the times). :func:`people_of_scenes` does the same for scenes already in
memory (``reconstruct``'s people page, built from the files it has just written). Every problem is one line naming
the file and the field (:class:`~dome_calib.skeletons.errors.PeopleFileError`).
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path

import numpy as np

from dome_calib.body3d_scene import FPS_OF_TYPE, LAYOUTS, SceneFile, read_scene_file, scene_files
from dome_calib.schema import show
from dome_calib.skeletons.errors import PeopleFileError

logger = logging.getLogger(__name__)

#: The frame rates a capture can have (the rate every writer puts in its file): 1 frame in 1000 s .. 100,000 fps.
FPS_RANGE = (Fraction(1, 1000), Fraction(100_000))
#: The most values a dense file (C3D: every point at every frame number of the span; BVH: every joint of a person)
#: may hold: 2^25 (a 512 MB C3D; 36 people over 33 min at 25 fps). Frame numbers far apart in one folder would
#: otherwise ask for an array of every frame between them.
MAX_DENSE_VALUES = 2**25


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


def rate_problem(fps: Fraction) -> str | None:
    """Why ``fps`` cannot be written as a capture's frame rate (None: it can): :data:`FPS_RANGE`."""
    low, high = FPS_RANGE
    if not low <= fps <= high:
        return f"a frame rate is between {float(low):g} and {float(high):g} fps"
    return None


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

    def scenes():
        for k, (_, path) in enumerate(files):
            scene = read_scene_file(path)
            if progress is not None:
                progress(k + 1, len(files))
            yield scene

    people = people_of_scenes(folder, files, scenes())
    logger.info("read %d files, %d people (%s)", len(files), len(people.tracks), people.layout)
    return people


def people_of_scenes(folder: str | Path, files: Sequence[tuple[int, Path]], scenes: Iterable[SceneFile | dict]
                     ) -> People:
    """The scenes of a folder's ``files`` ((frame, path) in frame order; scene objects or the dicts written) ->
    :class:`People`, with the same checks as :func:`read_people` (the messages name the files)."""
    frames = np.array([f for f, _ in files], dtype=np.int64)
    times = np.empty(len(files))
    layout = fps_type = None
    stated: str | None = None
    extra: tuple[str, ...] | None = None
    body_model: str | None = None
    lab_up: str | None = None
    per_id: dict[int, tuple[list[int], list[list[float]]]] = {}
    for k, ((_, path), scene) in enumerate(zip(files, scenes)):
        if isinstance(scene, dict):
            scene = SceneFile.model_validate(scene)
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
    return People(folder=Path(folder), frames=frames, times_ms=times, fps_type=fps_type,
                  fps=frame_rate(fps_type, frames, times, Fraction(stated) if stated else None), layout=layout,
                  tracks=tracks, extra=extra, body_model=body_model, lab_up=lab_up)
