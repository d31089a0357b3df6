"""Seeds where the seeded cloud ends on one side (PatchOptions.normal_max_gap_deg, seed.neighbour_gap_deg): their
neighbours leave a wide gap round them in their plane, their plane leans towards the side that has seeds, and with
the option they are dropped; inside the cloud nothing changes."""
from types import SimpleNamespace

import numpy as np
import pytest

from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.seed import CameraSeeds, _normals, merge_camera_seeds, neighbour_gap_deg
from tests.test_patches_normal_fit import CAMERAS, SPACING_CM, _half_cylinder

U, V = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])


def _grid(lo: float = -6.0, hi: float = 6.0) -> np.ndarray:
    g = np.arange(lo, hi + 1e-9, SPACING_CM)
    A, B = np.meshgrid(g, g)
    return np.stack([A, B, np.zeros_like(A)], -1).reshape(-1, 3)


def test_gap_inside_on_an_edge_at_a_corner():
    """Inside a grid of seeds the widest empty angle is the grid's (atan(1/2), 26.6 deg); on its straight edge 180;
    at a corner 270; alone (or with one neighbour) 360. Points at the seed's own place do not count."""
    X = _grid(0.0, 6.0)
    near = lambda x: X[np.linalg.norm(X - x, axis=1) <= 4.0]  # noqa: E731
    inside = neighbour_gap_deg(np.array([3.0, 3.0, 0.0]), near([3.0, 3.0, 0.0]), U, V)
    assert inside == pytest.approx(np.degrees(np.arctan(0.5)), abs=1e-5)
    assert neighbour_gap_deg(np.array([3.0, 0.0, 0.0]), near([3.0, 0.0, 0.0]), U, V) == pytest.approx(180.0)
    assert neighbour_gap_deg(np.array([0.0, 0.0, 0.0]), near([0.0, 0.0, 0.0]), U, V) == pytest.approx(270.0)
    x = np.zeros(3)
    assert neighbour_gap_deg(x, np.stack([x, x + [1.5, 0, 0]]), U, V) == 360.0


def test_outline_seeds_are_dropped_the_rest_kept():
    """The half cylinder seeded on the cameras' side only (its last columns seen edge-on): with a gap limit of 150
    deg the seeds whose plane is most off are dropped (the outline columns: their planes 10 deg off and more, leaning
    towards the cameras) and every seed away from the cloud's ends keeps its normal, bit for bit."""
    X, n_true = _half_cylinder()
    seen = np.ones((len(X), len(CAMERAS)), bool)
    n0, a0, ok0 = _normals(X, X, seen, CAMERAS, 4.0, 5, "plane")
    n1, a1, ok1 = _normals(X, X, seen, CAMERAS, 4.0, 5, "plane", max_gap_deg=150.0)
    assert ok0.all()
    err = np.degrees(np.arccos(np.clip(np.sum(n0 * n_true, 1), -1.0, 1.0)))
    outline = np.abs(n_true[:, 0]) >= np.abs(n_true[:, 0]).max() - 1e-9
    middle = np.abs(X[:, 1]) <= 1.5 + 1e-9
    assert not ok1[outline & middle].any()  # dropped where the plane leans most
    assert np.min(err[outline & middle]) > 10.0
    inner = np.abs(n_true[:, 0]) < 0.8  # within 53 deg of the cameras' side
    assert ok1[inner & middle].all()
    assert np.array_equal(n1[ok1], n0[ok1]) and np.array_equal(a1[ok1], a0[ok1])
    # the dropped seeds are the worst: the kept ones' normals are better on the whole
    assert np.median(err[ok1]) < np.median(err)


def test_default_keeps_every_seed():
    """360 (the default before split62) drops nothing: the bits of the rule without the limit."""
    X, _ = _half_cylinder(0.1)
    seen = np.ones((len(X), len(CAMERAS)), bool)
    a = _normals(X, X, seen, CAMERAS, 4.0, 5, "plane")
    b = _normals(X, X, seen, CAMERAS, 4.0, 5, "plane", max_gap_deg=PatchOptions(normal_max_gap_deg=360.0).normal_max_gap_deg)
    for p, q in zip(a, b):
        assert np.array_equal(p, q, equal_nan=p.dtype.kind == "f")


def test_the_stage_merge_drops_them():
    """``merge_camera_seeds`` (each stream's sweep seeds) applies the option: the outline columns' seeds go, the
    others keep their patches bit for bit, in their order."""
    X, n_true = _half_cylinder()
    views = SimpleNamespace(names=[f"cam{i}" for i in range(len(CAMERAS))], center_cm=CAMERAS)
    per = [CameraSeeds(camera=0, X_cm=X, seen=np.ones((len(X), len(CAMERAS)), bool), n_inliers=np.full(len(X), 5))]
    every = merge_camera_seeds(per, views, PatchOptions(normal_max_gap_deg=360.0))  # none dropped
    some = merge_camera_seeds(per, views, PatchOptions(normal_max_gap_deg=150.0))
    assert len(every.X_cm) == len(X) and 0 < len(some.X_cm) < len(X)
    kept = np.array([np.flatnonzero((every.X_cm[:, 0] == x).all(1))[0] for x in some.X_cm[:, 0]])
    assert np.all(np.diff(kept) > 0)
    assert np.array_equal(some.X_cm, every.X_cm[kept]) and np.array_equal(some.normal, every.normal[kept])
    outline = np.abs(n_true[:, 0]) >= np.abs(n_true[:, 0]).max() - 1e-9
    assert not np.isin(kept, np.flatnonzero(outline & (np.abs(X[:, 1]) <= 1.5 + 1e-9))).any()


def test_option_is_checked():
    assert PatchOptions().normal_max_gap_deg == 210.0  # the default since split62 (docs/benchmarks.md)
    assert PatchOptions(normal_max_gap_deg=200.0).normal_max_gap_deg == 200.0
    for bad in (0.0, 400.0):
        with pytest.raises(Exception):
            PatchOptions(normal_max_gap_deg=bad)
