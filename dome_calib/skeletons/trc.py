"""TRC (OpenSim's marker-trajectory text, what Pose2Sim writes and its kinematics reads): one file per person.

Layout, as Pose2Sim 0.10.49's own writer lays it out (``Pose2Sim/triangulation.py``, ``make_trc``; tab-separated;
five header lines, then one row per frame)::

    PathFileType  4  (X/Y/Z)  trial_P3_0-99.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    60  60  100  19  m  60  0  100
    Frame#  Time  Neck  <tab>  <tab>  Nose  <tab>  <tab> ... REar  <tab>  <tab>  <tab>
            X1  Y1  Z1  X2  Y2  Z2 ...  Z19  <tab>
    0  0.000000  0.123456  1.543210  -0.200000 ...

- Line 4 (marker names) ends with three tabs after the last name, as Pose2Sim's and OpenSim's writers end it
  (OpenSim 4.6's ``TRCFileAdapter.write`` writes lines 4 and 5 byte for byte as here):
  Pose2Sim's marker augmentation (``common.add_neck_hip_data``) inserts its ``Hip`` marker by replacing that
  ``"\\t\\t\\t\\n"``; without it the insertion fails in silence and the augmentation dies on a column count.
- Name: ``<trial>_P<id>_<first>-<last>.trc`` (:func:`trc_name`), Pose2Sim's multi-person name: its filtering
  replaces the last ``_`` field with the frame range, so every person keeps a file of their own.
- Markers: Pose2Sim's names for the detector's joints (:func:`dome_calib.skeletons.joints.marker_names`).
- Units: metres (``m``), 6 decimals (1 um). Rate: ``DataRate`` = ``CameraRate`` = ``OrigDataRate`` = the rate
  (an integer as an integer, else 6 decimals).
- Axes: y up (OpenSim's), :func:`dome_calib.skeletons.joints.y_up_axes` (the lab's own world turned as Pose2Sim
  turns it when the bundle came from the lab's tool).
- Rows: every body3DScene file from the person's first to last appearance; ``Frame#`` = the file's frame number
  (as Pose2Sim 0.10 writes frames 0-99 as 0-99); ``Time`` = (frame - the folder's first frame) / rate, so the
  steps are 1 / ``DataRate`` and every person's file shares one clock; ``OrigDataStartFrame`` = the first frame.
- Gaps: a marker missing for at most ``--fill-gaps`` frames (default 20, Pose2Sim's
  ``interp_if_gap_smaller_than``) is filled as Pose2Sim's triangulation fills its own TRC (:func:`fill_gaps`):
  Pose2Sim's marker augmentation is a sequence model, and one empty toe field gave empty augmented lower-body markers
  for 62 of 99 frames, so its inverse kinematics froze the knees (77 deg, exit 0).
- Missing: a joint not reconstructed, or a frame where the person is absent, is three empty fields (OpenSim reads
  them as NaN, pandas in Pose2Sim's ``read_trc`` too). Every field ends with a tab, as OpenSim's own writer
  (``TRCFileAdapter::extendWrite``) does: its reader drops the last empty field of a line, so a row whose last
  marker is missing must still end with one.
"""
from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

from dome_calib.arrays import fixed_text
from dome_calib.skeletons.joints import marker_names, y_up_axes
from dome_calib.skeletons.scenes import People, Track

M_PER_CM = 0.01


def rate_text(fps: Fraction) -> str:
    """``60`` for 60 fps, ``29.970030`` for 30000/1001."""
    return str(fps.numerator) if fps.denominator == 1 else f"{float(fps):.6f}"


def trc_name(trial: str, pid: int, first_frame: int, last_frame: int) -> str:
    """Pose2Sim's multi-person TRC name: ``<trial>_P<id>_<first>-<last>.trc``."""
    return f"{trial}_P{pid}_{first_frame}-{last_frame}.trc"


def fill_gaps(X: np.ndarray, max_frames: int) -> np.ndarray:
    """(F, M, 3) rows with NaN where missing -> the gaps of at most ``max_frames`` rows filled: inside, linearly
    between the values on either side; at the start or end, the nearest value held (Pose2Sim's triangulation fills its
    TRC the same way: ``interp_if_gap_smaller_than``, ``fill_large_gaps_with = 'last_value'``). Longer gaps and
    markers never seen stay missing."""
    out = X.copy()
    rows = np.arange(len(X))
    for m in range(X.shape[1]):
        ok = np.isfinite(X[:, m]).all(-1)
        if ok.all() or not ok.any() or max_frames <= 0:
            continue
        # each missing row's run of missing rows: its length decides
        edges = np.flatnonzero(np.diff(np.concatenate([[1], ok.astype(np.int8), [1]])))
        for start, stop in zip(edges[::2], edges[1::2]):
            if stop - start > max_frames:
                continue
            for c in range(3):
                out[start:stop, m, c] = np.interp(rows[start:stop], rows[ok], X[ok, m, c])  # holds at the ends
    return out


def trc_text(people: People, track: Track, name: str, joint_ok: np.ndarray, *, fill_frames: int = 0) -> str:
    """The TRC file of one person (``joint_ok`` (K, J): joints to write; the others are written as missing; gaps of
    at most ``fill_frames`` frames filled, :func:`fill_gaps`)."""
    markers = marker_names(people)
    first, last = int(track.rows[0]), int(track.rows[-1])
    rows = np.arange(first, last + 1)
    X = np.full((len(rows), len(markers), 3), np.nan)
    keep = track.rows - first
    X[keep] = np.where(joint_ok[..., None], track.X_cm @ y_up_axes(people).T * M_PER_CM, np.nan)
    X = fill_gaps(X, fill_frames)
    rate = rate_text(people.fps)
    start = int(people.frames[first])
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{name}",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             f"{rate}\t{rate}\t{len(rows)}\t{len(markers)}\tm\t{rate}\t{start}\t{len(rows)}",
             "Frame#\tTime\t" + "".join(f"{m}\t\t\t" for m in markers),
             "\t\t" + "".join(f"X{k}\tY{k}\tZ{k}\t" for k in range(1, len(markers) + 1))]
    frames = people.frames[rows]
    times_s = (frames - people.frames[0]) / float(people.fps)
    text = fixed_text(X, 6, missing="")
    for r, frame in enumerate(frames):
        lines.append(f"{int(frame)}\t{times_s[r]:.6f}\t" + "".join(v + "\t" for v in text[r]))
    return "\n".join(lines) + "\n"


def write_trc(folder: Path, people: People, track: Track, joint_ok: np.ndarray, *, trial: str,
              fill_frames: int = 0) -> Path:
    """Write ``<trial>_P<id>_<first>-<last>.trc`` into ``folder`` (a staging folder); returns its path."""
    frames = people.frames[track.rows]
    path = folder / trc_name(trial, track.id, int(frames[0]), int(frames[-1]))
    path.write_text(trc_text(people, track, path.name, joint_ok, fill_frames=fill_frames), encoding="utf-8")
    return path
