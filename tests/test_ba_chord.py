"""A stage's stopping step on the last accepted step's factor (issue 52: fewer factorisations of the reduced camera
system): :func:`dome_calib.ba.schur.chord_step` and ``BAOptions.chord_stop``.

A Levenberg-Marquardt stage ends with a step that only confirms convergence; it cost a new reduced system (the
points eliminated again, Y Y^T) and a factorisation. Its gain is first predicted, and taken when it meets the
stopping rule, with the new gradient on the kept system and factor of the step before. Off by default (it moves the
outlier verdicts: docs/benchmarks.md), so the tests turn it on.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from dome_calib.ba import BAOptions, ParamGroup, bundle_adjust
from dome_calib.ba.evaluate import residuals_and_jacobians
from dome_calib.ba.schur import build_reduced_system, build_structure, chord_step, linearize, solve_reduced
from dome_calib.panoptic_io import read_calibration
from dome_calib.synth.ba_problem import SyntheticOptions, make_problem

CALIBRATION = Path(__file__).parent / "data" / "panoptic" / "calibration_160906_band1.json"
NAMES = ["01_01", "03_05", "05_12", "07_20", "09_03", "00_03", "00_17", "50_02"]


@pytest.fixture(scope="module")
def problem():
    cams, _ = read_calibration(CALIBRATION)
    p = make_problem([cams[n] for n in NAMES], SyntheticOptions(n_points=300, target_observations=3000,
                                                                  noise_px=0.5, outlier_fraction=0.01, seed=5)).start
    p.fix(ParamGroup.K3, cameras=[NAMES[1]])
    return p


def _linearised(p, free):
    st = build_structure(p.camera_index, p.point_index, np.ones(p.n_observations, bool), free, p.n_points)
    res, Jc, Jp = residuals_and_jacobians(p.camera_params, p.points_cm, st.cam, st.pt, p.uv_px[st.obs])
    return st, linearize(st, res, Jc, Jp, np.ones(len(st.obs)), n_threads=2)


def test_the_chord_step_of_the_same_linearisation_is_the_step_itself(problem):
    """The kept elimination and factor with the same gradient: the step solve_reduced took (the right-hand side
    rebuilt from the kept y blocks, the factor's solver reused), a camera held and a term held included."""
    free = problem.free.copy()
    free[2] = False
    st, lin = _linearised(problem, free)
    system = build_reduced_system(st, lin, 1e-3, n_threads=2)
    step = solve_reduced(st, lin, system, 1e-3, n_threads=2, keep_factor=True)
    chord = chord_step(st, lin, system)
    assert chord is not None
    scale = np.abs(step.dc).max()
    np.testing.assert_allclose(chord.dc, step.dc, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(chord.dp, step.dp, rtol=0, atol=1e-9 * np.abs(step.dp).max())
    assert chord.predicted_decrease == pytest.approx(step.predicted_decrease, rel=1e-9)
    # a retry with more camera damping factorises again: the kept solver is then that factorisation's
    step2 = solve_reduced(st, lin, system, 1e-1, n_threads=2, keep_factor=True)
    np.testing.assert_allclose(chord_step(st, lin, system).dc, step2.dc, rtol=0, atol=1e-9 * np.abs(step2.dc).max())


def test_a_stage_ends_on_the_last_factor_with_fewer_factorisations(problem):
    """The same schedule with and without the chord stop: fewer factorisations of the reduced system, at least one
    stage ended on the kept factor, and the same solution within its noise (centres 1e-3 cm, focal 1e-5: far below
    their sigmas at 0.5 px)."""
    runs = {}
    for chord in (True, False):
        options = BAOptions(n_threads=2, compute_uncertainty=False, chord_stop=chord)
        runs[chord] = bundle_adjust(problem, options)
    count = {k: sum(e.factorisations for e in r.iterations) for k, r in runs.items()}
    assert any(e.factorisations == 0 for e in runs[True].iterations)
    assert all(e.factorisations >= 1 for e in runs[False].iterations)
    assert count[True] < count[False], count
    new, old = (runs[k].problem.camera_params for k in (True, False))
    assert np.abs(new[:, 3:6] - old[:, 3:6]).max() < 1e-3
    assert np.abs(new[:, 6:8] / old[:, 6:8] - 1.0).max() < 1e-5
    assert runs[True].cost <= runs[False].cost * (1 + 1e-6)


def test_no_chord_without_a_kept_factor(problem):
    """A solve that does not keep its system (solve_step's overwrite), or not its factor (chord_stop off: no factor
    held past its step), has no solver to reuse."""
    st, lin = _linearised(problem, problem.free)
    system = build_reduced_system(st, lin, 1e-3, n_threads=2)
    solve_reduced(st, lin, system, 1e-3, n_threads=2, keep=False, keep_factor=True)
    assert chord_step(st, lin, system) is None
    system = build_reduced_system(st, lin, 1e-3, n_threads=2)
    solve_reduced(st, lin, system, 1e-3, n_threads=2)
    assert chord_step(st, lin, system) is None
    assert dataclasses.replace(BAOptions(), chord_stop=False).chord_stop is False
