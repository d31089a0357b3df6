"""The choice helpers of :mod:`dome_calib.ties`: the same answer when the values move by noise far below the step
(another machine's last bits), equal quantised values broken by index (callers keep candidates in name order),
entries outside the mask never read."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dome_calib import ties

STEPS = [ties.CAMERA_DISTANCE_QUANTUM_CM, ties.POINT_OFFSET_QUANTUM_CM, ties.VIEW_COSINE_QUANTUM, ties.NCC_QUANTUM,
         ties.FLOW_QUANTUM_PX, ties.CORNER_QUANTUM_PX, ties.TIME_QUANTUM_MS, ties.RESIDUAL_QUANTUM_CM,
         ties.LENGTH_QUANTUM_CM, ties.UNIT_QUANTUM]
NOISE = 1e-3  # of a step: far below it, far above float noise on these values


@st.composite
def rows(draw, with_mask=True):
    """(multiples (R, C) int, values = multiples * step + noise (R, C), mask (R, C) or None, step)."""
    R, C = draw(st.integers(1, 4)), draw(st.integers(1, 7))
    step = draw(st.sampled_from(STEPS))
    k = np.array(draw(st.lists(st.integers(-5, 5), min_size=R * C, max_size=R * C)), dtype=np.int64).reshape(R, C)
    noise = np.array(draw(st.lists(st.floats(-NOISE, NOISE), min_size=R * C, max_size=R * C))).reshape(R, C)
    mask = (np.array(draw(st.lists(st.booleans(), min_size=R * C, max_size=R * C))).reshape(R, C)
            if with_mask else None)
    return k, (k + noise) * step, mask, step


def _reference_best(k: np.ndarray, mask: np.ndarray, largest: bool) -> tuple[list[int], list[bool]]:
    """Per row the first index of the largest (smallest) multiple among the masked: a plain loop."""
    best, found = [], []
    for kr, mr in zip(k, mask):
        cand = [j for j in range(len(kr)) if mr[j]]
        if not cand:
            best.append(0), found.append(False)
            continue
        target = max(kr[cand]) if largest else min(kr[cand])
        best.append(min(j for j in cand if kr[j] == target)), found.append(True)
    return best, found


@settings(max_examples=60, deadline=None)
@given(rows())
def test_masked_argmax_argmin_ignore_noise_and_break_ties_by_index(case):
    k, values, mask, step = case
    for fn, largest in ((ties.argmax_where, True), (ties.argmin_where, False)):
        best, found = fn(values, mask, step)
        ref_best, ref_found = _reference_best(k, mask, largest)
        assert best.tolist() == ref_best and found.tolist() == ref_found
        # entries outside the mask are never read: NaN or inf there changes nothing
        poisoned = np.where(mask, values, np.nan if largest else -np.inf)
        assert [a.tolist() for a in fn(poisoned, mask, step)] == [ref_best, ref_found]


@settings(max_examples=60, deadline=None)
@given(rows())
def test_masked_argsort_ignores_noise_and_puts_the_masked_out_last(case):
    k, values, mask, step = case
    got = ties.argsort_where(values, mask, step)
    for kr, mr, g in zip(k, mask, got):
        inside = sorted((j for j in range(len(kr)) if mr[j]), key=lambda j: (kr[j], j))
        assert g.tolist() == inside + [j for j in range(len(kr)) if not mr[j]]


@settings(max_examples=60, deadline=None)
@given(rows(with_mask=False), st.data())
def test_first_along_an_axis_and_comparisons_ignore_noise(case, data):
    k, values, _, step = case
    assert ties.argmax_first(values, step, axis=1).tolist() == np.argmax(k, axis=1).tolist()
    assert ties.argmin_first(values, step, axis=1).tolist() == np.argmin(k, axis=1).tolist()
    assert ties.argmax_first(values[0], step) == int(np.argmax(k[0]))
    limit_k = data.draw(st.integers(-5, 5))
    limit = (limit_k + data.draw(st.floats(-NOISE, NOISE))) * step
    assert ties.at_most(values, limit, step).tolist() == (k <= limit_k).tolist()
    assert ties.at_least(values, limit, step).tolist() == (k >= limit_k).tolist()
    assert ties.below(values, limit, step).tolist() == (k < limit_k).tolist()
    assert ties.above(values, limit, step).tolist() == (k > limit_k).tolist()


def test_comparisons_give_nan_no_rank_and_equal_by_design_values_compare_equal():
    step = ties.UNIT_QUANTUM
    a = np.array([np.nan, 0.5, 0.5 + 3e-16, 0.5 - 3e-16, np.inf])
    assert ties.at_most(a, 0.5, step).tolist() == [False, True, True, True, False]
    assert ties.at_least(a, 0.5, step).tolist() == [False, True, True, True, True]
    assert not ties.at_most(0.5, np.nan, step)
    assert ties.below(a, 0.5, step).tolist() == [False, False, False, False, False]
    assert ties.below(np.array([np.nan, 0.4, -np.inf]), 0.5, step).tolist() == [False, True, True]
    assert not ties.below(0.4, np.nan, step)
    assert ties.above(a, 0.5, step).tolist() == [False, False, False, False, True]
    assert not ties.above(0.6, np.nan, step)
    with pytest.raises(ValueError):  # a NaN inside the mask has no rank
        ties.argmax_where(np.array([[np.nan, 1.0]]), np.array([[True, True]]), step)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 40), st.integers(0, 40), st.floats(-1e-3, 1e-3), st.floats(-1e-3, 1e-3)),
                min_size=1, max_size=12))
def test_raster_order_is_row_then_column_then_input_order(points):
    step = ties.CORNER_QUANTUM_PX
    uv = np.array([((u + du) * step, (v + dv) * step) for u, v, du, dv in points])
    expected = sorted(range(len(points)), key=lambda i: (points[i][1], points[i][0], i))
    assert ties.raster_order(uv, step).tolist() == expected
