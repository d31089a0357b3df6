"""The people stream's choices through :mod:`dome_calib.ties`: a value a float's last bits away from a gate or a
radius is on the same side of it on every machine (both are quantised to the choice's named step)."""
from __future__ import annotations

import numpy as np

from dome_calib import ties
from dome_calib.recon.people.matching import greedy_match
from dome_calib.recon.people.proposals import AssociationOptions, cluster_hypotheses

NOISE = 1e-12  # a few ulps of a dome-sized length: what another BLAS may add or take


def _two_hypotheses(gap_cm: float) -> int:
    """Proposals clustered from two hypotheses ``gap_cm`` apart (the default radius: 30 cm; no weight floor)."""
    options = AssociationOptions(min_cluster_weight=0.0, relative_cluster_weight=0.0)
    centres = np.array([[100.0, 50.0, 90.0], [100.0 + gap_cm, 50.0, 90.0]])
    joints = np.broadcast_to(centres[:, None], (2, 19, 3)).copy()
    return len(cluster_hypotheses(centres, joints, np.array([5.0, 4.0]), options))


def test_hypotheses_on_the_cluster_radius_cluster_alike_whatever_their_last_bits():
    radius = AssociationOptions().cluster_radius_cm
    assert _two_hypotheses(radius - NOISE) == _two_hypotheses(radius) == _two_hypotheses(radius + NOISE) == 2
    assert _two_hypotheses(radius - 2 * ties.HYPOTHESIS_CENTRE_QUANTUM_CM) == 1  # a step inside: one cluster


def test_a_cost_on_the_gate_is_matched_alike_whatever_its_last_bits():
    step = ties.SKELETON_DISTANCE_QUANTUM_CM
    for noise in (-NOISE, 0.0, NOISE):
        assert greedy_match(np.array([[20.0 + noise]]), 20.0, step).tolist() == [-1]
    assert greedy_match(np.array([[20.0 - 2 * step]]), 20.0, step).tolist() == [0]
    # equal costs up to the last bits: the lowest (a, b) wins, whichever carries the noise
    assert greedy_match(np.array([[5.0 + NOISE, 5.0], [9.0, 9.0]]), 20.0, step).tolist() == [0, 1]
    assert greedy_match(np.array([[5.0, 5.0 + NOISE], [9.0, 9.0]]), 20.0, step).tolist() == [0, 1]
