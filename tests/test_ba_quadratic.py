"""The quadratic model's factor through the eliminated camera cores (dome_calib.ba.quadratic._PartitionedFactor):
the lens model's walk factorises only the selected lens terms' block of the cores' Schur complement, and gets the
same steps and inverse blocks as a factorisation of the whole selected block."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import dome_calib.ba.quadratic as quadratic
from dome_calib.ba import BAOptions, bundle_adjust
from dome_calib.ba.quadratic import QuadraticModel
from dome_calib.panoptic_io import read_calibration
from dome_calib.synth.ba_problem import SyntheticOptions, make_problem

CALIBRATION = Path(__file__).parent / "data" / "panoptic" / "calibration_160906_band1.json"


@pytest.fixture(scope="module")
def model() -> QuadraticModel:
    cams, _ = read_calibration(CALIBRATION)
    names = sorted(n for n in cams if not n.startswith("50_"))[::24]
    problem = make_problem([cams[n] for n in names], SyntheticOptions(
        n_points=1500, target_observations=15000, noise_px=0.3, outlier_fraction=0.0, seed=3)).start
    problem.free[:, 8:] = False  # the lens model's first solve: pose and focal only
    result = bundle_adjust(problem, BAOptions(n_threads=2, compute_uncertainty=False, outlier_rounds=1))
    return QuadraticModel.at(result, np.ones_like(problem.free))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_walk_steps_through_the_cores_equal_the_whole_blocks(model, seed, monkeypatch):
    rng = np.random.default_rng(seed)
    free = np.ones_like(model.index, dtype=bool)
    free[:, 8:] = rng.random((len(free), 7)) < 0.6
    columns = {i: [c for c in range(10, 15) if free[i, c]] for i in range(0, len(free), 2)}
    columns = {i: js for i, js in columns.items() if js}
    damping = (0.0, 1e-6, 1e-4)[seed]
    model._factor = None
    step, blocks = model.step(free, columns, damping=damping)
    assert isinstance(model._factor[1], quadratic._PartitionedFactor)
    monkeypatch.setattr(QuadraticModel, "_partitioned", lambda self, idx, damping: None)
    model._factor = None
    whole_step, whole_blocks = model.step(free, columns, damping=damping)
    assert np.abs(step - whole_step).max() <= 1e-9 * np.abs(whole_step).max()
    for i, block in whole_blocks.items():
        assert np.abs(blocks[i] - block).max() <= 1e-9 * np.abs(block).max()


def test_a_block_that_asks_for_a_core_column_takes_the_whole_factor(model):
    free = np.ones_like(model.index, dtype=bool)
    model._factor = None
    model.step(free)  # through the cores, kept for the same free set
    assert isinstance(model._factor[1], quadratic._PartitionedFactor)
    _, blocks = model.step(free, {0: [6, 7]})  # fx, fy: a core's columns (the same free set)
    assert not isinstance(model._factor[1], quadratic._PartitionedFactor)
    whole = np.linalg.inv(model.S)  # every candidate free: S itself
    k = model.index[0, [6, 7]]
    assert np.abs(blocks[0] - whole[np.ix_(k, k)]).max() <= 1e-8 * np.abs(whole[np.ix_(k, k)]).max()
