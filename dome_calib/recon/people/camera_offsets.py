"""A camera's offset taken out: ``reconstruct --correct-offsets``.

cameras.json measures where each camera puts people against where the others put them: the median offset of its
inlier detections from the bodies' joints projected, per image axis (:func:`~dome_calib.recon.people.scene_io.
camera_report`), and flags a camera whose offset is both significant and large (``offset_flagged``). The model of
that offset is a shift of the whole image: a camera turned since calibration by a small angle (knocked, re-aimed)
moves every point of its image alike (1 degree is ~f / 57 px, 24 px for a 70-degree 1920-px camera; a point near
the edge of the image moves at most a few percent more), and so does a detector that puts every joint of a view to
one side. A shift of the image is exactly a shift of the principal point (u = fx x_d + cx whatever the distortion),
so the correction is the camera's principal point moved by its measured offset, and the run made again with it.

What it does not model, measured (docs/reconstruct.md, "Where a camera puts people"): a camera moved (translated)
shifts near and far people differently; a camera whose joints disagree each in its own direction and from frame to
frame keeps what the shift does not explain (the real Pose2Sim trial's camera 03, ``bench/camera_bias_models.py``: a
shift takes its held-out median distance from the three others' joints from 37 to 20 px, a rotation, a full pose, the
focal length or k1 no further than 19 px), and the shifted camera then weighs in with it.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

from typing import TypeVar

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.recon.people.scene_io import OFFSET_Z

#: A corrected camera is shifted again only by at least this much (px): four bins of the offset's histogram.
MIN_STEP_PX = 1.0


@dataclass
class OffsetCorrection:
    """The shifts of ``--correct-offsets``, round by round (:meth:`step` on each run's cameras.json report).

    - Only the cameras flagged for their offset in the first run are ever shifted.
    - A camera is shifted again while its offset is significant (``offset_z`` above
      :data:`~dome_calib.recon.people.scene_io.OFFSET_Z`) and at least :data:`MIN_STEP_PX`, and only while the steps
      shrink along one direction: the offset is measured against bodies the camera itself pulls, from its inliers
      (within 5 sigma of its noise), so it comes out short of the camera's own and the correction is made again (on
      the rig, a camera turned 1 degree: 24.4 px, measured 13.4, then 4.4 more, ...). A step that grows or turns
      back means the shift is not the camera's error (its inliers change with the shift); that camera keeps its
      shift and is named in ``diverged``.
    - A round after which a camera that was not flagged for its offset is (the shifted camera now pulls the bodies
      away from the others) is undone, and the correction ends there (``undone``: those cameras): on the rig with two
      of five cameras turned, the first run flagged an agreeing camera that the two pulled, and shifting it flagged
      another (MPJPE 3.54 -> 3.89 cm, kept at 3.54). This rule does not catch every harm: on the real Pose2Sim
      trial the rounds converge (camera 03 shifted 30.3 / 18.0 px, nobody flagged after) and still move every joint
      angle away from Pose2Sim's run (pelvis rotation 3.2 -> 18.5 deg RMS): why the option is off by default.

    shifts_px: camera -> the total shift (u, v px) of the run to keep; diverged, undone: see above; undone_shifted:
    the cameras whose shift that undone round changed."""

    shifts_px: dict[str, np.ndarray] = field(default_factory=dict)
    diverged: list[str] = field(default_factory=list)
    undone: list[str] = field(default_factory=list)
    undone_shifted: list[str] = field(default_factory=list)
    _last: dict[str, np.ndarray] = field(default_factory=dict)
    _before: dict[str, np.ndarray] = field(default_factory=dict)
    _cameras: set[str] | None = None

    def step(self, report: dict, *, shift: bool = True) -> str:
        """Read the report of the run made with ``shifts_px`` -> "again" (shifts changed: run again; not with
        ``shift`` False, the last round), "done" (keep this run) or "undo" (keep the run before it: ``shifts_px``
        is back to its shifts)."""
        first = self._cameras is None
        flagged = {n for n, row in report["cameras"].items() if row.get("offset_flagged")}
        if first:
            self._cameras = flagged
        elif flagged - self._cameras:
            self.undone = sorted(flagged - self._cameras)
            self.undone_shifted = sorted(n for n in self.shifts_px
                                         if n not in self._before or np.any(self.shifts_px[n] != self._before[n]))
            self.shifts_px = self._before
            return "undo"
        if not shift:
            return "done"
        before = dict(self.shifts_px)
        changed = False
        for name in sorted(self._cameras - set(self.diverged)):
            row = report["cameras"][name]
            if row.get("median_offset_px") is None:
                continue
            m = np.asarray(row["median_offset_px"], float)
            if not first:
                if (row.get("offset_z") or 0.0) <= OFFSET_Z or float(np.hypot(*m)) < MIN_STEP_PX:
                    continue
                last = self._last[name]
                if m[0] * last[0] + m[1] * last[1] <= 0.0 or float(np.hypot(*m)) >= float(np.hypot(*last)):
                    self.diverged.append(name)
                    continue
            self.shifts_px[name] = self.shifts_px.get(name, np.zeros(2)) + m
            self._last[name] = m
            changed = True
        if changed:
            self._before = before
        return "again" if changed else "done"


def shifted_bundle(bundle: Bundle, shifts_px: dict[str, np.ndarray]) -> Bundle:
    """``bundle`` with each camera of ``shifts_px`` projecting ``shifts_px[name]`` (u, v px) further: its principal
    point moved by it (the image shifted alike everywhere, whatever the distortion)."""
    cams = dict(bundle.cameras)
    for name, (du, dv) in shifts_px.items():
        K = cams[name].K.copy()
        K[0, 2] += float(du)
        K[1, 2] += float(dv)
        cams[name] = dataclasses.replace(cams[name], K=K)
    return dataclasses.replace(bundle, cameras=cams)


Run = TypeVar("Run")


def with_offsets_corrected(run: Callable[[dict[str, np.ndarray]], Run], report_of: Callable[[Run], dict],
                           rounds: int) -> tuple[Run, OffsetCorrection]:
    """``run(shifts)`` (the people made with those cameras' principal points shifted; ``{}``: the bundle as given)
    corrected up to ``rounds`` times (0: once, as given) by :class:`OffsetCorrection` on ``report_of(result)`` (its
    cameras.json report) -> the run kept and the correction (its ``shifts_px`` are that run's)."""
    correction = OffsetCorrection()
    result = previous = run({})
    for k in range(rounds + 1 if rounds else 0):
        verdict = correction.step(report_of(result), shift=k < rounds)
        if verdict != "again":
            return (previous if verdict == "undo" else result), correction
        previous, result = result, run(dict(correction.shifts_px))
    return result, correction
