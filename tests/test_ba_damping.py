"""A rejected Levenberg-Marquardt step shortened along its direction (dome_calib.ba.solver._shortened)."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from dome_calib.ba import BAOptions, bundle_adjust
from dome_calib.ba.solver import LONGEST, SHORTEST, _shortened
from dome_calib.panoptic_io import read_calibration
from dome_calib.synth.ba_problem import SyntheticOptions, make_problem

CALIBRATION = Path(__file__).parent / "data/panoptic/calibration_160906_band1.json"
#: the 12 cameras of tests/test_ba.py
NAMES = ["01_01", "03_05", "05_12", "07_20", "09_03", "11_08", "13_15", "16_02", "18_10", "00_03", "00_17", "50_02"]


def _step(g: np.ndarray, h: np.ndarray, lam: float):
    """The damped step of the quadratic model 0.5 d^T H d + g^T d (H diagonal ``h``, damping lam x h) as the solver
    reports it: d and the model's decrease for it, 0.5 (-g.d + d^T Lambda d)."""
    d = -g / (h + lam * h)
    predicted = 0.5 * (-(g @ d) + lam * np.sum(h * d * d))
    lin = SimpleNamespace(g_c=g[None, :2], g_p=g[None, 2:])
    step = SimpleNamespace(dc=d[None, :2], dp=d[None, 2:], predicted_decrease=predicted)
    return d, lin, step


def test_alpha_is_the_minimiser_of_a_quadratic_cost_along_the_step_and_the_decrease_the_models():
    g, h, lam = np.array([1.0, -2.0, 0.5, 3.0]), np.array([2.0, 1.0, 4.0, 3.0]), 1e-3
    d, lin, step = _step(g, h, lam)
    # the true cost is quadratic along d with 3x the model's curvature: the full step gains about nothing
    curv_true = 3.0 * np.sum(h * d * d)
    phi = lambda a: 10.0 + a * (g @ d) + 0.5 * a * a * curv_true  # noqa: E731
    alpha, predicted = _shortened(step, lin, phi(0.0), phi(1.0))
    assert alpha == pytest.approx(-(g @ d) / curv_true)
    assert SHORTEST <= alpha <= LONGEST
    # the model's own decrease at alpha d (its curvature, not the true one)
    assert predicted == pytest.approx(-alpha * (g @ d) - 0.5 * alpha ** 2 * np.sum(h * d * d))
    assert phi(0.0) - phi(alpha) > 0.5 * predicted  # and the shortened step gains what the rule asks


def test_alpha_is_clamped_and_no_descent_direction_or_an_infinite_end_gives_none():
    g, h = np.array([1.0, -2.0, 0.5, 3.0]), np.array([2.0, 1.0, 4.0, 3.0])
    d, lin, step = _step(g, h, 0.0)
    assert _shortened(step, lin, 10.0, 1e12)[0] == SHORTEST  # a wall: the shortest fraction
    assert _shortened(step, lin, 10.0, 10.0 + 1e-9)[0] == pytest.approx(LONGEST)  # hardly any rise: half the step
    assert _shortened(step, lin, 10.0, 9.9)[0] == LONGEST  # a slight fall (rejected by rho): half the step
    assert _shortened(step, lin, 10.0, np.inf) is None
    ascent = SimpleNamespace(dc=-step.dc, dp=-step.dp, predicted_decrease=step.predicted_decrease)
    assert _shortened(ascent, lin, 10.0, 11.0) is None


def test_nielsens_rule_in_the_robust_stage_builds_fewer_systems_for_the_same_minimum():
    """After a ten-fold fall of the damping the robust stage's next step is rejected, each rejection a new reduced
    system; Nielsen's own rule (at most three-fold) rejects fewer and reaches the same minimum."""
    cams, _ = read_calibration(CALIBRATION)
    sp = make_problem([cams[n] for n in NAMES], SyntheticOptions(n_points=2500, target_observations=20000,
                                                                 noise_px=0.5, outlier_fraction=0.03, seed=3))
    runs = {rule: bundle_adjust(sp.start, BAOptions(n_threads=1, compute_uncertainty=False, robust_stage_nielsen=rule))
            for rule in (False, True)}
    systems = {rule: sum(it.reduced_systems for it in r.iterations) for rule, r in runs.items()}
    assert systems[True] < systems[False]
    assert runs[True].cost == pytest.approx(runs[False].cost, rel=1e-4)
    assert np.sum(runs[True].inlier != runs[False].inlier) <= 1e-3 * len(runs[False].inlier)
