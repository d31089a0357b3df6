"""The compiled square-block gather: the same values as numpy's fancy indexing, in any thread count."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.ba.submatrix import submatrix, submatrix_in_place


@pytest.mark.parametrize("n_threads", [1, 2, 3])
def test_submatrix_equals_fancy_indexing_bit_for_bit(n_threads):
    rng = np.random.default_rng(0)
    S = rng.standard_normal((700, 700))
    for idx in (np.sort(rng.choice(700, 650, replace=False)),  # most rows kept, in order (a few terms held)
                rng.choice(700, 400, replace=False),  # any order
                np.r_[np.arange(300), np.arange(300)]):  # repeated indices
        out = submatrix(S, idx, n_threads=n_threads)
        assert out.flags.c_contiguous and out.dtype == np.float64
        assert np.array_equal(out, S[np.ix_(idx, idx)])


def test_small_or_unusual_matrices_take_numpys_path():
    S = np.arange(36.0).reshape(6, 6)
    assert np.array_equal(submatrix(S, np.array([4, 1])), S[np.ix_([4, 1], [4, 1])])
    F = np.asfortranarray(np.random.default_rng(1).standard_normal((300, 300)))
    idx = np.arange(0, 300, 2)
    assert np.array_equal(submatrix(F, idx), F[np.ix_(idx, idx)])


def test_an_index_outside_the_matrix_is_refused():
    S = np.zeros((300, 300))
    with pytest.raises(IndexError, match="300 x 300"):
        submatrix(S, np.arange(1, 301))


def test_the_in_place_gather_equals_fancy_indexing_and_uses_the_matrix_own_memory():
    rng = np.random.default_rng(2)
    S = rng.standard_normal((500, 500))
    for idx in (np.sort(rng.choice(500, 460, replace=False)), np.arange(500), np.array([3, 250, 499]),
                np.arange(0, 500, 7)):
        work = S.copy()
        out = submatrix_in_place(work, idx)
        assert np.array_equal(out, S[np.ix_(idx, idx)])
        assert np.shares_memory(out, work) and out.flags.c_contiguous


def test_the_in_place_gather_refuses_what_it_cannot_do_in_place():
    S = np.zeros((300, 300))
    with pytest.raises(IndexError, match="ascending"):
        submatrix_in_place(S, np.array([5, 2]))
    with pytest.raises(ValueError, match="square C-ordered"):
        submatrix_in_place(np.asfortranarray(S), np.arange(3))
