"""C3D (the binary motion-capture file of Vicon, Qualisys, Visual3D, OpenSim's C3D reader): one file for the whole
capture, written through ezc3d.

- Points: every person's joints, labelled ``P<id>:<marker>`` (Vicon's ``subject:marker`` labels; the ``SUBJECTS``
  group lists the people, ``NAMES`` ``P<id>`` and ``LABEL_PREFIXES`` ``P<id>:``, as Vicon Nexus writes it);
  ``DESCRIPTIONS``: "person <id> <joint>" (up to 255 points: past them ezc3d writes them empty, split as the
  labels into ``LABELS2``, ``DESCRIPTIONS2``, ...). Markers: Pose2Sim's names (as the TRC files).
- Size: at most 4,095 points (215 people of 19 joints), what the ``c3d`` package reads (ezc3d reads more), 255
  people and 255 parameter blocks. More are refused before work, naming the limit (``--ids`` splits them); what
  was written is checked (a cut file on a full disk is an error, not exit 0).
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

import math
import os
import struct
from pathlib import Path

import ezc3d
import numpy as np
from ezc3d import ezc3d as ezc3d_core

from dome_calib.skeletons.errors import PeopleFileError
from dome_calib.skeletons.joints import marker_names, z_up_axes
from dome_calib.skeletons.scenes import People

MM_PER_CM = 10.0
#: C3D's limits: a parameter holds at most 255 items (its count is one byte: LABELS, LABELS2, ... as Vicon and
#: ezc3d split them; SUBJECTS:NAMES, which is not split: 255 people), the parameter section at most 255 blocks of
#: 512 bytes (its block count is one byte); and the ``c3d`` package (Pose2Sim's C3D library) reads a frame of 4,096
#: points or more as a 16-bit size (measured: 4,095 read, 4,096 "buffer is smaller than requested size").
MAX_ITEMS = 255
MAX_PARAMETER_BLOCKS = 255
MAX_POINTS = 4095
_BLOCK = 512


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


def _descriptions(descriptions: list[str]) -> list[str]:
    """POINT:DESCRIPTIONS as ezc3d can write them: up to 255 points, ours; past 255 points, its own empty ones
    (split as LABELS, LABELS2, ...: ezc3d writes a DESCRIPTIONS of more than 255 items with its one-byte count
    overflowed, which every reader then refuses, and drops any shorter one)."""
    return descriptions if len(descriptions) <= MAX_ITEMS else [""] * len(descriptions)


def _chunks(values: list[str]) -> list[list[str]]:
    return [values[i:i + MAX_ITEMS] for i in range(0, max(len(values), 1), MAX_ITEMS)]


def parameter_blocks(labels: list[str], descriptions: list[str], names: list[str]) -> int:
    """The 512-byte blocks of the parameter section ezc3d writes for these points and subjects (its defaults take
    2; each string parameter is its name, a 10-byte header and max length x count bytes; per chunk of 255 points
    LABELS<k>, DESCRIPTIONS<k> and UNITS<k>)."""
    total = 0
    for name, values in (("LABELS", labels), ("DESCRIPTIONS", descriptions), ("UNITS", ["mm"] * len(labels))):
        for k, chunk in enumerate(_chunks(values)):
            total += 10 + len(name) + 2 + max((len(v) for v in chunk), default=0) * len(chunk)
    for values in (names, [f"{n}:" for n in names]):
        total += 24 + max((len(v) for v in values), default=1) * max(len(values), 1)
    return 2 + math.ceil(total / _BLOCK)


def check_c3d_size(people: People) -> None:
    """Refuse before work what C3D readers do not take, naming the limit (:data:`MAX_POINTS`: 215 people of 19
    joints; :data:`MAX_ITEMS` people; a parameter section past :data:`MAX_PARAMETER_BLOCKS` blocks)."""
    J, P = len(people.joints), len(people.tracks)
    markers = marker_names(people)
    labels = [f"P{pid}:{m}" for pid in people.tracks for m in markers]
    descriptions = _descriptions([f"person {pid} {j}" for pid in people.tracks for j in people.joints])
    blocks = parameter_blocks(labels, descriptions, [f"P{pid}" for pid in people.tracks])
    limit = (f"{J * P} points, more than the {MAX_POINTS} C3D readers take" if J * P > MAX_POINTS else
             f"more than the {MAX_ITEMS} subjects a C3D parameter holds" if P > MAX_ITEMS else
             f"{blocks} parameter blocks for their labels, more than the {MAX_PARAMETER_BLOCKS} a C3D file declares"
             if blocks > MAX_PARAMETER_BLOCKS else None)
    if limit is not None:
        raise PeopleFileError(f"{people.folder}: {P} people x {J} joints: {limit}; export at most "
                              f"{min(MAX_POINTS // J, MAX_ITEMS)} people per file (--ids) or use --to trc")


def check_written(path: Path, n_points: int, n_frames: int) -> None:
    """What ezc3d wrote is whole (it does not report a failed write: a full disk left a cut file, exit 0): the
    header's point count, the parameter section within 255 blocks, the file as long as its data. PeopleFileError
    naming the file otherwise (the staging folder is then removed: nothing half-written is left)."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        header = f.read(_BLOCK)
    if len(header) < _BLOCK or header[1] != 0x50:
        raise PeopleFileError(f"{path}: written cut ({size} bytes, no C3D header): is the disk full?")
    points = struct.unpack("<H", header[2:4])[0]
    data_start = struct.unpack("<H", header[16:18])[0]
    need = (data_start - 1) * _BLOCK + n_frames * n_points * 16  # float data: x, y, z, residual per point
    if data_start - header[0] > MAX_PARAMETER_BLOCKS:
        raise PeopleFileError(f"{path}: written with {data_start - header[0]} parameter blocks: not a C3D readers "
                              f"take (at most {MAX_PARAMETER_BLOCKS}); export fewer people (--ids)")
    if points != n_points or data_start <= header[0] or size < need:
        raise PeopleFileError(f"{path}: written cut ({size} bytes, {max(need, size + 1)} expected): is the disk "
                              "full? Free space or write elsewhere")


def write_c3d(path: Path, people: People, joint_ok: dict[int, np.ndarray]) -> Path:
    """Write the capture's C3D file at ``path`` and check what was written (:func:`check_written`); returns it."""
    check_c3d_size(people)
    labels, descriptions, points = c3d_points(people, joint_ok)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [float(people.fps)]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = _descriptions(descriptions)
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
    with open(path, "rb+") as f:  # on the disk before it is judged
        os.fsync(f.fileno())
    check_written(path, points.shape[1], points.shape[2])
    return path
