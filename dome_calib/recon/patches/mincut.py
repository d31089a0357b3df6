"""Binary MAP labelling of many small graphs at once, solved exactly as one minimum s-t cut.

Energy of a labelling ``x`` (0/1 per node): ``sum_i cost[i, x_i] + sum_(i,j) w_ij [x_i != x_j]`` with
``w_ij >= 0`` (a Potts prior: submodular, so the minimum cut is the exact minimum; Kolmogorov and Zabih 2004).
Graph: source -> i with capacity ``cost[i, 0]`` (cut when i takes label 0), i -> sink with ``cost[i, 1]`` (cut
when i takes 1; each node's two costs are first shifted so that the smaller is 0), i <-> j with ``w_ij`` both
ways. The maximum flow comes from :func:`scipy.sparse.csgraph.maximum_flow` (integer capacities: costs are
quantised to ``1 / COST_SCALE`` first, so the cut is exact arithmetic); label 1 = the nodes the source still
reaches in the residual graph. That set is the same for every maximum flow (the smallest source side of all
minimum cuts), so a tie between labellings always goes to label 0, and many graphs solved together (one flow over
their disjoint union, sharing the source and the sink) give each graph exactly the labels it gets alone.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, maximum_flow

#: Costs are rounded to multiples of 1 / COST_SCALE before the cut (integer capacities, exact flows).
COST_SCALE = 1000
_MAX_CAPACITY = 2**30


def quantise_costs(cost: np.ndarray) -> np.ndarray:
    """Float costs -> int64 multiples of 1 / :data:`COST_SCALE` (NaN refused; clipped to keep flows in int32)."""
    cost = np.asarray(cost, dtype=float)
    if np.any(np.isnan(cost)):
        raise ValueError("a cost of the minimum cut is NaN")
    return np.clip(np.rint(cost * COST_SCALE), -_MAX_CAPACITY, _MAX_CAPACITY).astype(np.int64)


def min_cut_labels(cost: np.ndarray, edges: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Exact minimiser of the Potts energy over N nodes (any number of separate graphs).

    Args:
        cost: (N, 2) cost of label 0 and label 1 of each node (floats, quantised here).
        edges: (E, 2) node pairs (i != j; a pair may repeat: the weights add).
        weight: (E,) w_ij >= 0.
    Returns:
        (N,) int8 labels; ties go to 0 (the smallest source side).
    Example:
        >>> min_cut_labels(np.array([[1.0, 0.0], [0.0, 0.2]]), np.array([[0, 1]]), np.array([0.5]))
        array([1, 1], dtype=int8)
    """
    c = quantise_costs(cost).reshape(-1, 2)
    N = len(c)
    if N == 0:
        return np.zeros(0, np.int8)
    c = c - c.min(axis=1, keepdims=True)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = quantise_costs(weight).reshape(-1)
    if np.any(w < 0):
        raise ValueError("a pairwise weight of the minimum cut is negative (the energy would not be submodular)")
    if np.any(e[:, 0] == e[:, 1]) or (len(e) and (e.min() < 0 or e.max() >= N)):
        raise ValueError("an edge of the minimum cut joins a node to itself or names no node")
    s, t = N, N + 1
    nodes = np.arange(N)
    rows = np.concatenate([np.full(N, s), nodes, e[:, 0], e[:, 1]])
    cols = np.concatenate([nodes, np.full(N, t), e[:, 1], e[:, 0]])
    caps = np.concatenate([c[:, 0], c[:, 1], w, w])
    keep = caps > 0
    graph = sp.csr_matrix((caps[keep].astype(np.int32), (rows[keep], cols[keep])), shape=(N + 2, N + 2))
    graph.sum_duplicates()
    flow = maximum_flow(graph, s, t, method="dinic").flow
    residual = (graph - flow).tocsr()  # cap - flow; a reverse edge's residual is the flow it carries
    residual.data = np.where(residual.data > 0, 1, 0).astype(np.int8)
    residual.eliminate_zeros()
    reached = breadth_first_order(residual, s, directed=True, return_predecessors=False)
    labels = np.zeros(N + 2, np.int8)
    labels[reached] = 1
    return labels[:N]


def energy(cost: np.ndarray, edges: np.ndarray, weight: np.ndarray, labels: np.ndarray) -> int:
    """The quantised energy (in 1 / :data:`COST_SCALE`) of a labelling: for tests and for reports."""
    c = quantise_costs(cost).reshape(-1, 2)
    x = np.asarray(labels, dtype=np.int64)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = quantise_costs(weight).reshape(-1)
    return int(c[np.arange(len(c)), x].sum() + (w * (x[e[:, 0]] != x[e[:, 1]])).sum())
