"""bench/patches_body.py's reach(): the occluded joint-times whose part's patches the carry kept but did not measure
(``seed_dies_carried``, branch seed363) are counted apart from those whose patches had ended."""

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

BENCH = Path(__file__).resolve().parents[1] / "bench"


def _bench():
    sys.path.insert(0, str(BENCH))  # patches_body imports its sibling bench/patches.py
    try:
        spec = importlib.util.spec_from_file_location("bench_patches_body", BENCH / "patches_body.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(BENCH))
    return mod


def _case(n_carried: int):
    """One person, a left wrist hidden at times 2-3 of 5; four patches on the left forearm, alive at times 0-1 only,
    ``n_carried`` of them carried at times 2-4."""
    pb = _bench()
    T, N, b, j = 5, 4, 6, 5  # l_forearm, l_wrist
    removed = np.zeros((T, 1, 19), bool)
    removed[2:4, 0, j] = True
    alive = np.zeros((N, T), bool)
    alive[:, :2] = True
    carried = np.zeros((N, T), bool)
    carried[:n_carried, 2:] = True
    lab = SimpleNamespace(bone=np.full(N, b), person=np.zeros(N, int))
    motions = SimpleNamespace(person=np.zeros(0, int), bone=np.zeros(0, int), step=np.zeros(0, int))
    ties = SimpleNamespace(track_id=np.zeros(0, int), joint=np.zeros(0, int), from_ms=np.zeros(0))
    args = (removed, np.zeros_like(removed), np.arange(T) * 33.0, np.array([7]), np.array([7]), lab,
            np.zeros(N, int), np.full(N, b), alive, motions, ties, np.zeros(N))
    return pb, args, carried


def test_seed_dies_carried_counts_the_joint_times_the_carry_kept():
    pb, args, carried = _case(2)
    out = pb.reach(*args, carried=carried)
    assert out["missed_causes"]["seed_dies"] == 2
    assert out["seed_dies_carried"] == 2  # two kept (the motion's min_patches, 2) at both ends of a step
    assert "seed_dies_carried" not in pb.reach(*args)  # no carry given: the old fields only
    pb, args, carried = _case(1)
    assert pb.reach(*args, carried=carried)["seed_dies_carried"] == 0  # one kept: fewer than a motion takes
