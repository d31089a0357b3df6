"""The sparse reduced camera system (dome_calib.ba.sparse): the dense system's values, its steps, its solves.

A ring of 52 real cameras where each point is seen only by cameras within 2 places of one camera: most camera
pairs share no point, as on the full dome. The sparse path is forced below its size threshold.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import dome_calib.ba.sparse as sparse
from dome_calib.ba import BAOptions, bundle_adjust
from dome_calib.ba.evaluate import residuals_and_jacobians
from dome_calib.ba.gauge import inner_constraint_basis
from dome_calib.ba.schur import build_reduced_system, build_structure, free_columns, linearize, reduced_system, \
    solve_reduced
from dome_calib.panoptic_io import read_calibration
from dome_calib.synth.ba_problem import SyntheticOptions, make_problem

pytest.importorskip("sksparse", reason="the optional extra `sparse` (scikit-sparse) is not installed")
CALIBRATION = Path(__file__).parent / "data/panoptic/calibration_160906_band1.json"


@pytest.fixture(scope="module")
def ring():
    cams, _ = read_calibration(CALIBRATION)
    names = sorted(cams)[::10]
    p = make_problem([cams[n] for n in names], SyntheticOptions(n_points=800, target_observations=6000, noise_px=0.3,
                                                                outlier_fraction=0.01, seed=2)).start
    C = p.n_cameras
    home = p.point_index % C
    near = np.minimum((p.camera_index - home) % C, (home - p.camera_index) % C) <= 2
    return dataclasses.replace(p, camera_index=p.camera_index[near], point_index=p.point_index[near],
                               uv_px=p.uv_px[near], free=p.free.copy())


@pytest.fixture
def forced(monkeypatch):
    monkeypatch.setattr(sparse, "SPARSE_MIN_UNKNOWNS", 0)


def _linearized(p, free):
    st = build_structure(p.camera_index, p.point_index, np.ones(p.n_observations, dtype=bool), free, p.n_points)
    res, Jc, Jp = residuals_and_jacobians(p.camera_params, p.points_cm, st.cam, st.pt, p.uv_px[st.obs], n_threads=2)
    return st, linearize(st, res, Jc, Jp, np.ones(len(st.obs)), n_threads=2)


@pytest.mark.parametrize("gauge", [False, True])
def test_blocks_are_the_dense_systems_values_and_the_steps_agree(ring, forced, monkeypatch, gauge):
    free = ring.free.copy()
    free[:, 14] = False  # k3 held everywhere: blocks over the free columns only
    free[0, :6] = False  # one pose held: fixed parameters inside active cameras
    st, lin = _linearized(ring, free)
    layout = sparse.sparse_layout(st, free_columns(st))
    A = len(st.active_cameras)
    assert layout is not None and len(layout.cols) < A * (A + 1) // 2 // 2  # most camera pairs share no point
    basis = inner_constraint_basis(ring.camera_params[st.active_cameras], st.free, lin.D_c) if gauge else None
    system = build_reduced_system(st, lin, 1e-3, n_threads=2, gauge_basis=basis)
    assert system.layout is not None and system.S is None
    M = layout.matrix(system.blocks).toarray()
    M = M + np.tril(M, -1).T
    S_dense, _, _, _ = reduced_system(st, lin, 1e-3, n_threads=2)
    f = st.free_flat
    assert np.array_equal(M, S_dense[np.ix_(f, f)])  # the same sums in the same order
    step = solve_reduced(st, lin, system, 1e-2, n_threads=2)  # a retry's damping on the kept blocks
    monkeypatch.setattr(sparse, "SPARSE_MIN_UNKNOWNS", 10**9)
    st_dense, _ = _linearized(ring, free)
    ref = solve_reduced(st_dense, lin, build_reduced_system(st_dense, lin, 1e-3, n_threads=2, gauge_basis=basis),
                        1e-2, n_threads=2)
    assert ref.dc.shape == step.dc.shape
    assert np.abs(step.dc - ref.dc).max() <= 1e-10 * np.abs(ref.dc).max()
    assert np.abs(step.dp - ref.dp).max() <= 1e-10 * np.abs(ref.dp).max()
    assert step.predicted_decrease == pytest.approx(ref.predicted_decrease, rel=1e-10)


def test_a_solve_on_the_sparse_path_equals_the_dense_one_and_repeats_to_the_bit(ring, monkeypatch):
    options = BAOptions(n_threads=2, compute_uncertainty=False)
    dense = bundle_adjust(ring, options)
    monkeypatch.setattr(sparse, "SPARSE_MIN_UNKNOWNS", 0)
    first, second = bundle_adjust(ring, options), bundle_adjust(ring, options)
    assert np.array_equal(first.problem.camera_params, second.problem.camera_params)
    assert np.array_equal(first.problem.points_cm, second.problem.points_cm)
    assert np.array_equal(first.inlier, dense.inlier)
    d, s = dense.problem.camera_params, first.problem.camera_params
    assert np.abs(s[:, 3:6] - d[:, 3:6]).max() < 1e-5  # cm: 1e-4 mm
    assert np.abs(s[:, 6:8] / d[:, 6:8] - 1).max() < 1e-9  # relative focal


def test_the_rule_keeps_a_system_where_every_camera_pair_shares_points_dense(ring, forced):
    cams, _ = read_calibration(CALIBRATION)  # the ring's 52 cameras without its window: every pair shares points
    every = make_problem([cams[n] for n in sorted(cams)[::10]], SyntheticOptions(
        n_points=300, target_observations=3000, noise_px=0.3, outlier_fraction=0.0, seed=2)).start
    st, _ = _linearized(every, every.free)
    assert sparse.sparse_layout(st, free_columns(st)) is None
    st, _ = _linearized(ring, ring.free)
    assert sparse.sparse_layout(st, free_columns(st)) is not None


def test_block_fill_counts_the_factors_blocks():
    # an arrow: camera 0 shares points with every other, no other pair shares any
    A = 6
    row_ptr = np.array([0, 6, 7, 8, 9, 10, 11])
    cols = np.array([0, 1, 2, 3, 4, 5, 1, 2, 3, 4, 5])
    assert sparse.block_factor_fill(row_ptr, cols, np.arange(A)) == A * (A + 1) // 2  # the hub first: full fill
    assert sparse.block_factor_fill(row_ptr, cols, np.array([1, 2, 3, 4, 5, 0])) == 2 * A - 1  # the hub last: none
    # per column, in elimination order: the hub first fills every later column to the bottom (6, 5, ..., 1 blocks);
    # the hub last leaves each leaf its diagonal and the hub's block (2 blocks), the hub its diagonal alone
    assert sparse.block_factor_counts(row_ptr, cols, np.arange(A)).tolist() == [6, 5, 4, 3, 2, 1]
    assert sparse.block_factor_counts(row_ptr, cols, np.array([1, 2, 3, 4, 5, 0])).tolist() == [2, 2, 2, 2, 2, 1]


def test_the_lens_models_quadratic_model_is_the_same_on_the_sparse_path(ring, monkeypatch):
    from dome_calib.ba.quadratic import QuadraticModel

    result = bundle_adjust(ring, BAOptions(n_threads=2, compute_uncertainty=False))
    result.problem.camera_params[:, 6:8] *= 1.002  # off the solution: steps well above rounding
    result.problem.camera_params[:, 10] += 0.01
    lens = {i: [10, 11, 14] for i in range(ring.n_cameras)}
    held = ring.free.copy()
    held[:, 14] = False
    models = {}
    # against the dense path's whole factorisation (its factor through the cameras' cores is compared with that one
    # in tests/test_ba_quadratic.py: this ring's undamped system is too ill-conditioned for two orderings to agree
    # on the inverse's small entries, 8e-4 of a block's largest apart)
    monkeypatch.setattr(QuadraticModel, "_partitioned", lambda self, idx, damping: None)
    for name, minimum in (("dense", 10**9), ("sparse", 0)):
        monkeypatch.setattr(sparse, "SPARSE_MIN_UNKNOWNS", minimum)
        models[name] = QuadraticModel.at(result, ring.free)
    assert models["sparse"].sparse and not models["dense"].sparse
    assert models["sparse"].noise_px == pytest.approx(models["dense"].noise_px, rel=1e-5)
    dense = models["dense"]
    for free, damping in ((ring.free, 0.0), (held, 1e-4)):
        (sd, bd), (ss, bs) = (models[k].step(free, lens, damping=damping) for k in ("dense", "sparse"))
        # the undamped model with every lens term free is ill-conditioned (the two steps differ by ~1e-5
        # relative): judged by the backward error in the dense system, which must be as small as the dense solve's
        idx = dense.index[free & (dense.index >= 0)]
        S = dense.S[np.ix_(idx, idx)]
        S[np.diag_indices_from(S)] *= 1.0 + damping
        x_of = lambda step: step[free & (dense.index >= 0)]  # noqa: E731
        backward = [np.linalg.norm(S @ x_of(x) - dense.b[idx]) / np.linalg.norm(dense.b[idx]) for x in (sd, ss)]
        assert backward[1] <= max(10 * backward[0], 1e-10), backward
        assert np.abs(ss - sd).max() <= 1e-4 * np.abs(sd).max()
        for c in bd:
            assert np.abs(bs[c] - bd[c]).max() <= 1e-5 * np.abs(bd[c]).max()
