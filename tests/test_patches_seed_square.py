"""The seeds' own square (``PatchOptions.seed_ncc_size_cm``, ``refine_ncc_size_cm``): unset (None), every role
compares the ``ncc_size_cm`` square as before (the same bits); set, the normals' refinement and the seeds' check
(``seed_features.square_ncc``) compare their own size while the visibility keeps ``ncc_size_cm``. The defaults: the
visibility and the seeds' checks on 4 cm, the refinement on 6 cm (docs/benchmarks.md, branch split62)."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.patches.model import PatchOptions, refine_square_cm, seed_square_cm
from dome_calib.recon.patches.refine import refine_normals
from dome_calib.recon.patches.seed_features import square_ncc
from dome_calib.recon.patches.visibility import Frames, camera_neighbours, estimate_visibility

from .patches_helpers import one_person_capture
from .test_patches_refine_reach import _Kept
from .test_patches_visibility import P0, facing_plane


@pytest.fixture(scope="module")
def plane():
    """The tiny dome's VGA cameras see a textured plane; a patch on it with its normal 20 deg off (its refinement at 4 and 6 cm ends apart)."""
    bundle, _ = one_person_capture()
    names = sorted(n for n, c in bundle.cameras.items() if str(c.type) == "vga")
    views, normal = facing_plane(bundle, names)
    source = _Kept(bundle, normal, set())
    t = np.radians(20.0)
    n = normal * np.cos(t) + np.cross(source.u, normal) * np.sin(t)
    a = np.cross(n, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    X = np.array([[P0, P0 + 3.0 * a, P0 + 3.0 * np.cross(n, a)]])
    frames = Frames(frame=np.zeros(len(names), np.int64), offset_ms=np.zeros(len(names)))
    return views, source, X, frames, np.ones((1, len(names)), bool)


#: The old rule: one square for every role.
ONE = dict(seed_ncc_size_cm=None, refine_ncc_size_cm=None)


def test_unset_the_seeds_roles_take_ncc_size_cm():
    for o in (PatchOptions(**ONE), PatchOptions(ncc_size_cm=6.0, **ONE)):
        assert seed_square_cm(o) == refine_square_cm(o) == o.ncc_size_cm
    d = PatchOptions()  # the defaults
    assert (d.ncc_size_cm, seed_square_cm(d), refine_square_cm(d)) == (4.0, 4.0, 6.0)
    o = PatchOptions(ncc_size_cm=4.0, seed_ncc_size_cm=6.0, refine_ncc_size_cm=5.0)
    assert (seed_square_cm(o), refine_square_cm(o)) == (6.0, 5.0)


def test_the_refinement_compares_its_own_square(plane):
    views, source, X, frames, seen = plane
    old4 = refine_normals(source, views, frames, X, seen, PatchOptions(ncc_size_cm=4.0, **ONE))
    old6 = refine_normals(source, views, frames, X, seen, PatchOptions(ncc_size_cm=6.0, **ONE))
    assert not np.array_equal(old4, old6)  # the size matters here
    # set to ncc_size_cm: the same bits as unset
    assert np.array_equal(refine_normals(source, views, frames, X, seen, PatchOptions(
        ncc_size_cm=6.0, seed_ncc_size_cm=None, refine_ncc_size_cm=6.0)), old6)
    # its own size, whatever the visibility's
    split = PatchOptions(ncc_size_cm=4.0, refine_ncc_size_cm=6.0, seed_ncc_size_cm=4.0)
    assert np.array_equal(refine_normals(source, views, frames, X, seen, split), old6)


def test_the_seeds_check_compares_its_own_square(plane):
    views, source, X, frames, seen = plane
    old4 = square_ncc(source, views, frames, X, seen, PatchOptions(ncc_size_cm=4.0, **ONE))
    old6 = square_ncc(source, views, frames, X, seen, PatchOptions(ncc_size_cm=6.0, **ONE))
    assert not np.array_equal(old4, old6)
    assert np.array_equal(square_ncc(source, views, frames, X, seen, PatchOptions(
        ncc_size_cm=6.0, seed_ncc_size_cm=6.0, refine_ncc_size_cm=None)), old6)
    split = PatchOptions(ncc_size_cm=4.0, seed_ncc_size_cm=6.0, refine_ncc_size_cm=4.0)
    assert np.array_equal(square_ncc(source, views, frames, X, seen, split), old6)


def test_the_visibility_keeps_ncc_size_cm(plane):
    views, source, X, frames, seen = plane
    nb = camera_neighbours(views, 4)

    def ncc(o):
        return estimate_visibility(source, views, frames, X, np.zeros_like(X), seen, None, nb, o).ncc

    four = ncc(PatchOptions(ncc_size_cm=4.0, **ONE))
    assert not np.array_equal(four, ncc(PatchOptions(ncc_size_cm=6.0, **ONE)))
    assert np.array_equal(ncc(PatchOptions(ncc_size_cm=4.0, seed_ncc_size_cm=6.0, refine_ncc_size_cm=6.0)), four)
