"""The MAP term's neighbour NCC (:func:`dome_calib.recon.patches.visibility.neighbour_ncc`) from the sampled squares
alone against the rule it replaced, a dense (N, V, G) block of every camera's square (zeros where not sampled) and
each camera pair's NCC for every patch (over the samples inside both images where a square crosses its border,
``border_squares``): the same bits (issue 49, branches speed50 and visdef50)."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.patches import visibility
from dome_calib.recon.patches.visibility import Squares, ncc_partial, neighbour_ncc


def dense_rule(samples: np.ndarray, row_of: np.ndarray, anchor: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    N, V = row_of.shape
    dense = np.zeros((N, V, samples.shape[1]), np.float32)
    dense[row_of >= 0] = samples[row_of[row_of >= 0]]
    best = np.full((N, V), -1.0)
    for i, j in neighbours:
        c = ncc_partial(dense[:, i], dense[:, j])
        best[:, i] = np.where(anchor[:, j], np.maximum(best[:, i], c), best[:, i])
        best[:, j] = np.where(anchor[:, i], np.maximum(best[:, j], c), best[:, j])
    return best


def scene(N: int, V: int, seed: int, cut: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Squares of patches seen alike in their cameras; a share ``cut`` of them crossing the image border (a band of
    their samples NaN, as ``border_squares`` samples them)."""
    rng = np.random.default_rng(seed)
    sampled = rng.random((N, V)) < 0.4
    row_of = np.full((N, V), -1, np.int64)
    row_of[sampled] = rng.permutation(int(sampled.sum()))  # rows in any order, as cameras are sampled in turn
    base = rng.uniform(0.0, 255.0, (N, 49)).astype(np.float32)  # each patch's texture, seen alike in its cameras
    samples = np.empty((int(sampled.sum()), 49), np.float32)
    pn, _ = np.nonzero(sampled)
    samples[row_of[sampled]] = base[pn] + rng.normal(0.0, 40.0, (len(pn), 49)).astype(np.float32)
    samples[rng.random(len(samples)) < 0.05] = 77.0  # no texture: NCC 0
    grid = np.arange(49).reshape(7, 7)
    for r in np.flatnonzero(rng.random(len(samples)) < cut):  # 1-4 columns or rows outside the image
        k, side = int(rng.integers(1, 5)), int(rng.integers(0, 4))
        band = [grid[:, :k], grid[:, -k:], grid[:k], grid[-k:]][side]
        samples[r, band.ravel()] = np.nan
    anchor = sampled & (rng.random((N, V)) < 0.5)
    anchor[rng.random((N, V)) < 0.02] = True  # anchors without a square (the rule's zeros)
    pairs = {(min(a, b), max(a, b)) for a, b in rng.integers(0, V, (4 * V, 2)) if a != b}
    return samples, row_of, anchor, np.array(sorted(pairs), np.int64)


@pytest.mark.parametrize("cut", [0.0, 0.3])
@pytest.mark.parametrize("N,V,chunk", [(1, 2, 1024), (37, 12, 1024), (300, 60, 64), (5, 9, 2)])
def test_neighbour_ncc_is_the_dense_rule_bit_for_bit(N, V, chunk, cut, monkeypatch):
    monkeypatch.setattr(visibility, "NEIGHBOUR_CHUNK", chunk)
    samples, row_of, anchor, neighbours = scene(N, V, N + V, cut)
    got = neighbour_ncc(Squares.of(samples), row_of, anchor, neighbours)
    want = dense_rule(samples, row_of, anchor, neighbours)
    assert got.dtype == want.dtype and got.shape == (N, V)
    assert np.array_equal(got, want)
    if N * V >= 400:  # the draw reaches every case
        assert np.any(got > 0.5) and np.any(got == 0.0) and np.any(got == -1.0)


def test_no_anchor_is_minus_one_everywhere():
    samples, row_of, anchor, neighbours = scene(20, 8, 3, 0.3)
    assert np.all(neighbour_ncc(Squares.of(samples), row_of, np.zeros_like(anchor), neighbours) == -1.0)
