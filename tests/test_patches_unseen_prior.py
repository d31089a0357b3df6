"""The patches' body prior rests on what the detector saw (dome_calib.recon.patches.occlusion.hold_unseen_parts,
stage.body_prior): a joint the body over time put out through an occluded span, where no detection saw it, or left
out there, is carried by its parent with the offset of the times it was seen on either side, so a skeleton seed's capsule (its
initial depth and normal) and an occluder sit where the limb is, not where the smoothness prior guessed it. Seen
joints are kept bit for bit. Before, the prior took the unseen joints as the body over time gave them (a part left out had no capsule)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from dome_calib.recon.body_models import JOINTS19
from dome_calib.recon.patches.occlusion import hold_unseen_parts
from dome_calib.recon.patches.stage import body_prior

HIP, KNEE, ANKLE = (JOINTS19.index(j) for j in ("l_hip", "l_knee", "l_ankle"))
T = 11
TIMES = 40.0 * np.arange(T)


def _walker() -> np.ndarray:
    """(T, 1, 19, 3) a person moving along x (40 cm per time), every joint at a fixed offset from the
    neck, the left shin swinging: the knee-to-ankle offset turns by 4 deg per time."""
    base = np.zeros((19, 3))
    base[:, 1] = np.arange(19) * 5.0 + 10.0  # distinct joints below the neck
    base[0] = 0.0
    J = np.repeat(base[None, None], T, 0).astype(float)
    J[..., 0] += TIMES[:, None, None]
    J[:, 0, HIP] = J[:, 0, 0] + [10.0, 90.0, 0.0]
    J[:, 0, KNEE] = J[:, 0, HIP] + [0.0, 45.0, 0.0]
    a = np.radians(4.0 * np.arange(T))
    J[:, 0, ANKLE] = J[:, 0, KNEE] + 45.0 * np.stack([np.sin(a), np.cos(a), np.zeros(T)], 1)
    return J


def test_unseen_joints_are_carried_by_their_parent_from_the_seen_times():
    truth = _walker()
    est = truth.copy()
    seen = np.ones((T, 1, 19), bool)
    seen[3:8, 0, [KNEE, ANKLE]] = False  # the occluded span
    est[3:8, 0, KNEE] += [0.0, -8.0, 12.0]  # the smoothness prior's guess: centimetres off
    est[3:8, 0, ANKLE] += [6.0, -10.0, 15.0]
    held = hold_unseen_parts(TIMES, est, seen)
    assert np.array_equal(held[seen], est[seen])  # what the detector saw is kept bit for bit
    # the knee's offset from the hip is the same on both sides: exactly the truth; the ankle's turns, linear between
    assert np.allclose(held[3:8, 0, KNEE], truth[3:8, 0, KNEE])
    err_ankle = np.linalg.norm(held[3:8, 0, ANKLE] - truth[3:8, 0, ANKLE], axis=-1)
    assert err_ankle.max() < 1.0 < np.linalg.norm(est[3:8, 0, ANKLE] - truth[3:8, 0, ANKLE], axis=-1).min()
    # left out by the body over time (NaN through the span): the part is there again
    gap = est.copy()
    gap[4:7, 0, [KNEE, ANKLE]] = np.nan
    filled = hold_unseen_parts(TIMES, gap, seen)
    assert np.allclose(filled[3:8, 0, KNEE], truth[3:8, 0, KNEE])
    assert np.allclose(filled[4:7, 0, ANKLE], held[4:7, 0, ANKLE])
    # seen on one side only: that side's offset; never seen with its parent, or no parent: left as it is
    seen_end = seen.copy()
    seen_end[3:, 0, [KNEE, ANKLE]] = False
    assert np.allclose(hold_unseen_parts(TIMES, est, seen_end)[3:8, 0, KNEE], truth[3:8, 0, KNEE])
    never = np.ones((T, 1, 19), bool)
    never[:, 0, ANKLE] = False
    assert np.array_equal(hold_unseen_parts(TIMES, est, never), est)
    gone, unseen_centre = est.copy(), seen.copy()
    gone[5, 0, HIP] = np.nan  # a missing hip is carried by the body centre, unless that was never seen
    assert np.allclose(hold_unseen_parts(TIMES, gone, seen)[5, 0, [HIP, KNEE]], truth[5, 0, [HIP, KNEE]])
    unseen_centre[:, 0, JOINTS19.index("body_center")] = False
    out = hold_unseen_parts(TIMES, gone, unseen_centre)
    assert np.isnan(out[5, 0, HIP]).all() and np.array_equal(out[5, 0, KNEE], gone[5, 0, KNEE])


def test_the_stage_s_prior_holds_the_joints_no_detection_saw():
    truth = _walker()
    est = truth.copy()
    est[3:8, 0, KNEE] += [0.0, -8.0, 12.0]
    n_inl = np.full((T, 1, 19), 4)
    n_inl[3:8, 0, KNEE] = 0  # put out by the body over time, no inlier: unseen
    bodies = [SimpleNamespace(ids=np.array([7]), X_cm=est[k], n_inliers=n_inl[k]) for k in range(T)]
    prior = body_prior(TIMES, bodies, TIMES)
    assert np.allclose(prior.joints_cm[3:8, 0, KNEE], truth[3:8, 0, KNEE])
    assert np.array_equal(np.delete(prior.joints_cm, KNEE, axis=2), np.delete(est, KNEE, axis=2))
    # the body over time left the knee out (NaN): the prior has it, and so the thigh's and shin's capsules
    out = [SimpleNamespace(ids=b.ids, X_cm=np.where((np.arange(19) == KNEE)[:, None], np.nan, b.X_cm)
                           if 3 <= k < 8 else b.X_cm, n_inliers=b.n_inliers) for k, b in enumerate(bodies)]
    assert np.allclose(body_prior(TIMES, out, TIMES).joints_cm[3:8, 0, KNEE], truth[3:8, 0, KNEE])
    # between the people's times a joint is seen where both times around it saw it (the stage's reference times)
    mid = body_prior(TIMES, bodies, TIMES[:-1] + 20.0)
    assert np.allclose(mid.joints_cm[:, 0, KNEE], 0.5 * (truth[:-1, 0, KNEE] + truth[1:, 0, KNEE]))
    # bodies without n_inliers: every joint seen, the people as they are
    plain = [SimpleNamespace(ids=b.ids, X_cm=b.X_cm) for b in bodies]
    assert np.array_equal(body_prior(TIMES, plain, TIMES).joints_cm, est)
