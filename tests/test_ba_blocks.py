"""The compiled per-observation kernels of the normal equations (dome_calib.ba.blocks): against the plain sums they
stand for, and the same to the last bit on any number of threads."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dome_calib.ba import ParamGroup
from dome_calib.ba.blocks import camera_ranges
from dome_calib.ba.evaluate import residuals_and_jacobians
from dome_calib.ba.schur import build_structure, linearize, point_step, reduced_system
from dome_calib.panoptic_io import read_calibration
from dome_calib.synth.ba_problem import SyntheticOptions, make_problem

CALIBRATION = Path(__file__).parent / "data/panoptic/calibration_160906_band1.json"
NAMES = ["01_01", "03_05", "05_12", "07_20", "09_03", "00_03", "00_17", "50_02"]


@pytest.fixture(scope="module")
def case():
    """A small dome problem with k3 held on one camera, a whole camera held (not active) and IRLS-like weights."""
    cams, _ = read_calibration(CALIBRATION)
    p = make_problem([cams[n] for n in NAMES], SyntheticOptions(n_points=300, target_observations=3000,
                                                                  noise_px=0.5, outlier_fraction=0.0, seed=5)).start
    p.fix(ParamGroup.K3, cameras=[NAMES[1]])
    free = p.free.copy()
    free[2] = False
    st = build_structure(p.camera_index, p.point_index, np.ones(p.n_observations, bool), free, p.n_points)
    res, Jc, Jp = residuals_and_jacobians(p.camera_params, p.points_cm, st.cam, st.pt, p.uv_px[st.obs])
    w = np.random.default_rng(1).uniform(0.2, 1.0, len(st.obs))
    return st, res, Jc, Jp, w


def test_linearization_equals_the_plain_sums(case):
    st, res, Jc, Jp, w = case
    lin = linearize(st, res, Jc.copy(), Jp, w, n_threads=2)
    Jm = Jc[:, :, st.act] * st.free[st.cam_local[st.act]].T[None]  # fixed columns zeroed
    cl = st.cam_local[st.act]
    for a in range(len(st.active_cameras)):
        m = cl == a
        wa, J0, J1 = w[st.act][m], Jm[0][:, m], Jm[1][:, m]
        U = (J0 * wa) @ J0.T + (J1 * wa) @ J1.T
        np.testing.assert_allclose(lin.U[a], U, rtol=1e-12, atol=1e-12 * np.abs(U).max())
        g = J0 @ (wa * res[0, st.act][m]) + J1 @ (wa * res[1, st.act][m])
        np.testing.assert_allclose(lin.g_c[a], g, rtol=1e-12, atol=1e-12 * np.abs(g).max())
    for q in np.unique(st.pt)[:50]:
        m = st.pt == q
        V = (Jp[0][:, m] * w[m]) @ Jp[0][:, m].T + (Jp[1][:, m] * w[m]) @ Jp[1][:, m].T
        np.testing.assert_allclose(lin.V[q], V, rtol=1e-12, atol=1e-12 * np.abs(V).max())


def test_reduced_system_and_point_step_are_the_same_on_any_number_of_threads(case):
    st, res, Jc, Jp, w = case
    out = []
    for threads in (1, 2, 3):
        lin = linearize(st, res, Jc.copy(), Jp, w, n_threads=threads)
        S, rhs, Li, ypt = reduced_system(st, lin, 1e-3, n_threads=threads)
        dc = np.random.default_rng(2).normal(size=(len(st.active_cameras), 15)) * st.free
        out.append((lin.U, lin.g_c, lin.V, lin.g_p, S, rhs, ypt, point_step(st, lin, Li, ypt, dc)))
    for other in out[1:]:
        assert all(np.array_equal(a, b) for a, b in zip(out[0], other))


def test_camera_ranges_cover_every_camera_once():
    starts = np.array([0, 10, 10, 50, 51, 200, 201])  # a camera without observations is kept in its range
    for n in (1, 2, 3, 8, 20):
        ranges = camera_ranges(starts, n)
        assert ranges[0][0] == 0 and ranges[-1][1] == 6 and len(ranges) <= n
        assert all(a < b and b == c for (a, b), (c, _) in zip(ranges, ranges[1:] + [(6, 0)]))
    assert camera_ranges(np.array([0]), 4) == []
