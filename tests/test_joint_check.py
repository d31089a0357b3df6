"""The skeleton check after triangulation (dome_calib.recon.people.joint_check): a joint that few views put far from its
body is dropped, a real body (any pose, a child's or a tall adult's size) keeps every joint."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dome_calib.recon.body_models import BONE_LENGTH_CM, BONES19, JOINTS19
from dome_calib.errors import OptionsError
from dome_calib.recon.people.joint_check import JointCheckOptions, check_joints
from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.people.proposals import select_pairs
from dome_calib.recon.people.run import PeopleOptions, associate_batch
from dome_calib.recon.project import project_points, view_set
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.skeleton import skeleton_cm

from .recon_helpers import real_bundle

L_WRIST = JOINTS19.index("l_wrist")


def test_one_bone_table_covers_the_tree():
    assert set(BONES19) <= set(BONE_LENGTH_CM)
    assert all(a in JOINTS19 and b in JOINTS19 and 0 < L < 60 for (a, b), L in BONE_LENGTH_CM.items())


@pytest.fixture(scope="module")
def group_poses():
    """(K, 19, 3) poses of the synthetic group (walking, talking, crouching; each person's own height), cm."""
    truth = make_group(GroupOptions(n_people=8, duration_ms=4000.0, seed=4))
    X, present = truth.joints_cm(np.arange(0.0, 4000.0, 50.0))
    return X[present]


@given(st.integers(0, 10**6), st.floats(0.6, 1.15), st.booleans(), st.integers(0, 2**31 - 1))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_real_bodies_keep_every_joint(group_poses, k, scale, gaps, seed):
    """Any pose of the synthetic group, scaled from a child (0.6) to a tall adult (1.15: the group's tallest is
    173 cm from ankle to nose, so 2.0 m, a person of about 2.1 m; at 1.3 hypothesis found a 2.4 m body whose ankle
    stood 180 cm from its joints' median, the reach limit), 3 cm noise per joint:
    nothing dropped, whether joints are missing (then 3 to 12 views each) or all there (2 to 12: every 2-view
    joint has a plausible bone to the body)."""
    rng = np.random.default_rng(seed)
    X = group_poses[k % len(group_poses)]
    X = X.mean(0) + scale * (X - X.mean(0)) + rng.normal(scale=3.0, size=(19, 3))
    if gaps:
        X[rng.random(19) < 0.15] = np.nan
    n = rng.integers(3 if gaps else 2, 13, 19)
    keep = check_joints(X[None], n[None])[0]
    np.testing.assert_array_equal(keep, np.isfinite(X).all(1))


@given(st.floats(0, 5000), st.integers(0, 18), st.floats(200, 400), st.integers(0, 2**31 - 1))
@settings(max_examples=80, deadline=None)
def test_a_joint_metres_off_is_dropped_and_only_it(t_ms, joint, off_cm, seed):
    rng = np.random.default_rng(seed)
    X = skeleton_cm(np.array([t_ms]))[0] + rng.normal(scale=2.0, size=(19, 3))
    direction = rng.normal(size=3)
    X[joint] += off_cm * direction / np.linalg.norm(direction)
    n = rng.integers(3, 13, 19)
    n[joint] = rng.integers(2, 13)
    keep = check_joints(np.stack([X, X]), np.stack([n, n]))  # two bodies: vectorised rows stay independent
    expect = np.ones(19, bool)
    expect[joint] = False
    np.testing.assert_array_equal(keep, [expect, expect])


def test_two_views_need_the_body():
    """A 2-view forearm that agrees with itself but not with the shoulder goes entirely; with 3 views the wrist
    alone (no elbow left to judge it) stays if it is within reach. Across a joint nobody triangulated, the 2-view
    wrist is linked to the shoulder by distance against the path's nominal length."""
    X = skeleton_cm(np.array([900.0]))[0]
    elbow, wrist = JOINTS19.index("l_elbow"), L_WRIST
    X[[elbow, wrist]] += [90.0, 0.0, 0.0]  # a neighbour's forearm, 90 cm to the side
    n = np.full(19, 8)
    n[[elbow, wrist]] = 2
    keep = check_joints(X[None], n[None])[0]
    assert not keep[elbow] and not keep[wrist] and keep.sum() == 17
    n[wrist] = 3
    keep = check_joints(X[None], n[None])[0]
    assert not keep[elbow] and keep[wrist]
    # the elbow not triangulated at all: the 2-view wrist is judged against the shoulder over the path's 53 cm
    Y = skeleton_cm(np.array([900.0]))[0]
    Y[elbow] = np.nan
    n = np.full(19, 8)
    n[wrist] = 2
    assert check_joints(Y[None], n[None])[0].sum() == 18  # its own wrist: kept
    shoulder = Y[JOINTS19.index("l_shoulder")]
    Y[wrist] = shoulder + (Y[wrist] - shoulder) / np.linalg.norm(Y[wrist] - shoulder) * 110.0  # 110 cm off it
    assert not check_joints(Y[None], n[None])[0][wrist]
    # a person seen by two views only (every joint 2 views) keeps its consistent joints
    assert check_joints(skeleton_cm(np.array([900.0])), np.full((1, 19), 2)).all()
    assert check_joints(X[None], n[None], JointCheckOptions(enabled=False)).all()


def test_options_refuse_bad_values():
    for bad in ({"max_bone_ratio": 0.0}, {"min_views_alone": 1}, {"max_reach_cm": float("nan")}):
        with pytest.raises(OptionsError, match=next(iter(bad))):
            JointCheckOptions(**bad)


@pytest.mark.parametrize("right_views", [0, 1])
def test_a_neighbours_wrist_in_two_views_is_not_the_persons(right_views):
    """16 views see two people 1 m apart; person A's left wrist is detected in 2 views only, and there it is the
    neighbour's wrist (a borrowed limb, consistent between the two views), plus ``right_views`` view(s) of the
    true wrist. Before the check the 2-view point sat on the neighbour's wrist (~1 m off); now it is dropped (or
    right), every other joint of both people is kept within 3 cm."""
    bundle = real_bundle(kinect=False, sync=False)
    A = skeleton_cm(np.array([1200.0]), radius_cm=40.0)[0]
    B = A + [95.0, 0.0, 35.0]
    truth = np.stack([A, B])
    names = sorted(n for n, c in bundle.cameras.items() if c.type in ("vga", "hd"))
    whole = project_points(view_set(bundle, names), truth.reshape(-1, 3)).visible.all(1)
    seeing = [n for n, w in zip(names, whole) if w]  # cameras that see both people whole
    views = view_set(bundle, seeing[:: len(seeing) // 16][:16])
    proj = project_points(views, truth.reshape(-1, 3))
    uv = proj.uv_px.reshape(16, 2, 19, 2) + np.random.default_rng(3).normal(scale=1.0, size=(16, 2, 19, 2))
    conf = np.full((16, 2, 19), 0.9)
    options = PeopleOptions()
    pairs = select_pairs(views, options.association.max_pairs)
    wrong = pairs[0]  # two views far apart (axes near perpendicular) give the neighbour's wrist as A's
    conf[:, 0, L_WRIST] = 0.0
    for v in wrong:
        uv[v, 0, L_WRIST], conf[v, 0, L_WRIST] = uv[v, 1, L_WRIST], 0.9
    right = [v for v in range(16) if v not in wrong][:right_views]
    conf[right, 0, L_WRIST] = 0.9
    kp = np.concatenate([uv, conf[..., None]], axis=-1)[None]  # (T=1, V, N=2, 19, 3)

    def wrist_error(opts):
        bodies, _ = associate_batch(views, CameraKernel(views), pairs, kp, opts)
        b = bodies[0]
        assert len(b.X_cm) == 2
        who = np.argsort(np.nanmedian(np.linalg.norm(b.X_cm - A, axis=-1), axis=1))  # body 0 = A
        X, c = b.X_cm[who], b.confidence[who]
        others = np.ones((2, 19), bool)
        others[0, L_WRIST] = False
        err = np.linalg.norm(X - truth, axis=-1)
        assert np.all(err[others] < 3.0), err
        assert np.all(c[others] > 0)
        return err[0, L_WRIST], c[0, L_WRIST]

    off = dataclasses.replace(options, joint_check=JointCheckOptions(enabled=False))
    assert wrist_error(off)[0] > 50.0  # the failure: the person's wrist on the neighbour's
    err, c = wrist_error(options)
    assert (np.isnan(err) and c == -1) or err < 5.0


def test_an_extra_joint_hangs_from_its_body():
    """The detector's joints beside joints19 are checked as bones are: a big toe 3 m from its ankle (a synthetic
    crouching person's, which Pose2Sim's kinematics took) is dropped, one 16 cm from it kept; where the ankle is
    missing, a toe needs 3 inlier views (two always agree)."""
    from dome_calib.recon.body_models import JOINTS19
    from dome_calib.recon.people.extras import hangs_from_its_body
    from dome_calib.recon.people.run import PeopleOptions

    body = np.zeros((3, 19, 3))
    body[:, JOINTS19.index("l_ankle")] = [0.0, 90.0, 0.0]
    body[2, JOINTS19.index("l_ankle")] = np.nan
    toe = np.array([[[16.0, 95.0, 0.0]], [[300.0, 95.0, 0.0]], [[16.0, 95.0, 0.0]]])  # (3 bodies, 1 extra joint, 3)
    keep = hangs_from_its_body(toe, np.array([[2], [4], [2]]), body, ["l_big_toe"], PeopleOptions())
    np.testing.assert_array_equal(keep[:, 0], [True, False, False])
    keep = hangs_from_its_body(toe, np.array([[2], [4], [3]]), body, ["l_big_toe"], PeopleOptions())
    np.testing.assert_array_equal(keep[:, 0], [True, False, True])
