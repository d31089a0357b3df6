"""A joint's cap left out of a limb's labels (PartOptions.joint_cap_cm) and a hidden limb's prior taken from the
body fitted with the patches (stage.body_prior(hidden_from=))."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from dome_calib.recon.patches.parts import BONES, PartLabels, PartOptions, label_parts, leave_joint_caps

#: One person standing, arms hanging (joints19, world cm, y up).
_JOINTS = {0: (0, 150, 0), 1: (0, 160, 5), 2: (0, 100, 0), 3: (20, 145, 0), 4: (22, 115, 0), 5: (22, 90, 0),
           6: (10, 100, 0), 7: (10, 55, 0), 8: (10, 10, 0), 9: (-20, 145, 0), 10: (-22, 115, 0), 11: (-22, 90, 0),
           12: (-10, 100, 0), 13: (-10, 55, 0), 14: (-10, 10, 0), 15: (3, 162, 4), 16: (7, 160, 0),
           17: (-3, 162, 4), 18: (-7, 160, 0)}


def _scene(T=8):
    """Patches on one still person: 6 on the left shoulder's cap (6 cm out of the joint, up and out, where the
    closest point of both the shoulders' bone and the left upper arm's is the joint) and 6 along the left upper
    arm's outer side (6 cm out of the bone, between its ends: the arm's measured radius, which the cap's patches
    match, so the thickness pass gives them the arm, as the few-camera rig's seed 3 did)."""
    J = np.array([_JOINTS[j] for j in range(19)], float)
    shoulder, elbow = J[3], J[4]
    caps = [shoulder + 6.0 * np.array([np.cos(a), np.sin(a), 0.3 * (i - 2.5)]) / np.linalg.norm(
        [np.cos(a), np.sin(a), 0.3 * (i - 2.5)]) for i, a in enumerate(np.linspace(0.5, 1.1, 6))]
    axis = (elbow - shoulder) / np.linalg.norm(elbow - shoulder)
    out = np.cross(axis, [0.0, 0.0, 1.0])
    out *= np.sign(out[0])
    arm = [shoulder + s * (elbow - shoulder) + 6.0 * out + np.array([0, 0, z]) for s, z in
           zip(np.linspace(0.3, 0.8, 6), np.linspace(-1, 1, 6))]
    P = np.array(caps + arm)
    normal = np.array([(p - shoulder) / np.linalg.norm(p - shoulder) for p in caps] + [out] * len(arm))
    X = np.repeat(P[:, None], T, 1)
    nrm = np.repeat(normal[:, None], T, 1)
    return X, nrm, np.ones(X.shape[:2], bool), np.repeat(J[None, None], T, 0)


def test_a_patch_on_a_joints_cap_is_kept_out_of_the_limbs_motion():
    X, normal, alive, joints = _scene()
    off = label_parts(X, normal, alive, joints, PartOptions(crease_cm=0.0, joint_cap_cm=0.0))
    arm = [b[0] for b in BONES].index("l_upper_arm")
    assert (off.bone == arm).all()  # the old rule: the cap's patches given to the arm
    on = label_parts(X, normal, alive, joints, PartOptions(crease_cm=0.0, joint_cap_cm=5.0))
    assert (on.bone[:6] == -1).all() and (on.person[:6] == -1).all() and np.isnan(on.cost[:6]).all()
    assert np.array_equal(on.bone[6:], off.bone[6:])  # the arm's own patches keep their label
    assert PartOptions().joint_cap_cm == 5.0  # the default since merge63: what reconstruct labels with
    dflt = label_parts(X, normal, alive, joints, PartOptions(crease_cm=0.0))
    assert np.array_equal(dflt.bone, on.bone) and np.array_equal(dflt.cost, on.cost, equal_nan=True)


def test_the_cap_rule_needs_both_the_joint_and_the_neighbour_as_near():
    """A patch labelled the left upper arm (bone 4) with its foot 2 cm from the shoulder: on the cap only where the
    shoulders' bone (2) is as near as its own (within joint_cap_near_cm); 8 cm down the bone it is not, whatever the
    distances; a bone the labelled one does not meet (the torso, 0) is no neighbour, nor is the forearm (6) at the
    elbow (a limb's joint, not the trunk's); a patch labelled the shoulders (the trunk) on the cap keeps its label."""
    N, P, K = 5, 1, len(BONES)
    dist = np.full((N, P, K), 20.0)
    dist[:, 0, 4] = 5.0
    dist[0, 0, 2] = 5.3  # as near: cap
    dist[1, 0, 2] = 6.0  # 1 cm farther: not
    dist[2, 0, 2] = 5.0  # as near but its foot is far from the joint: not
    dist[3, 0, 0] = 5.0  # as near the torso's bone, which does not meet the upper arm: not
    dist[4, 0, 6] = 5.0  # as near the forearm's bone at the elbow: not
    foot = np.full((N, P, K, 2), 15.0)
    foot[:, 0, 4] = [2.0, 28.0]
    foot[2, 0, 4] = [8.0, 22.0]
    foot[4, 0, 4] = [28.0, 2.0]
    labels = PartLabels(person=np.zeros(N, np.int64), bone=np.full(N, 4), cost=np.ones(N))
    out = leave_joint_caps(labels, dist, foot, cap_cm=6.0, near_cm=0.5)
    assert out.bone.tolist() == [-1, 4, 4, 4, 4]
    dist[0, 0, 4], foot[0, 0, 2] = 5.3, [0.0, 40.0]  # labelled the shoulders, the arm as near: kept
    shoulders = PartLabels(person=np.zeros(N, np.int64), bone=np.full(N, 2), cost=np.ones(N))
    assert leave_joint_caps(shoulders, dist, foot, cap_cm=6.0, near_cm=0.5).bone[0] == 2


def test_a_hidden_joint_is_taken_from_the_body_fitted_with_the_patches():
    """body_prior(hidden_from=): a joint no detection saw is the refitted body's where it puts it out (else carried
    by its parent as before); the seen joints are the detections' body's, bit for bit; without it, the old prior."""
    from dome_calib.recon.patches.stage import body_prior

    J = np.array([_JOINTS[j] for j in range(19)], float)
    times = np.array([0.0, 40.0, 80.0])
    seen = np.ones((3, 19), int)
    seen[1, 5] = 0  # the left wrist hidden at the middle time
    alone = [SimpleNamespace(ids=np.array([7]), X_cm=(J + 2.0 * k)[None], n_inliers=seen[k][None]) for k in range(3)]
    moved = J.copy()
    moved[5] += [0.0, 10.0, 0.0]  # where the patches carried the wrist
    refit = [SimpleNamespace(ids=np.array([7]), X_cm=(moved + 2.0 * k)[None]) for k in range(3)]
    old = body_prior(times, alone, times).joints_cm
    new = body_prior(times, alone, times, hidden_from=refit).joints_cm
    assert np.allclose(new[1, 0, 5], moved[5] + 2.0, atol=1e-9)
    assert not np.allclose(old[1, 0, 5], new[1, 0, 5], atol=1.0)
    keep = np.ones((3, 19), bool)
    keep[1, 5] = False
    assert np.array_equal(new[:, 0][keep], old[:, 0][keep])
    # the refitted body without the joint: carried by its parent, as without it
    gone = [SimpleNamespace(ids=b.ids, X_cm=np.where(np.arange(19)[None, :, None] == 5, np.nan, b.X_cm))
            for b in refit]
    assert np.array_equal(body_prior(times, alone, times, hidden_from=gone).joints_cm, old, equal_nan=True)


def test_the_second_stream_replaces_only_the_clouds_whose_prior_changed():
    """reseed_hidden's second stream (stage.reseed_clouds): a cloud whose seed time's prior the fitted people changed
    is streamed again, alone, and put in its place (its ids those of its cloud); the others are the first's."""
    from dome_calib.recon.patches.model import PatchTrajectories
    from dome_calib.recon.patches.occlusion import BodyPrior
    from dome_calib.recon.patches.stage import reseed_clouds

    T, V = 5, 2

    def stream(clouds, n, value):
        ids = np.concatenate([c * 100000 + np.arange(n) for c in range(len(clouds))])
        N = len(ids)
        return PatchTrajectories(ids=ids, seed_time_ms=np.repeat(np.asarray(clouds, float) * 40.0, n),
                                 times_ms=np.arange(T) * 40.0, cameras=["a", "b"],
                                 X_cm=np.full((N, T, 3, 3), value), normal=np.zeros((N, T, 3)),
                                 visible=np.ones((N, T, V), bool), photometric=np.ones((N, T, V), bool),
                                 alive=np.ones((N, T), bool), carried=np.zeros((N, T), bool))

    first = stream([0, 2, 4], 3, 1.0)
    J = np.zeros((T, 1, 19, 3))
    moved = J.copy()
    moved[2, 0, 5] = 10.0  # the fitted people move a hidden wrist at time 80 ms (cloud 1, frame 2)
    asked = []

    def again(frames):
        asked.append(frames)
        return stream(frames, 4, 2.0)

    held, fitted = BodyPrior(np.arange(T) * 40.0, J), BodyPrior(np.arange(T) * 40.0, moved)
    out = reseed_clouds(first, np.array([0, 2, 4]), np.array([0.0, 80.0, 160.0]), held, fitted, again)
    assert asked == [[2]]
    assert out.ids.tolist() == [0, 1, 2, 100000, 100001, 100002, 100003, 200000, 200001, 200002]
    assert (out.X_cm[3:7] == 2.0).all() and (out.X_cm[:3] == 1.0).all() and (out.X_cm[7:] == 1.0).all()
    assert (out.seed_time_ms[3:7] == 80.0).all()  # the new cloud's own seed time (frame 2)
    # nothing changed, or no prior: the first stream itself, nothing streamed
    assert reseed_clouds(first, np.array([0, 2, 4]), np.array([0.0, 80.0, 160.0]), held, held, again) is first
    assert reseed_clouds(first, np.array([0, 2, 4]), np.array([0.0, 80.0, 160.0]), None, fitted, again) is first
    assert asked == [[2]]
