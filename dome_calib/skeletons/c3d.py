"""C3D (the binary motion-capture file of Vicon, Qualisys, Visual3D, OpenSim's C3D reader): one file for the whole
capture, written through ezc3d.

- Points: every person's joints, labelled ``P<id>:<marker>`` (Vicon's ``subject:marker`` labels; the ``SUBJECTS``
  group lists the people, ``NAMES`` ``P<id>`` and ``LABEL_PREFIXES`` ``P<id>:``, as Vicon Nexus writes it);
  ``DESCRIPTIONS``: "person <id> <joint>". Markers: Pose2Sim's names (as the TRC files).
- Units: millimetres (``POINT:UNITS`` ``mm``, the C3D custom), floats (``POINT:SCALE`` < 0).
- Axes: z up, as C3D viewers show a capture: ``(x, z, -y) x 10`` of our Panoptic cm; ``POINT:X_SCREEN`` ``+X``,
  ``POINT:Y_SCREEN`` ``+Z`` say so to viewers that read them (Mokka, Vicon).
- Frames: one per frame number from the folder's first to its last file at ``POINT:RATE`` (the capture's rate);
  the header's first frame is the first file's frame number (C3D counts from 1: ``body3DScene_00000000`` is C3D
  frame 1); frame numbers beyond the header's 16 bits (65,535: 44 min at 25 fps) go into ``TRIAL:ACTUAL_START_FIELD``
  and ``ACTUAL_END_FIELD`` (two 16-bit words, low first), as Vicon writes long trials.
- Missing: a joint not reconstructed, a frame without a file, a person not there: NaN to ezc3d, which writes the
  C3D missing value (residual -1; ezc3d and the ``c3d`` package read it back as missing). Present points have
  residual 0 ("no residual computed").
"""
from __future__ import annotations

from pathlib import Path

import ezc3d
import numpy as np
from ezc3d import ezc3d as ezc3d_core

from dome_calib.skeletons.joints import marker_names, z_up_axes
from dome_calib.skeletons.scenes import People

MM_PER_CM = 10.0


def c3d_points(people: People, joint_ok: dict[int, np.ndarray]) -> tuple[list[str], list[str], np.ndarray]:
    """(labels, descriptions, (4, N, F) homogeneous points in mm, NaN where missing) of every person in id order;
    F frames from the folder's first frame number to its last."""
    first = int(people.frames[0])
    n_frames = int(people.frames[-1]) - first + 1
    J = len(people.joints)
    labels, descriptions = [], []
    points = np.full((4, J * len(people.tracks), n_frames), np.nan)
    points[3] = 1.0
    markers = marker_names(people)
    for p, (pid, track) in enumerate(people.tracks.items()):
        labels += [f"P{pid}:{m}" for m in markers]
        descriptions += [f"person {pid} {j}" for j in people.joints]
        X = np.where(joint_ok[pid][..., None], track.X_cm @ z_up_axes(people).T * MM_PER_CM, np.nan)
        columns = people.frames[track.rows] - first
        points[:3, p * J:(p + 1) * J, columns] = X.transpose(2, 1, 0)
    return labels, descriptions, points


def _int_parameter(c3d: ezc3d.c3d, group: str, name: str, values: list[int]) -> None:
    """An integer parameter (ezc3d's ``add_parameter`` stores every number list as floats)."""
    c3d.add_parameter(group, name, values)
    c3d["parameters"][group][name]["type"] = ezc3d_core.INT
    c3d["parameters"][group][name]["value"] = np.asarray(values, dtype=int)


def _words(frame: int) -> list[int]:
    """A frame number as C3D's two 16-bit words (low, high), stored as signed integers."""
    low, high = frame & 0xFFFF, (frame >> 16) & 0xFFFF
    return [w - 65536 if w > 32767 else w for w in (low, high)]


def write_c3d(path: Path, people: People, joint_ok: dict[int, np.ndarray]) -> Path:
    """Write the capture's C3D file at ``path``; returns it."""
    labels, descriptions, points = c3d_points(people, joint_ok)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [float(people.fps)]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = descriptions
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d.add_parameter("POINT", "X_SCREEN", ["+X"])
    c3d.add_parameter("POINT", "Y_SCREEN", ["+Z"])
    names = [f"P{pid}" for pid in people.tracks]
    _int_parameter(c3d, "SUBJECTS", "USED", [len(names)])
    c3d.add_parameter("SUBJECTS", "NAMES", names or [""])
    c3d.add_parameter("SUBJECTS", "LABEL_PREFIXES", [f"{n}:" for n in names] or [""])
    first, last = int(people.frames[0]), int(people.frames[-1])
    if 0 <= first and last + 1 <= 65535:
        c3d["header"]["points"]["first_frame"] = first
    else:  # the header's 16 bits cannot hold it: TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD (two 16-bit words)
        _int_parameter(c3d, "TRIAL", "ACTUAL_START_FIELD", _words(first + 1))
        _int_parameter(c3d, "TRIAL", "ACTUAL_END_FIELD", _words(last + 1))
    c3d["data"]["points"] = points
    c3d.write(str(path))
    return path
