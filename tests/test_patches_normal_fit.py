"""Seeds' normals on a curved surface seeded on one side only (PatchOptions.normal_fit, seed._normals): the plane
through the neighbours leans towards the side that has seeds; a quadric's normal at the seed does not."""
import numpy as np
import pytest

from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.seed import _normals

RADIUS_CM = 6.0  # a forearm-sized cylinder, axis along y
SPACING_CM = 1.5  # the seeds' cell size


def _half_cylinder(noise_cm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Seeds on the half of the cylinder facing +z (the cameras' side): points (N, 3), true normals (N, 3)."""
    step = np.degrees(SPACING_CM / RADIUS_CM)  # 14.3 deg: columns at 0, +-14.3, ..., +-81.9 (none exactly edge-on)
    th = step * np.arange(-int(90.0 / step), int(90.0 / step) + 1)
    y = np.arange(-6.0, 6.0 + 1e-9, SPACING_CM)
    T, Y = np.meshgrid(np.radians(th), y)
    n = np.stack([np.sin(T), np.zeros_like(T), np.cos(T)], -1).reshape(-1, 3)
    X = RADIUS_CM * n + np.stack([np.zeros_like(Y), Y, np.zeros_like(Y)], -1).reshape(-1, 3)
    return X + np.random.default_rng(3).normal(0.0, noise_cm, X.shape), n


CAMERAS = np.array([[x, -20.0, 300.0] for x in (-150.0, -75.0, 0.0, 75.0, 150.0)])


def _error_deg(fit: str, radius_cm: float, noise_cm: float = 0.0) -> np.ndarray:
    X, n_true = _half_cylinder(noise_cm)
    seen = np.ones((len(X), len(CAMERAS)), bool)
    n, _, ok = _normals(X, X, seen, CAMERAS, radius_cm, 5, fit)
    assert ok.all()
    return X, np.degrees(np.arccos(np.clip(np.sum(n * n_true, 1), -1.0, 1.0)))


@pytest.mark.parametrize("noise_cm", [0.0, 0.1])
def test_outline_of_a_cylinder_seen_edge_on(noise_cm):
    """At the outline (the seeded half's last column of seeds, 86 deg round from +z: every camera sees it within 20
    deg of edge-on) the plane of the seeds within 4 cm is 12-14 deg off, leaning towards the cameras; the quadric
    within 6 cm within 4 deg (noise-free: 1)."""
    X, plane = _error_deg("plane", 4.0, noise_cm)
    _, quad = _error_deg("quadric", 6.0, noise_cm)
    X0, n_true = _half_cylinder()  # the noise-free seeds, row for row
    outline = np.abs(n_true[:, 0]) >= np.abs(n_true[:, 0]).max() - 1e-9
    middle = np.abs(X0[:, 1]) <= 1.5 + 1e-9  # away from the cylinder's cut ends
    m = outline & middle
    assert m.sum() >= 4
    assert np.min(plane[m]) > 10.0
    assert np.max(quad[m]) < (1.0 if noise_cm == 0 else 4.0)


def test_quadric_on_a_plane_is_the_plane():
    """A flat patch of seeds: both fits give its normal (the quadric's curvature terms vanish)."""
    g = np.arange(-6.0, 6.0 + 1e-9, SPACING_CM)
    A, B = np.meshgrid(g, g)
    X = np.stack([A, B, 0.3 * A], -1).reshape(-1, 3)
    true = np.array([-0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0)
    seen = np.ones((len(X), len(CAMERAS)), bool)
    for fit in ("plane", "quadric"):
        n, _, ok = _normals(X, X, seen, CAMERAS, 6.0, 5, fit)
        assert ok.all()
        assert np.degrees(np.arccos(np.clip(n @ true, -1, 1))).max() < 1e-4


def test_too_few_points_for_a_quadric_keep_the_plane():
    """Fewer than 8 neighbours: the plane's normal, the same bits as fit="plane"."""
    X, _ = _half_cylinder()
    seen = np.ones((len(X), len(CAMERAS)), bool)
    plane = _normals(X, X, seen, CAMERAS, 2.2, 5, "plane")
    quad = _normals(X, X, seen, CAMERAS, 2.2, 5, "quadric")
    counts = np.array([np.sum(np.linalg.norm(X - x, axis=1) <= 2.2) for x in X])
    few = counts < 8
    assert few.any()
    for a, b in zip(plane, quad):
        assert np.array_equal(a[few], b[few], equal_nan=a.dtype.kind == "f")


def test_option_is_checked():
    assert PatchOptions().normal_fit == "plane"
    assert PatchOptions(normal_fit="quadric").normal_fit == "quadric"
    with pytest.raises(Exception):
        PatchOptions(normal_fit="cubic")
