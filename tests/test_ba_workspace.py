"""The bundle adjustment's large arrays come from one kept workspace (issue 52): the quadratic model of the
lens-model selection and the uncertainties at the end reuse the solves' pages instead of building fresh reduced
systems (each a fresh mapping of 7,815^2 doubles on the full dome, zeroed by the kernel page by page).

Measured with tracemalloc (numpy reports its allocations to it): with the workspace warm, a quadratic model and the
uncertainties allocate less than one reduced system at their peak; before, each took three or more (the system, its
free block, LAPACK's Fortran copy, the inverse's symmetrised copies).
"""
from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np

from dome_calib.ba import BAOptions, bundle_adjust, solution_uncertainty
from dome_calib.ba.quadratic import QuadraticModel
from dome_calib.ba.schur import Workspace
from dome_calib.panoptic_io import read_calibration
from dome_calib.synth.ba_problem import SyntheticOptions, make_problem

CALIBRATION = Path(__file__).parent / "data" / "panoptic" / "calibration_160906_band1.json"


def test_a_workspace_hands_out_the_same_memory_by_name():
    ws = Workspace()
    a = ws.array("S", (40, 40))
    b = ws.array("S", (30, 30), zero=True)
    assert np.shares_memory(a, b) and b.flags.c_contiguous and not b.any()
    c = ws.array("S", (50, 50))  # larger: a new allocation, the old one let go
    assert not np.shares_memory(a, c) and ws.nbytes() == 50 * 50 * 8
    assert ws.array("S32", (10,), dtype=np.float32).dtype == np.float32


def test_the_quadratic_model_and_the_uncertainties_reuse_the_solves_arrays():
    cams, _ = read_calibration(CALIBRATION)
    names = sorted(n for n in cams if not n.startswith("50_"))[:48]  # many cameras, few observations: S dominates
    problem = make_problem([cams[n] for n in names], SyntheticOptions(
        n_points=400, target_observations=4000, noise_px=0.3, outlier_fraction=0.0, seed=3)).start
    ws = Workspace()
    result = bundle_adjust(problem, BAOptions(n_threads=2, compute_uncertainty=False, outlier_rounds=1), workspace=ws)
    system_bytes = (problem.n_cameras * 15) ** 2 * 8
    QuadraticModel.at(result, problem.free, workspace=ws)  # the workspace's first quadratic model: its factors' pages
    peaks = []
    for call in (lambda: QuadraticModel.at(result, problem.free, workspace=ws),
                 lambda: solution_uncertainty(result, workspace=ws)):
        tracemalloc.start()
        out = call()
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert out is not None
    assert max(peaks) < 0.9 * system_bytes, (peaks, system_bytes)
    # the same numbers as without a shared workspace
    alone = solution_uncertainty(result)
    shared = solution_uncertainty(result, workspace=ws)
    assert np.array_equal(alone.sigma_center_cm, shared.sigma_center_cm)
    assert np.array_equal(alone.sigma_intr_px, shared.sigma_intr_px)


def test_a_reduced_system_with_the_inner_constraints_allocates_nothing_of_its_size_once_warm():
    """The inner constraints' rank-7 term goes into S through a kept buffer: before, each block of its rows was a
    fresh array (on the full dome 64 MB each, past glibc's largest heap size: a new mapping faulted in and zeroed
    by the kernel, 8 per reduced system), here one of S's size since the system has fewer rows than a block."""
    from dome_calib.ba.evaluate import residuals_and_jacobians
    from dome_calib.ba.gauge import inner_constraint_basis
    from dome_calib.ba.schur import build_reduced_system, build_structure, linearize

    cams, _ = read_calibration(CALIBRATION)
    names = sorted(n for n in cams if not n.startswith("50_"))[:48]
    problem = make_problem([cams[n] for n in names], SyntheticOptions(
        n_points=400, target_observations=4000, noise_px=0.3, outlier_fraction=0.0, seed=3)).start
    st = build_structure(problem.camera_index, problem.point_index, np.ones(problem.n_observations, dtype=bool),
                         problem.free, problem.n_points, Workspace())
    res, Jc, Jp = residuals_and_jacobians(problem.camera_params, problem.points_cm, st.cam, st.pt,
                                          problem.uv_px[st.obs])
    lin = linearize(st, res, Jc, Jp, np.ones(len(st.obs)))
    basis = inner_constraint_basis(problem.camera_params[st.active_cameras], st.free, lin.D_c)
    plain = build_reduced_system(st, lin, 1e-4).S.copy()
    build_reduced_system(st, lin, 1e-4, gauge_basis=basis)  # warm
    tracemalloc.start()
    S = build_reduced_system(st, lin, 1e-4, gauge_basis=basis).S
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 0.5 * S.nbytes, (peak, S.nbytes)
    expected = plain
    for i in range(0, len(expected), 1024):  # the former expression: the same bits
        expected[i:i + 1024] += basis[i:i + 1024] @ basis.T
    assert np.array_equal(S, expected)
