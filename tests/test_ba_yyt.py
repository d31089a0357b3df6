"""The compiled Y Y^T kernel against the dense product it stands for."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dome_calib.ba.schur import build_structure
from dome_calib.ba.yyt import LANES, subtract_yyt


def _random_case(seed: int, n_cams: int, n_points: int, nk: int, duplicates: bool):
    rng = np.random.default_rng(seed)
    cam, pt = [], []
    for p in range(n_points):
        seen = rng.choice(n_cams, size=rng.integers(1, n_cams + 1), replace=False)
        if duplicates and rng.random() < 0.3:  # one camera sees the point twice (two features, one track)
            seen = np.append(seen, seen[0])
        cam += list(seen)
        pt += [p] * len(seen)
    cam, pt = np.array(cam), np.array(pt)
    free = np.ones((n_cams, 15), bool)
    free[rng.integers(n_cams)] = False  # one camera held: not active
    s = build_structure(cam, pt, np.ones(len(cam), bool), free, n_points)
    y = rng.normal(size=(int(s.act.sum()), nk, 3))
    return s, y


def _point_major(s, y: np.ndarray) -> np.ndarray:
    """The (camera, point)-ordered (Ma, k, 3) blocks as the kernel reads them: transposed, point-major, padded."""
    nk = y.shape[1]
    ypt = np.zeros((len(y), 3, -(-nk // LANES) * LANES))
    ypt[:, :, :nk] = y[s.pt_order].transpose(0, 2, 1)
    return ypt


def _dense_yyt(s, y: np.ndarray) -> np.ndarray:
    A, nk = len(s.active_cameras), y.shape[1]
    Y = np.zeros((A * nk, 3 * s.n_points))
    cl, pt = s.cam_local[s.act], s.pt[s.act]
    for i in range(len(y)):
        Y[cl[i] * nk:(cl[i] + 1) * nk, 3 * pt[i]:3 * pt[i] + 3] += y[i]
    return Y @ Y.T


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_cams=st.integers(2, 9), n_points=st.integers(1, 40),
       nk=st.sampled_from([1, 3, 8, 15]), duplicates=st.booleans())
def test_yyt_kernel_equals_dense_product(seed, n_cams, n_points, nk, duplicates):
    s, y = _random_case(seed, n_cams, n_points, nk, duplicates)
    A = len(s.active_cameras)
    S4 = np.full((A, nk, A, nk), 2.0)  # the kernel subtracts from what is there
    subtract_yyt(S4, _point_major(s, y), s, n_threads=2)
    expected = 2.0 - _dense_yyt(s, y)
    np.testing.assert_allclose(S4.reshape(A * nk, A * nk), expected, rtol=0,
                               atol=1e-10 * max(1.0, np.abs(expected).max(initial=0.0)))


def test_yyt_kernel_is_the_same_on_any_number_of_threads():
    s, y = _random_case(7, 12, 300, 15, True)
    A = len(s.active_cameras)
    out = []
    for threads in (1, 2, 3):
        S4 = np.zeros((A, 15, A, 15))
        subtract_yyt(S4, _point_major(s, y), s, n_threads=threads)
        out.append(S4)
    assert np.array_equal(out[0], out[1]) and np.array_equal(out[0], out[2])
    S = out[0].reshape(A * 15, A * 15)
    assert np.array_equal(S, S.T)  # mirrored, not recomputed
