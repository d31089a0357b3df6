"""The visibility MAP's minimum cut against brute force on small graphs, and its tie rule."""
from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dome_calib.recon.patches.mincut import energy, min_cut_labels


@st.composite
def potts_graphs(draw):
    n = draw(st.integers(1, 8))
    cost = np.array(draw(st.lists(st.tuples(st.integers(-5, 9), st.integers(-5, 9)), min_size=n, max_size=n)),
                    dtype=float) / 4.0
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    chosen = draw(st.lists(st.sampled_from(pairs), max_size=12)) if pairs else []
    edges = np.array(chosen, dtype=np.int64).reshape(-1, 2)
    weight = np.array(draw(st.lists(st.integers(0, 6), min_size=len(edges), max_size=len(edges))), dtype=float) / 4
    return cost, edges, weight


def _brute(cost, edges, weight):
    n = len(cost)
    best, argbest = None, []
    for x in itertools.product((0, 1), repeat=n):
        e = energy(cost, edges, weight, np.array(x))
        if best is None or e < best:
            best, argbest = e, [x]
        elif e == best:
            argbest.append(x)
    return best, argbest


@settings(max_examples=300, deadline=None)
@given(potts_graphs())
def test_min_cut_is_the_minimum_and_ties_go_to_zero(graph):
    cost, edges, weight = graph
    labels = min_cut_labels(cost, edges, weight)
    best, minimisers = _brute(cost, edges, weight)
    assert energy(cost, edges, weight, labels) == best
    # the smallest source side: every minimiser labels 1 at least where this one does
    ones = set(np.flatnonzero(labels))
    assert all(ones <= {i for i, v in enumerate(x) if v} for x in minimisers)


@settings(max_examples=100, deadline=None)
@given(st.lists(potts_graphs(), min_size=2, max_size=5))
def test_graphs_solved_together_get_their_own_labels(graphs):
    alone = [min_cut_labels(*g) for g in graphs]
    offsets = np.cumsum([0] + [len(g[0]) for g in graphs])
    cost = np.concatenate([g[0] for g in graphs])
    edges = np.concatenate([g[1] + o for g, o in zip(graphs, offsets)])
    weight = np.concatenate([g[2] for g in graphs])
    together = min_cut_labels(cost, edges, weight)
    assert np.array_equal(together, np.concatenate(alone))


def test_prior_pulls_a_doubtful_camera_to_its_neighbours():
    cost = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 0.3]])  # two confident "visible", one weakly "hidden"
    edges = np.array([[0, 2], [1, 2]])
    assert min_cut_labels(cost, edges, np.array([0.0, 0.0])).tolist() == [1, 1, 0]
    assert min_cut_labels(cost, edges, np.array([0.2, 0.2])).tolist() == [1, 1, 1]
