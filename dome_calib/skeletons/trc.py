"""TRC (OpenSim's marker-trajectory text, what Pose2Sim writes and its kinematics reads): one file per person.

Layout, as OpenSim's ``TRCFileAdapter`` reads it (tab-separated; five header lines, then one row per frame)::

    PathFileType  4  (X/Y/Z)  person3.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    25.000000  25.000000  120  19  m  25.000000  1  120
    Frame#  Time  Neck  <tab>  <tab>  Nose ...
            X1  Y1  Z1  X2  Y2  Z2 ...
    1  0.000000  0.123456  1.543210  -0.200000 ...

- Markers: Pose2Sim's names (:data:`dome_calib.skeletons.joints.MARKER`), in the file's joint order.
- Units: metres (``m``), 6 decimals (1 um), as Pose2Sim writes them.
- Axes: y up (OpenSim's): ``(x, -y, -z) / 100`` of our Panoptic cm.
- Rows: every body3DScene file from the person's first to last appearance; ``Frame#`` = the file's frame + 1
  (TRC counts from 1, as Pose2Sim writes frames 0-99 as 1-100); ``Time`` = seconds since the folder's first file
  (its ``univTime``), so every person's file shares one clock.
- Missing: a joint not reconstructed, or a frame where the person is absent, is three empty fields (OpenSim reads
  them as NaN, pandas in Pose2Sim's ``read_trc`` too). Every field ends with a tab, as OpenSim's own writer
  (``TRCFileAdapter::extendWrite``) does: its reader drops the last empty field of a line, so a row whose last
  marker is missing must still end with one.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dome_calib.arrays import per_row
from dome_calib.skeletons.joints import MARKER, Y_UP_FROM_PANOPTIC
from dome_calib.skeletons.scenes import People, Track

M_PER_CM = 0.01


def trc_text(people: People, track: Track, name: str, joint_ok: np.ndarray) -> str:
    """The TRC file of one person (``joint_ok`` (K, J): joints to write; the others are written as missing)."""
    markers = [MARKER[j] for j in people.joints]
    first, last = int(track.rows[0]), int(track.rows[-1])
    rows = np.arange(first, last + 1)
    X = np.full((len(rows), len(markers), 3), np.nan)
    keep = track.rows - first
    X[keep] = np.where(joint_ok[..., None], track.X_cm @ Y_UP_FROM_PANOPTIC.T * M_PER_CM, np.nan)
    rate = f"{float(people.fps):.6f}"
    start = int(people.frames[first]) + 1
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{name}",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             f"{rate}\t{rate}\t{len(rows)}\t{len(markers)}\tm\t{rate}\t{start}\t{len(rows)}",
             "Frame#\tTime\t" + "".join(f"{m}\t\t\t" for m in markers).rstrip("\t"),
             "\t\t" + "".join(f"X{k}\tY{k}\tZ{k}\t" for k in range(1, len(markers) + 1))]
    times_s = (people.times_ms[rows] - people.times_ms[0]) / 1000.0
    text = np.char.mod("%.6f", per_row(X))
    text[np.isnan(per_row(X))] = ""
    for r, frame in enumerate(people.frames[rows]):
        lines.append(f"{int(frame) + 1}\t{times_s[r]:.6f}\t" + "".join(v + "\t" for v in text[r]))
    return "\n".join(lines) + "\n"


def write_trc(folder: Path, people: People, track: Track, joint_ok: np.ndarray) -> Path:
    """Write ``person<id>.trc`` into ``folder`` (a staging folder); returns its path."""
    path = folder / f"person{track.id}.trc"
    path.write_text(trc_text(people, track, path.name, joint_ok), encoding="utf-8")
    return path
