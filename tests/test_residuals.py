"""One residual convention, observed - projected (dome_calib.residuals), from the solver to residuals.npz."""
from __future__ import annotations

import dataclasses

import numpy as np

from dome_calib.layout import nominal_dome
from dome_calib.pipeline.stages import ba_options, observation_residuals, run_ba_stage
from dome_calib.residuals import Residuals, observed_minus_projected

from .test_calibrate import _problem

TOL_PX = 1e-6


def test_the_convention_is_observed_minus_projected():
    assert np.array_equal(observed_minus_projected([[12.0, 5.0]], [[10.0, 6.0]]), [[2.0, -1.0]])


def test_a_feature_seen_right_of_its_projection_has_a_positive_x_residual():
    problem = _problem(nominal_dome("tiny", seed=0), noise_px=0.0)
    problem.uv_px[0, 0] += 4.0
    res = observation_residuals(problem)
    assert abs(res[0, 0] - 4.0) < TOL_PX and abs(res[0, 1]) < TOL_PX


def test_the_ba_stage_reports_observed_minus_projected_not_the_solver_sign(tmp_path):
    """The solver works with projected - observed; what the BA stage hands on (and saves) is the opposite."""
    problem = _problem(nominal_dome("tiny", seed=0), seed=1)
    outcome = run_ba_stage(problem, options=dataclasses.replace(ba_options(), compute_uncertainty=False))
    independent = observation_residuals(outcome.problem)[outcome.inlier]  # projected again from the solution
    assert np.abs(outcome.residuals.residual_px - independent).max() < TOL_PX
    outcome.residuals.save(tmp_path / "residuals.npz")
    back = Residuals.load(tmp_path / "residuals.npz")
    assert np.abs(back.residual_px - independent).max() < 1e-4  # px: stored as float32
