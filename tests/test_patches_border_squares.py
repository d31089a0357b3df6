"""A patch whose square crosses a camera's image border (``PatchOptions.border_squares``): with the option the camera
is a candidate, judged on the square's samples inside the image, and labelled visible when it sees the patch and not
when it sees something else; without it, the camera is no candidate (the old rule: the whole square inside). On by
default.
``visibility.ncc_partial`` is the plain NCC where nothing is cut, the NCC of the shared samples where something is."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.patches.frames import patch_grid_cm, ncc
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.visibility import (MIN_BORDER_SAMPLES, Frames, camera_neighbours, estimate_visibility,
                                                 ncc_partial)
from dome_calib.recon.project import project_view
from dome_calib.camera import pixels_to_normalized

from .test_patches_visibility import P0, TexturedPlane, plane  # noqa: F401  (the module's plane fixture)

CUT_CAMERA = 0  # the camera (name order) whose left border the square crosses


def _at_border(views, normal: np.ndarray, o: PatchOptions) -> tuple[np.ndarray, int]:
    """A point of the plane through P0 (normal ``normal``) whose square (plane axes as TexturedPlane's) projects into
    CUT_CAMERA's image with its centre inside and 5 of its 7 columns (35 samples) inside, the rest cut by the left
    border; and how many samples are inside."""
    v = CUT_CAMERA
    h = float(views.resolution[v][1])
    u_ax = np.cross(normal, [0.0, 1.0, 0.0])
    u_ax /= np.linalg.norm(u_ax)
    for x in np.arange(0.0, 40.0, 0.25):
        xn = pixels_to_normalized(np.array([[x, h / 2]]), views.intr[v], views.dist[v])
        d = np.concatenate([xn, [[1.0]]], 1)[0] @ views.R[v]
        c = views.center_cm[v]
        Q = c + ((P0 - c) @ normal / (d @ normal)) * d
        X = np.array([[Q, Q + 3.0 * u_ax, Q + 3.0 * np.cross(normal, u_ax)]])
        _, seen = project_view(views, v, patch_grid_cm(X[:, 0], X[:, 1], X[:, 2], o.ncc_size_cm)[0])
        if seen.sum() == 35:
            return X, int(seen.sum())
    raise AssertionError("no point puts the square across the border")




def _visibility(plane, covered: set[str], **options):
    bundle, names, views, normal = plane
    o = PatchOptions(**options)
    X, inside = _at_border(views, normal, o)
    assert MIN_BORDER_SAMPLES <= inside < 49
    source = TexturedPlane(bundle, normal, covered, centre=X[0, 0])
    frames = Frames(frame=np.zeros(len(names), np.int64), offset_ms=np.zeros(len(names)))
    before = np.ones((1, len(names)), bool)
    before[0, CUT_CAMERA] = False  # the patch comes into the border camera: another camera is the reference
    vis = estimate_visibility(source, views, frames, X, np.zeros_like(X), before, None, camera_neighbours(views, 4), o)
    assert vis.reference[0] != CUT_CAMERA
    return vis


def test_a_square_across_the_border_is_judged_on_its_inside(plane):
    old = _visibility(plane, set(), border_squares=False)
    assert not old.candidate[0, CUT_CAMERA]  # the whole square must be inside: the camera is lost
    assert not old.visible[0, CUT_CAMERA]
    new = _visibility(plane, set(), border_squares=True)
    assert new.candidate[0, CUT_CAMERA] and new.visible[0, CUT_CAMERA]
    # the same plane: its inside matches the reference (0.884 on the default 4 cm square, above 0.9 on 6 cm)
    assert new.ncc[0, CUT_CAMERA] > 0.85
    others = np.arange(new.visible.shape[1]) != CUT_CAMERA
    assert np.array_equal(new.visible[0, others], old.visible[0, others])
    assert new.visible[0, others].all()


def test_a_covered_camera_across_the_border_is_not_visible(plane):
    names = plane[1]
    vis = _visibility(plane, {names[CUT_CAMERA]}, border_squares=True)
    assert vis.candidate[0, CUT_CAMERA]
    assert vis.ncc[0, CUT_CAMERA] < 0.3
    assert not vis.visible[0, CUT_CAMERA]


def test_ncc_partial_is_ncc_without_cuts_and_the_shared_samples_with():
    rng = np.random.default_rng(0)
    a, b = rng.uniform(0, 255, (2, 5, 49)).astype(np.float32)
    b = (0.7 * a + 0.3 * b).astype(np.float32)
    assert np.array_equal(ncc_partial(a, b), ncc(a, b).astype(float))
    cut = a.copy()
    cut[0, :10] = np.nan  # 39 shared
    cut[1, :30] = np.nan  # 19 shared: too few
    got = ncc_partial(cut, b)
    assert got[0] == pytest.approx(float(ncc(a[0, 10:], b[0, 10:])), abs=1e-6)
    assert got[1] == 0.0
    assert np.array_equal(got[2:], ncc(a[2:], b[2:]).astype(float))
