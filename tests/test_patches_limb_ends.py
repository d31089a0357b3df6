"""Why a patch ended (``CloudTrack.ended``, :data:`~dome_calib.recon.patches.track.END_CAUSES`) and a patch whose
views are lost carried by its body part's motion as one whose centre is lost (``PatchOptions.carry_unseen``; issue
49, branch limb63): on the few-camera rig the limb ends' patches end before an occluded span is bridged, most by
their centre's flow at their first steps (re-found by ``refind_from_body``), then by the MAP cut (too few views),
though two or more cameras truly see them."""
from __future__ import annotations

import dataclasses

import numpy as np

from dome_calib.bundle import SyncTable
from dome_calib.recon.patches.occlusion import BodyPrior
from dome_calib.recon.patches.run import run_cloud
from dome_calib.recon.patches.seed import Seeds
from dome_calib.recon.patches.track import END_CAUSES, Clock, end_causes
from dome_calib.recon.patches.visibility import Visibility

from .patches_helpers import uncarried

from .test_patches_refind_body import BASELINE_CM, DEPTH_CM, SEED_MS, PlaneScene, _body, _patch, _plane_point, _views


def test_each_ended_patch_is_given_the_first_rule_that_ended_it():
    N, V = 7, 3
    o = uncarried()
    lost = np.array([1, 1, 0, 0, 0, 0, 0], bool)
    unseen = np.array([0, 0, 1, 1, 1, 1, 0], bool)
    stretched = np.array([0, 0, 0, 0, 0, 0, 1], bool)
    tracked = np.zeros((N, 3, V), bool)
    tracked[0, 0, :1] = True  # the centre flown in one view: the flow
    tracked[1, 0, :2] = True  # in two, not triangulated
    cand = np.zeros((N, V), bool)
    hidden = np.zeros((N, V), bool)
    cand[2, 0] = True  # one camera in the image and faced: geometry
    cand[3, 0], hidden[3, 1:] = True, True  # the people hide the others
    cand[4:6] = True  # the cut labelled them "not visible"
    motion = np.full((N, V), np.nan)
    motion[4, 1] = np.inf  # one with a failed flow
    vis = Visibility(visible=np.zeros((N, V), bool), photometric=np.zeros((N, V), bool), ncc=np.zeros((N, V)),
                     candidate=cand, reference=np.zeros(N, np.int64), hidden=hidden)
    got = end_causes(lost, unseen, stretched, np.zeros(N, bool), tracked, vis, motion, o)
    assert [END_CAUSES[i] for i in got] == ["flow", "triangulation", "unseen_geometry", "unseen_body",
                                            "unseen_flow", "unseen_photo", "stretched"]


def _occluded_body(times_ms: np.ndarray, hidden_ms: float) -> BodyPrior:
    """test_patches_refind_body's forearm behind the plane's patch, and a second person's forearm across camera b's
    ray to the patch at ``hidden_ms`` alone (2 m off elsewhere): the people hide the patch from b there."""
    one = _body(times_ms)
    J = np.concatenate([one.joints_cm, np.full_like(one.joints_cm, np.nan)], axis=1)
    for k, t in enumerate(times_ms):
        mid = 0.5 * (_plane_point(t, np.zeros(3)) + [BASELINE_CM, 0.0, -DEPTH_CM])  # halfway to b's centre
        off = np.zeros(3) if abs(t - hidden_ms) < 0.5 else np.array([0.0, 200.0, 0.0])
        J[k, 1, 10], J[k, 1, 11] = mid + off + [0.0, -10.0, 0.0], mid + off + [0.0, 10.0, 0.0]
    return BodyPrior(times_ms=np.asarray(times_ms, float), joints_cm=J)


def test_a_patch_the_people_hide_for_a_step_is_carried_and_found_again_with_carry_unseen():
    clocks = [Clock(table=SyncTable(index=np.arange(40), univ_time_ms=np.arange(40) * 40.0), frames=np.arange(40))] * 2
    times = SEED_MS + 40.0 * np.arange(5)  # frames 5..9; the people hide it from b at frame 7
    seeds = Seeds(X_cm=_patch(), normal=np.array([[0.0, 0.0, -1.0]]), seen=np.ones((1, 2), bool))
    o = uncarried(refine_normals=False, refind_from_body=True, refind_carry_steps=2, occluder_margin_cm=0.0)
    body = _occluded_body(times, float(times[2]))
    _, ends = run_cloud(PlaneScene(), _views(), clocks, SEED_MS, times, seeds, o, body=body)
    assert ends.alive[0].tolist() == [True, True, False, False, False]
    assert END_CAUSES[int(ends.ended[0])] == "unseen_body" and not ends.carried.any()
    _, kept = run_cloud(PlaneScene(), _views(), clocks, SEED_MS, times, seeds,
                        dataclasses.replace(o, carry_unseen=True), body=body)
    assert kept.alive[0].tolist() == [True, True, False, True, True] and kept.ended[0] == 0
    assert kept.carried[0].tolist() == [False, False, True, False, False]
    assert np.isnan(kept.X_cm[0, 2]).all() and not kept.visible[0, 2].any()  # predicted: nothing written
    assert np.abs(kept.X_cm[0, 3:] - _plane_point(times[3:, None, None], _patch()[0])).max() < 0.3
    assert np.array_equal(kept.X_cm[0, :2], ends.X_cm[0, :2])
    # without refind_carry_steps the option changes nothing
    _, same = run_cloud(PlaneScene(), _views(), clocks, SEED_MS, times, seeds,
                        dataclasses.replace(o, carry_unseen=True, refind_carry_steps=0), body=body)
    assert np.array_equal(same.X_cm, ends.X_cm, equal_nan=True) and np.array_equal(same.alive, ends.alive)
