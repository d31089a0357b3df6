"""Files out of ``dome-calib reconstruct``: one Panoptic ``body3DScene_<k:08d>.json`` per time and ``cameras.json``.

body3DScene (as the Panoptic toolbox reads it, several bodies)::

    {"version": 0.7, "univTime": t_ms, "fpsType": "vga_25", "bodies": [{"id": 3, "joints19": [x, y, z, c] * 19,
     "inlierViews19": [n] * 19}, ...]}

x, y, z world cm (Panoptic frame); c = the probability, under the fitted body over time, that the joint lies within
5 cm of where it is put (:mod:`~dome_calib.recon.people.temporal`; with the body over time off, the mean detection
confidence of the supporting views); -1 (x = y = z = 0) for a joint not reconstructed; inlierViews19 = the number
of views supporting each joint.

Beside joints19 (which the Panoptic toolbox reads as it always has), the joints the detector gives and joints19
lacks (:data:`~dome_calib.recon.body_models.EXTRA_JOINTS`: the feet, BODY_25B's UpperNeck, the head top) ride in
fields of their own: ``"bodyModel"`` (the detector's model, e.g. ``"BODY_25B"``), ``"extraJointNames"``
(``["upper_neck", "head_top", "l_big_toe", ...]``) per file, and per body ``"extraJoints"`` (``[x, y, z, c] * E`` in
that order, the same conventions as joints19; triangulated per frame, :mod:`~dome_calib.recon.people.extras`) and
``"inlierViewsExtra"`` (``[n] * E``). ``"labUp"``: where the bundle was imported from a lab's tool, the up axis of
that lab's world (``"+z"``; our world is that world turned by ``PANOPTIC_FROM_UP[labUp]``, in cm), so the people
export can write the lab's own axes. ``"fps"`` (``"60"``, ``"30000/1001"``): with ``fpsType`` ``"custom"`` (a bundle
without sync tables), the exact rate the times were made with.

cameras.json: per camera the people it detected, the share of them used by a reconstructed body and the median
pixel distance between its used joints and the reconstructed joints; ``flagged`` lists the cameras that disagree
(median error above ``max(3 x the cameras' median, 5 px)`` or a share used below half the cameras' median, or, an
absolute criterion that holds when half the cameras are off, more than :data:`OUTVOTED_LIMIT` of its joint
detections outvoted by the body over time, or its detections lying to one side of the bodies: :data:`OFFSET_Z`,
:data:`OFFSET_FLOOR`): a camera that moved since calibration, a bad lens, or a camera that sees nobody well. With the
body over time, per camera also the share of its joint detections that the body outvoted (farther than 5 sigma of
that camera's measured pixel noise from where the body puts the joint: swaps, a neighbour's limb, a moved camera),
``median_offset_px`` (u, v: the median of its inlier detections minus the body's joints projected), over
``offset_joints``, ``offset_z`` (its length in standard errors), ``offset_floor_px`` and ``offset_flagged`` (flagged for
it); ``offset_corrected_px``: with ``--correct-offsets``, the shift its principal point was given before the run
(:mod:`~dome_calib.recon.people.camera_offsets`; null: none); ``notes``: one line per camera flagged for its offset
("camera 03: its joints lie 16 px to the left of where the others put them: moved or re-aimed?") and per camera
corrected.
"""
from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import model_validator

from dome_calib.body3d_scene import scene_json, scene_name, write_scene_folder
from dome_calib.bundle import Bundle
from dome_calib.errors import PeopleFileError
from dome_calib.ownership import claim_folder
from dome_calib.recon.people.agreement import CameraAgreement
from dome_calib.recon.people.detection_cache import KeptDetections
from dome_calib.recon.people.extras import ExtraJoints
from dome_calib.recon.people.run import PeopleSequence
from dome_calib.recon.people.windows import noise_px_of
from dome_calib.schema import (CameraName, Field, FieldError, FileSchema, NonNegFinite, NonNegInt, Unique, Vec,
                               read_json)

CAMERAS_FILE = "cameras.json"
PAGE_FILE = "index.html"
#: A camera is flagged, whatever the others do, when the body over time puts aside more than this share of its joint
#: detections (farther than 5 sigma of its pixel noise): the detector's own rate of such outliers, measured on real
#: OpenPose output (:class:`dome_calib.synth.detector_model.DetectorModel`: 4.8 % for wrists, 0.1-0.2 % for the
#: other joints), is a fifth of it at most. The relative criteria alone miss cameras when half of them are off (their
#: median is off too): two cameras 33 px and 22 px off with 86 % and 52 % of their joints outvoted were not flagged.
OUTVOTED_LIMIT = 0.25
#: ... once at least this many of its joint detections were judged.
MIN_JUDGED = 100  # the people page, written into the staging folder by write_people's ``also``
#: A camera is flagged, whatever the others do, when the median offset of its inlier detections from the body
#: (detection minus the body's joint projected, per image axis) is both significant and large: longer than
#: OFFSET_Z standard errors of a median of its n inliers (sqrt(pi / 2) sigma / sqrt(n), sigma the camera's measured
#: pixel noise per axis, :func:`~dome_calib.recon.people.windows.noise_px_of`) and than OFFSET_FLOOR of its image
#: diagonal. Noise alone averages out; a camera that moved or was re-aimed since calibration puts every person to
#: one side of where the others put them. The floor is twice the largest offset of a camera agreeing with the others
#: on the real Pose2Sim trial (3.7 px of a 1088 x 1920 image: the detector's per-joint biases, the calibration's
#: error); its disagreeing camera has 23 px. The detector's noise is correlated over ~150 ms
#: (``bench/detector_stats.py``), so with thousands of joints the significance is overstated and the floor decides.
OFFSET_Z = 5.0
OFFSET_FLOOR = 0.0035


def check_people_folder(folder: str | Path) -> Path:
    """The output folder ``-o`` may replace (:func:`dome_calib.ownership.claim_folder`: absent, empty or what
    dome-calib wrote, unchanged); anything else is refused before any work."""
    return claim_folder(folder)


def offset_words(offset_px: np.ndarray) -> str:
    """(2,) an offset in the image (u right, v down; px) -> "16 px to the left", "12 px up and to the right"."""
    u, v = float(offset_px[0]), float(offset_px[1])
    length = float(np.hypot(u, v))
    side = "" if abs(u) < 0.4 * length else ("to the right" if u > 0 else "to the left")
    height = "" if abs(v) < 0.4 * length else ("down" if v > 0 else "up")
    return f"{length:.0f} px " + " and ".join(w for w in (height, side) if w)


def camera_report(agreement: CameraAgreement, resolution_px: np.ndarray | None = None,
                  min_noise_px: float = 0.5, corrected_px: dict[str, np.ndarray] | None = None,
                  diverged: list[str] = (), undone: tuple[list[str], list[str]] = ((), ())) -> dict:
    """The per-camera agreement as a JSON object (see the module docstring). resolution_px (V, 2): each camera's
    image (width, height), in ``agreement.names`` order, for the offset criterion's floor (None: that criterion is
    not applied); min_noise_px: the body over time's floor of a camera's pixel noise; corrected_px: camera -> the
    shift (u, v px) its principal point was given before this run (``--correct-offsets``,
    :mod:`~dome_calib.recon.people.camera_offsets`): said in its row and its note; diverged: those of them whose
    correction stopped because its steps did not shrink (said in the note); undone: (the cameras whose further shift
    was undone, the cameras it made disagree; said in a note)."""
    corrected_px = corrected_px or {}
    offset, n_off = agreement.median_offset_px()
    noise = noise_px_of(agreement.noise, min_noise_px)
    # every verdict is made on the figures as written (rounded to their printed places): a flag never rests on a
    # float's last bits, which another machine's kernels change, and the file's flags agree with its numbers
    offset = np.round(offset, 2)
    off_len = np.hypot(offset[:, 0], offset[:, 1])
    off_z = np.round(off_len / (np.sqrt(np.pi / 2.0) * noise / np.sqrt(np.maximum(n_off, 1))), 1)
    floor = (np.round(OFFSET_FLOOR * np.hypot(*np.asarray(resolution_px, float).T), 2) if resolution_px is not None
             else np.full(len(agreement.names), np.inf))
    notes = []
    med = np.round(agreement.median_px(), 2)
    share = np.round(np.where(agreement.detected > 0, agreement.used / np.maximum(agreement.detected, 1), np.nan), 4)
    outvoted = np.round(agreement.outvoted / np.maximum(agreement.judged, 1), 4)
    all_med = float(np.nanmedian(med)) if np.isfinite(med).any() else float("nan")
    all_share = float(np.nanmedian(share)) if np.isfinite(share).any() else float("nan")
    flagged = []
    cams = {}
    for v, name in enumerate(agreement.names):
        bad_err = np.isfinite(med[v]) and med[v] > max(3.0 * all_med, 5.0)
        bad_share = np.isfinite(share[v]) and share[v] < 0.5 * all_share
        judged = int(agreement.judged[v])
        bad_outvoted = judged >= MIN_JUDGED and agreement.outvoted[v] > OUTVOTED_LIMIT * judged  # counts: exact
        bad_offset = bool(n_off[v] >= MIN_JUDGED and off_z[v] > OFFSET_Z and off_len[v] > floor[v])  # absolute
        if bad_offset:
            notes.append(f"camera {name}: its joints lie {offset_words(offset[v])} of where the others put them: "
                         f"moved or re-aimed?")
        if name in corrected_px:
            notes.append(f"camera {name}: its image shifted {offset_words(np.asarray(corrected_px[name]))} "
                         "(--correct-offsets: its principal point moved by its measured offset)"
                         + ("; the offset changed with the shift, so it is not a shift of the whole image: its "
                            "joints disagree each their own way" if name in diverged else ""))
        if bad_err or bad_share or bad_outvoted or bad_offset:
            flagged.append(name)
        cams[name] = {"detected": int(agreement.detected[v]), "used": int(agreement.used[v]),
                      "share_used": None if not np.isfinite(share[v]) else float(share[v]),
                      "median_reprojection_px": None if not np.isfinite(med[v]) else float(med[v]),
                      "joints_judged": judged,
                      "outvoted_share": float(outvoted[v]) if judged else None,
                      "median_offset_px": (None if not n_off[v] else [float(offset[v, 0]), float(offset[v, 1])]),
                      "offset_joints": int(n_off[v]),
                      "offset_z": float(off_z[v]) if n_off[v] else None,
                      "offset_flagged": bad_offset,
                      "offset_corrected_px": ([round(float(x), 2) for x in corrected_px[name]]
                                              if name in corrected_px else None),
                      "offset_floor_px": float(floor[v]) if np.isfinite(floor[v]) else None}
    if len(undone[0]):
        notes.append(f"--correct-offsets: shifting camera {', '.join(undone[0])} further made camera "
                     f"{', '.join(undone[1])} disagree with the others, so that shift was undone")
    return {"median_reprojection_px": None if not np.isfinite(all_med) else round(all_med, 2),
            "median_share_used": None if not np.isfinite(all_share) else round(all_share, 4),
            "flagged": flagged, "notes": notes, "cameras": cams}


@dataclass(frozen=True)
class StagedPeople:
    """What :func:`write_people` has staged, handed to the files written beside it (the people page) so that they
    are made from the run's own results, not read back: ``files`` ((frame, path) of each body3DScene file in the
    staging folder, in frame order), ``scenes()`` (the objects written, in that order, made again one at a time from
    the run's arrays: a long session's scenes are never all in memory), ``report`` (cameras.json's), ``bundle`` (the
    run's calibration, loaded once by the plan; None: the caller's), ``patches`` (the page's patch layer of a further
    stage, :func:`~dome_calib.recon.patches.page_layer.patch_layer`; None: none), ``detections`` (the detections the
    run kept, as it used them, :class:`~dome_calib.recon.people.detection_cache.KeptDetections`; None: none kept, the
    page reads the files)."""

    files: list[tuple[int, Path]]
    scenes: Callable[[], Iterator[dict]]
    report: dict
    bundle: Bundle | None = None
    patches: dict | None = None
    detections: KeptDetections | None = None


def people_scenes(seq: PeopleSequence, fps_type: str, *, body_model: str | None = None,
                  extras: ExtraJoints | None = None, lab_up: str | None = None,
                  fps: Fraction | None = None) -> Iterator[dict]:
    """The body3DScene object of every time of ``seq``, one at a time (:func:`dome_calib.body3d_scene.scene_json`;
    see the module docstring)."""
    for k, b in enumerate(seq.bodies):
        extra = None if extras is None else (extras.names, extras.X_cm[k], extras.confidence[k], extras.n_inliers[k])
        yield scene_json(seq.times_ms[k], b.ids, b.X_cm, b.confidence, b.n_inliers, fps_type, body_model=body_model,
                         extra=extra, lab_up=lab_up, fps=fps)


def write_people(folder: str | Path, seq: PeopleSequence, numbers: np.ndarray, fps_type: str,
                 also: Callable[[Path, StagedPeople], None] | None = None, *, body_model: str | None = None,
                 extras: ExtraJoints | None = None, lab_up: str | None = None, fps: Fraction | None = None,
                 report: dict | None = None, bundle: Bundle | None = None) -> list[Path]:
    """Write the body3DScene files and cameras.json (``report``, :func:`camera_report` of ``seq.cameras`` when not
    given) into ``folder``, replacing it as a whole (staged beside it, then renamed); ``also(staging, staged)``
    adds to the staged folder before the rename (the people page, from :class:`StagedPeople`); ``body_model`` and
    ``extras`` (the detector's joints beside joints19) go into every file (see the module docstring)."""
    def scenes() -> Iterator[dict]:
        return people_scenes(seq, fps_type, body_model=body_model, extras=extras, lab_up=lab_up, fps=fps)

    report = camera_report(seq.cameras) if report is None else report

    def beside(staging: Path) -> None:
        (staging / CAMERAS_FILE).write_text(camera_report_text(report), encoding="utf-8")
        if also is not None:
            staged = [(int(n), staging / scene_name(n)) for n in numbers]
            also(staging, StagedPeople(files=staged, scenes=scenes, report=report, bundle=bundle))

    return write_scene_folder(folder, numbers, scenes(), also=beside)


def camera_report_text(report: dict) -> str:
    """cameras.json's text: the report of :func:`camera_report` (read back by :func:`read_camera_report`)."""
    return json.dumps(report, indent=1, allow_nan=False) + "\n"


Share = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]


class CameraAgreementRow(FileSchema):
    """One camera of cameras.json (:func:`camera_report`): its tallies, and the figures of the body over time (null
    where it judged none of the camera's joints, or, ``offset_floor_px``, without the image size)."""

    detected: NonNegInt = Field(description="people the camera detected")
    used: NonNegInt = Field(description="of them, used by a reconstructed body")
    share_used: Share | None = Field(None, description="used / detected")
    median_reprojection_px: NonNegFinite | None = Field(
        None, description="median pixel distance between its used joints and the reconstructed joints")
    joints_judged: NonNegInt = Field(0, description="its joint detections the body over time judged")
    outvoted_share: Share | None = Field(None, description="share of them the body outvoted (farther than 5 sigma)")
    median_offset_px: Vec(2) | None = Field(
        None, description="[u, v] median of its inlier detections minus the body's joints projected")
    offset_joints: NonNegInt = Field(0, description="the detections that median is over")
    offset_z: NonNegFinite | None = Field(None, description="the offset's length in standard errors")
    offset_floor_px: NonNegFinite | None = Field(None, description="the offset a flag needs at least (a share of "
                                                 "the image diagonal)")
    offset_flagged: bool = Field(False, description="flagged for its offset (significant and above the floor)")
    offset_corrected_px: Vec(2) | None = Field(
        None, description="[u, v] the shift its principal point was given before the run (--correct-offsets)")


class CamerasFile(FileSchema):
    """cameras.json as ``reconstruct`` writes it (:func:`camera_report`, the module docstring), read back by
    ``dome-calib people-page`` for the page's camera table."""

    median_reprojection_px: NonNegFinite | None = Field(None, description="the cameras' median of theirs")
    median_share_used: Share | None = Field(None, description="the cameras' median share used")
    flagged: Unique(CameraName) = Field([], description="the cameras that disagree (each one of cameras)")
    notes: list[str] = Field([], description="one line per camera flagged for its offset")
    cameras: dict[CameraName, CameraAgreementRow] = Field(description="camera name -> its row")

    @model_validator(mode="after")
    def _flagged_are_cameras(self) -> CamerasFile:
        for k, name in enumerate(self.flagged):
            if name not in self.cameras:
                raise FieldError(("flagged", k), f"camera {name} is not one of cameras")
        return self


def read_camera_report(folder: str | Path) -> dict | None:
    """``folder``'s cameras.json through :class:`CamerasFile`, as the report :func:`camera_report` gave (None when
    the folder has none: a body3DScene folder another tool wrote); PeopleFileError of one line naming the file and
    the field when it does not read."""
    path = Path(folder) / CAMERAS_FILE
    if not path.is_file():
        return None
    return read_json(path, CamerasFile, error=PeopleFileError).model_dump(mode="json")
