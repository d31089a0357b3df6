"""Issue 15, the gate between SfM and the bundle adjustment: it follows the prior's size (a prior in millimetres
keeps its cameras), still drops a camera SfM put km away, and when every camera is dropped it says why in one
line instead of crashing in the solver (``argmax of an empty sequence``)."""
from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from dome_calib.align import sim3_apply, transform_cameras
from dome_calib.ba.problem import BAProblem
from dome_calib.camera import project
from dome_calib.errors import CaptureError
from dome_calib.pipeline.stages import center_gate, prune_problem
from dome_calib.layout import nominal_dome

MM_FROM_CM = pycolmap.Sim3d(10.0, pycolmap.Rotation3d(np.eye(3)), [0.0, 0.0, 0.0])


def _problem_and_prior(frame: pycolmap.Sim3d):
    """Tent points seen by the tiny nominal dome (exact pixels), cameras and points expressed in ``frame``; the
    prior is the same cameras in the same frame (SfM output is aligned to the prior's frame and unit)."""
    truth = nominal_dome("tiny", seed=0)
    X = np.random.default_rng(0).uniform([-60, -180, -60], [60, -20, 60], size=(300, 3))
    names = sorted(truth.cameras)
    s = truth.stacked(names)
    proj = project(X, s["R"], s["t_cm"], s["intr"], s["dist"])
    cam_idx, pt_idx = np.nonzero(proj.in_image(s["resolution"]) & proj.in_lens)
    cams = transform_cameras(truth.cameras, frame)
    problem = BAProblem.from_cameras(cams, {"scene_01": sim3_apply(frame, X)}, camera_index=cam_idx,
                                     point_index=pt_idx, uv_px=proj.uv_px[cam_idx, pt_idx], camera_names=names)
    return problem, cams


def test_gate_follows_a_prior_in_millimetres():
    problem, prior_mm = _problem_and_prior(MM_FROM_CM)
    radii = [np.linalg.norm(c.center_cm) for c in prior_mm.values()]
    assert min(radii) > 1000.0  # every camera beyond the old fixed 10 m (1000 units)
    pruned, dropped = prune_problem(problem, prior=prior_mm)
    assert dropped == {} and pruned.n_cameras == problem.n_cameras


def test_gate_still_drops_a_camera_km_away():
    problem, prior_mm = _problem_and_prior(MM_FROM_CM)
    name = problem.camera_names[-1]  # whichever camera the preset holds
    far = problem.camera_position(name)
    problem.camera_params[far, 3:6] += [0.0, 0.0, 5e7]  # 50 km in mm
    pruned, dropped = prune_problem(problem, prior=prior_mm)
    assert sorted(dropped) == [name] and "outside the gate of radius" in dropped[name]
    assert pruned.n_cameras == problem.n_cameras - 1


def test_every_camera_dropped_is_one_line_saying_why():
    problem, _ = _problem_and_prior(MM_FROM_CM)
    with pytest.raises(CaptureError) as err:
        prune_problem(problem, prior=None)  # the design's gate (10 m, cm) against a mm reconstruction
    message = str(err.value)
    assert "\n" not in message
    assert f"all {problem.n_cameras} cameras left out of the bundle adjustment" in message
    assert "outside the gate of radius 1000 cm around the dome centre" in message and "prior" in message


def test_gate_of_the_real_dome_is_about_the_old_ten_metres(real_cameras):
    centre, radius_cm, _ = center_gate(real_cameras)
    assert 1090.0 < radius_cm < 1135.0  # 4 x the median distance (278.1 cm) of the 520 cameras from where they look
    assert np.linalg.norm(centre - [2.4, -133.5, 1.0]) < 1.0  # cm: 1.3 m above the floor centre
    hd = {n: c for n, c in real_cameras.items() if n.startswith("00_")}  # the 31 HD cameras alone: the same gate
    assert abs(center_gate(hd)[1] - radius_cm) < 0.05 * radius_cm
    panel = {n: c for n, c in real_cameras.items() if n.startswith("05_")}  # one panel: axes too close to parallel
    assert center_gate(panel)[1] == 1000.0  # to place the dome centre: the design's gate
