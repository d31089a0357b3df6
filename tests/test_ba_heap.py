"""dome_calib.ba.heap: freed memory kept for reuse inside the block, glibc's defaults back after it.

Observed through glibc's own accounting (``mallinfo2``: ``hblks`` counts the blocks served by mmap), not by
reading back our settings."""
from __future__ import annotations

import ctypes

import numpy as np
import pytest

from dome_calib.ba import heap


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                      "fsmblks", "uordblks", "fordblks", "keepcost")]


def _mallinfo2():
    lib = heap._glibc()
    if lib is None or not hasattr(lib, "mallinfo2"):
        pytest.skip("not glibc >= 2.33: no mallopt / mallinfo2 to observe")
    lib.mallinfo2.restype = _Mallinfo2
    return lib.mallinfo2


BIG = 64 * 2**20 // 8  # 64 MB of float64: above glibc's largest mmap threshold (32 MB)


def _mapped_blocks_for_a_big_array() -> int:
    """How many more blocks glibc serves by mmap while a fresh 64 MB array lives."""
    info = _mallinfo2()
    before = info().hblks
    a = np.ones(BIG)
    during = info().hblks
    del a
    return during - before


@pytest.fixture(autouse=True)
def _no_user_settings(monkeypatch):
    for v in heap.USER_VARIABLES:
        monkeypatch.delenv(v, raising=False)


def test_a_big_array_comes_from_the_heap_inside_and_from_mmap_outside():
    assert _mapped_blocks_for_a_big_array() == 1  # glibc's default
    with heap.kept_heap():
        assert heap.active()
        assert _mapped_blocks_for_a_big_array() == 0
        # freed and asked for again: the same heap memory, no new mapping
        arena = _mallinfo2()().arena
        for _ in range(3):
            a = np.ones(BIG)
            del a
        assert _mallinfo2()().arena == arena
    assert not heap.active()
    assert _mapped_blocks_for_a_big_array() == 1  # the defaults are back


def test_the_kept_memory_is_given_back_on_leaving():
    with heap.kept_heap():
        a = np.ones(4 * BIG)
        del a
        kept = _mallinfo2()().arena
    assert _mallinfo2()().arena < kept - 3 * BIG * 8


def test_nested_blocks_restore_only_at_the_outermost_and_on_an_exception():
    with pytest.raises(RuntimeError):
        with heap.kept_heap():
            with heap.kept_heap():
                pass
            assert heap.active() and _mapped_blocks_for_a_big_array() == 0
            raise RuntimeError("inside")
    assert not heap.active()
    assert _mapped_blocks_for_a_big_array() == 1


def test_a_user_setting_in_the_environment_is_left_to_rule(monkeypatch):
    _mallinfo2()
    monkeypatch.setenv("MALLOC_MMAP_MAX_", "65536")
    with heap.kept_heap():
        assert not heap.active()
        assert _mapped_blocks_for_a_big_array() == 1


def test_the_same_bits_from_the_heap_as_from_mmap():
    """Where an array lives (and how it is aligned) changes no value: a product and a Cholesky solve of 35 MB
    matrices, the bundle adjustment's kind of work, inside and outside the block."""
    import scipy.linalg

    from dome_calib.ba.blas import blas_threads

    rng = np.random.default_rng(7)
    A = rng.standard_normal((2100, 2100))
    b = rng.standard_normal(2100)

    def solve():
        S = A @ A.T
        S[np.diag_indices_from(S)] += 2100.0
        S32 = S.astype(np.float32)
        return scipy.linalg.cho_solve(scipy.linalg.cho_factor(S), b), scipy.linalg.cho_factor(S32)[0]

    for threads in (1, 2):
        with blas_threads(threads):
            plain = solve()
            with heap.kept_heap():
                kept = solve()
        assert all(np.array_equal(p, k) for p, k in zip(plain, kept))
