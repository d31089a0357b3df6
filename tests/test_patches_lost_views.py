"""A patch's view that loses one point's flow (issue 49, branch life50): on the few-camera rig 218 of 225 limb
patches are seen by exactly two cameras, so one lost flow ends the patch. A point lost in a camera where its
patch's other points were tracked is re-found from their motion (``PatchOptions.lk_refind``), and a plane point
lost alone no longer makes its view a failed flow in the visibility's motion term
(``PatchOptions.view_lost_with_centre``)."""
from __future__ import annotations

import numpy as np

from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.track import flow_camera, motion_term, refind_lost
from dome_calib.recon.project import project_points, view_set

from .patches_helpers import one_person_capture
from .test_patches_predict import FAST_PX_MS, P0, FastTexture, _clock


def test_a_lost_point_is_re_found_from_its_patch_mates_motion():
    clock = _clock()
    source = FastTexture(clock)
    t0, t1 = 200.0, 240.0
    o = PatchOptions(lk_levels=0, lk_levels_predicted=0)  # no pyramid: an 18 px motion is beyond a standing start
    p = (P0[:3] + FAST_PX_MS * t0)[None]  # one patch's three points (1, 3, 2)
    true = (P0[:3] + FAST_PX_MS * t1)[None]
    q0, ok0 = flow_camera(source, "c", clock, t0, t1, p[0], o)
    assert not ok0.all()  # the standing start loses points
    q = true.copy()
    q[0, 0] = q0[0]  # the centre lost, its mates tracked
    ok = np.array([[False, True, True]])
    got, good, found = refind_lost(source, "c", clock, t0, t1, p, q, ok, o)
    assert good.all() and found.tolist() == [[True, False, False]]
    assert np.abs(got - true).max() < 0.05
    # a patch with no point tracked in the camera has nothing to be re-found from: left lost
    _, good, found = refind_lost(source, "c", clock, t0, t1, p, q, np.zeros((1, 3), bool), o)
    assert not good.any() and not found.any()


def test_a_plane_point_lost_alone_keeps_its_view_in_the_motion_term():
    bundle, _ = one_person_capture()
    names = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"][:3]
    views = view_set(bundle, names)
    X = np.array([[[0.0, -100.0, 0.0], [3.0, -100.0, 0.0], [0.0, -97.0, 0.0]]] * 3)  # three patches (N, 3, 3)
    N, V = len(X), len(names)
    uv = project_points(views, X.reshape(-1, 3)).uv_px.transpose(1, 0, 2).reshape(N, 3, V, 2) + 0.2
    tracked = np.ones((N, 3, V), bool)
    tracked[1, 2, 0] = False  # patch 1: a plane point lost in camera 0
    uv[1, 2, 0] += 40.0  # where its failed flow left it
    tracked[2, 0, 0] = False  # patch 2: its centre lost in camera 0
    flown, slid = np.ones((N, V), bool), np.zeros((N, V), bool)
    flown[:, 2] = False  # flown in two cameras: no view to spare (min_visible 2)
    new = motion_term(views, uv, tracked, flown, slid, X, PatchOptions())
    old = motion_term(views, uv, tracked, flown, slid, X, PatchOptions(view_lost_with_centre=False))
    assert np.all(new[0, :2] < 1.0) and np.array_equal(new[0], old[0], equal_nan=True)  # all tracked: the same
    assert np.isnan(new[:, 2]).all()  # not flown: no term
    assert new[1, 0] < 1.0 and old[1, 0] == np.inf  # the plane point lost alone: the view keeps its term
    assert new[2, 0] == np.inf and old[2, 0] == np.inf  # the centre lost: a failed flow either way
    # flown in three cameras, a view to spare: the old rule (a view with a point lost is doubtful)
    spare = motion_term(views, uv, tracked, np.ones((N, V), bool), slid, X, PatchOptions())
    assert spare[1, 0] == np.inf and spare[2, 0] == np.inf and np.all(spare[0] < 1.0)
