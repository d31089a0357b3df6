"""Pose2Sim's own pipeline (pose2sim 0.10.49: filtering, markerAugmentation, kinematics with OpenSim's inverse
kinematics) run on a TRC, and the joint angles of two runs compared: used by ``tests/test_pose2sim_pipeline.py``
(slow) and ``bench/pose2sim_pipeline.py``.

Pose2Sim's steps find their files by folder (``<project>/pose-3d/*.trc`` in, ``<project>/kinematics/*.mot`` out)
and read their settings from one config dict: its demo's ``Config.toml`` (shipped in the wheel) with the figures
and C3D copies turned off. Its triangulation (the reference) runs on the same detections and calibration
(``<project>/pose``, ``<project>/calibration``).
"""
from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

import numpy as np

#: OpenSim coordinates compared (degrees), as the issue asks: pelvis, hips, knees, ankles.
ANGLES = ("pelvis_tilt", "pelvis_list", "pelvis_rotation", "hip_flexion_r", "hip_adduction_r", "hip_rotation_r",
          "knee_angle_r", "ankle_angle_r", "hip_flexion_l", "hip_adduction_l", "hip_rotation_l", "knee_angle_l",
          "ankle_angle_l")


def pose2sim_config(project: Path, *, model: str, fps: int, multi_person: bool = False) -> dict:
    """Pose2Sim's demo config (``Demo_SinglePerson/Config.toml`` of the wheel) for ``project``: the detector's
    model, the frame rate, no figures, no C3D copies."""
    import rtoml
    from Pose2Sim import Pose2Sim as p2s_main

    base = rtoml.load(Path(p2s_main.__file__).parent / "Demo_SinglePerson" / "Config.toml")
    return p2s_main.recursive_update(base, {
        "project": {"project_dir": str(project), "frame_rate": fps, "multi_person": multi_person},
        "pose": {"pose_model": model},
        "triangulation": {"make_c3d": False},
        "filtering": {"display_figures": False, "save_filt_plots": False, "make_c3d": False},
        "markerAugmentation": {"make_c3d": False}})


@contextlib.contextmanager
def _stdout_to(path: Path):
    """The process's standard output (file descriptor 1: OpenSim's C++ logger writes every IK frame there) into
    ``path`` for the block, so a bench's JSON lines stay its own."""
    import sys

    sys.stdout.flush()
    saved = os.dup(1)
    with open(path, "ab") as log:
        os.dup2(log.fileno(), 1)
        try:
            yield
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)


@contextlib.contextmanager
def _agg_backend():
    """Pose2Sim's modules pick a matplotlib backend on import; no window is ever opened here."""
    import matplotlib

    before = matplotlib.get_backend()
    matplotlib.use("Agg")
    try:
        yield
    finally:
        matplotlib.use(before)


def run_pose2sim_steps(project: Path, config: dict) -> list[Path]:
    """Pose2Sim's filtering, marker augmentation and kinematics on ``project/pose-3d/*.trc`` -> the ``.mot`` files
    of joint angles it wrote (one per person)."""
    with _agg_backend(), _stdout_to(project / "pose2sim_stdout.log"):
        from Pose2Sim.filtering import filter_all
        from Pose2Sim.kinematics import kinematics_all
        from Pose2Sim.markerAugmentation import augment_markers_all

        for step in (filter_all, augment_markers_all, kinematics_all):
            step(config)
    return sorted((project / "kinematics").glob("*.mot"))


def pose2sim_reference(project: Path, pose: Path, calibration: Path, *, model: str, fps: int) -> list[Path]:
    """Pose2Sim's own run: its person association and triangulation of the detections ``pose`` (camera folders of
    OpenPose JSON) with its calibration file, then :func:`run_pose2sim_steps` -> its ``.mot`` files."""
    (project / "calibration").mkdir(parents=True, exist_ok=True)
    shutil.copy(calibration, project / "calibration" / calibration.name)
    shutil.copytree(pose, project / "pose")
    config = pose2sim_config(project, model=model, fps=fps)
    import rtoml

    (project / "Config.toml").write_text(rtoml.dumps(config))  # its association looks for a Config.toml beside it
    with _agg_backend(), _stdout_to(project / "pose2sim_stdout.log"):
        from Pose2Sim.personAssociation import associate_all
        from Pose2Sim.triangulation import triangulate_all

        cwd = Path.cwd()
        try:
            os.chdir(project)
            associate_all(config)
            triangulate_all(config)
        finally:
            os.chdir(cwd)
    return run_pose2sim_steps(project, config)


def pose2sim_on_trcs(project: Path, trcs: list[Path], *, model: str, fps: int) -> list[Path]:
    """Pose2Sim's filtering, augmentation and kinematics on our TRC files (copied to ``project/pose-3d``)."""
    (project / "pose-3d").mkdir(parents=True, exist_ok=True)
    for trc in trcs:
        shutil.copy(trc, project / "pose-3d" / trc.name)
    config = pose2sim_config(project, model=model, fps=fps, multi_person=len(trcs) > 1)
    return run_pose2sim_steps(project, config)


def read_mot(path: Path) -> dict[str, np.ndarray]:
    """An OpenSim ``.mot`` (header to ``endheader``, then a table) -> column -> values."""
    import pandas as pd

    lines = path.read_text().splitlines()
    start = next(k for k, line in enumerate(lines) if line.strip() == "endheader") + 1
    table = pd.read_csv(path, sep=r"\s+", skiprows=start)
    return {c: table[c].to_numpy(dtype=float) for c in table.columns}


def angle_rms_deg(ours: Path, theirs: Path) -> dict[str, float]:
    """RMS difference (degrees) per compared angle between two runs' ``.mot`` files, over the times both hold."""
    a, b = read_mot(ours), read_mot(theirs)
    common, ia, ib = np.intersect1d(np.round(a["time"], 4), np.round(b["time"], 4), return_indices=True)
    assert len(common) > 10, "the two runs share too few times"
    return {c: float(np.sqrt(np.mean((a[c][ia] - b[c][ib]) ** 2))) for c in ANGLES}
