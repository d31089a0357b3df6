"""A centre whose flow is lost in a view, re-found from its body part's motion (``PatchOptions.refind_from_body``,
issue 49, branch refind61): on the few-camera rig a limb patch is flown in exactly two cameras, and a centre lost
in one of them ended it. The body over time says where its part goes; the lost points are flown again from there."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from dome_calib.bundle import SyncTable
from dome_calib.recon.patches.motion import bone_carry
from dome_calib.recon.patches.occlusion import PART_RADIUS_CM, BodyPrior
from dome_calib.recon.patches.parts import BONES, nearest_part
from dome_calib.recon.patches.run import assemble, run_cloud
from dome_calib.recon.patches.seed import Seeds
from dome_calib.recon.patches.track import Clock, body_prediction, refind_from_body
from dome_calib.recon.project import ViewSet

from .patches_helpers import uncarried

PX_PER_CM = 2.0  # f 200 px at 100 cm
DEPTH_CM = 100.0
FAST_PX_MS = np.array([0.45, -0.3])  # 18 / 12 px per 40 ms frame: beyond a 15 px window without a pyramid
BASELINE_CM = 20.0  # camera b sits this far along x from camera a: its image is a's moved 40 px left
SEED_MS = 200.0
R_FOREARM = [name for name, _, _ in BONES].index("r_forearm")


def _views() -> ViewSet:
    return ViewSet(names=["a", "b"], R=np.stack([np.eye(3)] * 2), t_cm=np.array([[0.0, 0, DEPTH_CM], [-BASELINE_CM, 0, DEPTH_CM]]),
                   intr=np.array([[200.0, 200.0, 160.0, 120.0]] * 2), dist=np.zeros((2, 5)),
                   resolution=np.array([[320, 240]] * 2))


class PlaneScene:
    """A textured plane at z = 0, 100 cm in front of both cameras (at z = -100) and facing them, translating at FAST_PX_MS (in camera a's pixels) from
    the seed time on; frame k of every camera is at 40 k ms."""

    def __init__(self):
        rng = np.random.default_rng(0)
        base = cv2.GaussianBlur(rng.uniform(0, 255, (240, 320)).astype(np.float32), (0, 0), 2.0)
        self.base = cv2.normalize(base, None, 20, 235, cv2.NORM_MINMAX)

    def gray(self, camera: str, frame: int) -> np.ndarray:
        shift = FAST_PX_MS * (40.0 * frame - SEED_MS) + ([0.0, 0.0] if camera == "a" else
                                                          [-BASELINE_CM * PX_PER_CM, 0.0])
        M = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]], np.float32)
        return cv2.warpAffine(self.base, M, (320, 240), flags=cv2.INTER_CUBIC,
                              borderMode=cv2.BORDER_REFLECT).astype(np.uint8)


def _plane_point(t_ms: float, X: np.ndarray) -> np.ndarray:
    """Where the plane carries world points ``X`` (..., 3) at the seed time by ``t_ms``."""
    move = np.append(FAST_PX_MS / PX_PER_CM, 0.0) * (t_ms - SEED_MS)
    return np.asarray(X, float) + move


def _body(times_ms: np.ndarray) -> BodyPrior:
    """One person whose right forearm lies behind the plane's patch, its capsule's surface through it (5 cm), and
    moves with the plane; the rest of the body unknown."""
    J = np.full((len(times_ms), 1, 19, 3), np.nan)
    elbow, wrist = np.array([-15.0, 0.0, 5.0]), np.array([15.0, 0.0, 5.0])
    for k, t in enumerate(times_ms):
        J[k, 0, 10], J[k, 0, 11] = _plane_point(t, elbow), _plane_point(t, wrist)
    return BodyPrior(times_ms=np.asarray(times_ms, float), joints_cm=J)


def _patch() -> np.ndarray:
    """(1, 3, 3) centre and plane points, its normal (towards -z) facing the cameras."""
    c = np.array([0.0, 0.0, 0.0])
    return np.array([[c, c + [0.0, 3.0, 0.0], c + [3.0, 0.0, 0.0]]])


def test_nearest_part_is_the_capsule_whose_surface_is_nearest():
    J = np.full((2, 19, 3), np.nan)
    J[0, 10], J[0, 11] = [0.0, 0.0, 0.0], [30.0, 0.0, 0.0]  # person 0: a right forearm along x
    J[1, 3], J[1, 4] = [0.0, 50.0, 0.0], [0.0, 80.0, 0.0]  # person 1: a left upper arm along y
    X = np.array([[10.0, 5.0, 0.0], [10.0, 0.0, 7.0], [0.0, 60.0, 5.0], [10.0, 30.0, 0.0], [np.nan, 0.0, 0.0]])
    person, bone = nearest_part(X, J, PART_RADIUS_CM, 3.0)
    assert person.tolist() == [0, 0, 1, -1, -1]
    assert bone.tolist() == [R_FOREARM, R_FOREARM, [n for n, _, _ in BONES].index("l_upper_arm"), -1, -1]
    assert nearest_part(X, J[:0], PART_RADIUS_CM, 3.0)[0].tolist() == [-1] * 5  # nobody: no part


def test_bone_carry_keeps_a_points_place_on_its_bone():
    A0, B0 = np.array([[0.0, 0.0, 0.0]]), np.array([[10.0, 0.0, 0.0]])
    X = np.array([[[4.0, 5.0, 0.0], [10.0, 0.0, 5.0], [12.0, 0.0, 0.0]]])
    # a translation carries every point with it
    got = bone_carry(X, A0, B0, A0 + [1.0, 2.0, 3.0], B0 + [1.0, 2.0, 3.0])
    assert np.allclose(got, X + [1.0, 2.0, 3.0])
    # the bone turned 90 deg about z at A: a rigid turn of the points about A (past the end: clamped, kept)
    got = bone_carry(X, A0, B0, A0, np.array([[0.0, 10.0, 0.0]]))
    assert np.allclose(got, [[[-5.0, 4.0, 0.0], [0.0, 10.0, 5.0], [0.0, 12.0, 0.0]]])
    assert np.isnan(bone_carry(X, A0, A0, A0, B0)).all()  # no bone length: no motion


def test_body_prediction_carries_the_patch_with_its_part():
    times = np.array([SEED_MS, SEED_MS + 40.0])
    body = _body(times)
    got = body_prediction(_patch(), body.at(times[0]), body.at(times[1]), uncarried())
    assert np.allclose(got, _plane_point(times[1], _patch()))
    far = _patch() + [0.0, 0.0, -20.0]  # 20 cm off every capsule: no part, no prediction
    assert np.isnan(body_prediction(far, body.at(times[0]), body.at(times[1]), uncarried())).all()


def test_a_lost_centre_is_flown_again_from_the_bodys_prediction():
    views, source = _views(), PlaneScene()
    clock = Clock(table=SyncTable(index=np.arange(40), univ_time_ms=np.arange(40) * 40.0), frames=np.arange(40))
    t0, t1 = SEED_MS, SEED_MS + 40.0
    o = uncarried(lk_levels=0, lk_levels_predicted=0)  # no pyramid: an 18 px motion is beyond a standing start
    X = _patch()
    p = X[..., :2] / DEPTH_CM * 200.0 + [160.0, 120.0]  # camera a's pixels (1, 3, 2)
    true = p + FAST_PX_MS * (t1 - t0)
    lost = np.zeros((1, 3), bool)
    X_pred = _plane_point(t1, X)
    q, ok, found = refind_from_body(source, views, 0, clock, t0, t1, X, X_pred, p, p.copy(), lost, np.ones(1, bool), o)
    assert ok.all() and found.all() and np.abs(q - true).max() < 0.05
    # not asked (a view to spare), no prediction, or the centre tracked: left as it was
    for need, pred, ok0 in ((np.zeros(1, bool), X_pred, lost), (np.ones(1, bool), X_pred * np.nan, lost),
                            (np.ones(1, bool), X_pred, np.array([[True, False, False]]))):
        _, ok, found = refind_from_body(source, views, 0, clock, t0, t1, X, pred, p, p.copy(), ok0, need, o)
        assert not found.any() and np.array_equal(ok, ok0)


def test_a_two_view_patch_lost_by_its_flow_lives_on_with_its_parts_motion():
    views, source = _views(), PlaneScene()
    clocks = [Clock(table=SyncTable(index=np.arange(40), univ_time_ms=np.arange(40) * 40.0), frames=np.arange(40))] * 2
    times = SEED_MS + 40.0 * np.arange(4)
    seeds = Seeds(X_cm=_patch(), normal=np.array([[0.0, 0.0, -1.0]]), seen=np.ones((1, 2), bool))
    o = uncarried(lk_levels=0, lk_levels_predicted=0, refine_normals=False)
    body = _body(times)
    _, before = run_cloud(source, views, clocks, SEED_MS, times, seeds, o, body=body)
    assert before.alive[0].tolist() == [True, False, False, False]  # the standing start loses it in both views
    on = dataclasses.replace(o, refind_from_body=True)
    _, after = run_cloud(source, views, clocks, SEED_MS, times, seeds, on, body=body)
    assert after.alive[0].all()
    assert np.abs(after.X_cm[0] - _plane_point(times[:, None, None], _patch()[0])).max() < 0.3
    # without the people the option changes nothing
    _, alone = run_cloud(source, views, clocks, SEED_MS, times, seeds, on)
    assert np.array_equal(alone.X_cm, before.X_cm, equal_nan=True) and np.array_equal(alone.alive, before.alive)


class HiddenFrame(PlaneScene):
    """The plane scene with camera b's view of the patch covered by a flat grey square in frame ``hidden``."""

    def __init__(self, hidden: int):
        super().__init__()
        self.hidden = hidden

    def gray(self, camera: str, frame: int) -> np.ndarray:
        img = super().gray(camera, frame)
        if camera == "b" and frame == self.hidden:
            u, v = (np.array([160.0 - BASELINE_CM * PX_PER_CM, 120.0]) + FAST_PX_MS * (40.0 * frame - SEED_MS)
                    ).astype(int)
            img[v - 20:v + 20, u - 20:u + 20] = 128
        return img


def test_a_patch_lost_in_a_view_for_two_steps_is_carried_by_its_part_and_found_again():
    clocks = [Clock(table=SyncTable(index=np.arange(40), univ_time_ms=np.arange(40) * 40.0), frames=np.arange(40))] * 2
    times = SEED_MS + 40.0 * np.arange(6)  # frames 5..10; camera b's frame 7 hides the patch
    seeds = Seeds(X_cm=_patch(), normal=np.array([[0.0, 0.0, -1.0]]), seen=np.ones((1, 2), bool))
    o = uncarried(refine_normals=False, refind_from_body=True)
    source, views, body = HiddenFrame(7), _views(), _body(times)
    _, ends = run_cloud(source, views, clocks, SEED_MS, times, seeds, o, body=body)
    assert ends.alive[0].tolist() == [True, True, False, False, False, False]
    assert not ends.carried.any()
    # carried at frame 7 (lost in b) and 8 (flown in b from the hidden frame): predicted, nothing written there
    _, kept = run_cloud(source, views, clocks, SEED_MS, times, seeds, dataclasses.replace(o, refind_carry_steps=2),
                        body=body)
    assert kept.alive[0].tolist() == [True, True, False, False, True, True]
    assert kept.carried[0].tolist() == [False, False, True, True, False, False]
    assert np.isnan(kept.X_cm[0, 2:4]).all() and not kept.visible[0, 2:4].any()
    assert np.abs(kept.X_cm[0, 4:] - _plane_point(times[4:, None, None], _patch()[0])).max() < 0.3
    assert np.array_equal(kept.X_cm[0, :2], ends.X_cm[0, :2])  # the same bits before
    # one step allowed: the second loss ends it
    _, once = run_cloud(source, views, clocks, SEED_MS, times, seeds, dataclasses.replace(o, refind_carry_steps=1),
                        body=body)
    assert once.alive[0].tolist() == [True, True, False, False, False, False]
    assert once.carried[0].tolist() == [False, False, True, False, False, False]


def test_the_options_off_or_no_people_give_the_same_bits_and_any_subset_tracks_as_the_whole():
    clocks = [Clock(table=SyncTable(index=np.arange(40), univ_time_ms=np.arange(40) * 40.0), frames=np.arange(40))] * 2
    times = SEED_MS + 40.0 * np.arange(6)
    source, views, body = HiddenFrame(7), _views(), _body(times)
    off = uncarried(refine_normals=False)
    X = np.concatenate([_patch(), _patch() + [-12.0, 10.0, 0.0]])  # the second 10 cm off the forearm: no part
    seeds = Seeds(X_cm=X, normal=np.array([[0.0, 0.0, -1.0]] * 2), seen=np.ones((2, 2), bool))
    _, plain = run_cloud(source, views, clocks, SEED_MS, times, seeds, off)
    _, given = run_cloud(source, views, clocks, SEED_MS, times, seeds, off, body=body)
    assert np.array_equal(plain.X_cm, given.X_cm, equal_nan=True) and np.array_equal(plain.visible, given.visible)
    assert not given.carried.any()
    on = dataclasses.replace(off, refind_from_body=True, refind_carry_steps=2)
    _, whole = run_cloud(source, views, clocks, SEED_MS, times, seeds, on, body=body)
    assert whole.carried[0].any() and not whole.carried[1].any()
    for n in range(2):
        one = Seeds(X_cm=X[n:n + 1], normal=seeds.normal[n:n + 1], seen=seeds.seen[n:n + 1])
        _, alone = run_cloud(source, views, clocks, SEED_MS, times, one, on, body=body)
        assert np.array_equal(alone.X_cm[0], whole.X_cm[n], equal_nan=True)
        assert np.array_equal(alone.carried[0], whole.carried[n]) and np.array_equal(alone.alive[0], whole.alive[n])


def test_the_stream_keeps_the_carried_flag_where_nothing_is_written():
    clocks = [Clock(table=SyncTable(index=np.arange(40), univ_time_ms=np.arange(40) * 40.0), frames=np.arange(40))] * 2
    times = SEED_MS + 40.0 * np.arange(-2, 6)  # frames 3..10, the seed at frame 5
    seeds = Seeds(X_cm=_patch(), normal=np.array([[0.0, 0.0, -1.0]]), seen=np.ones((1, 2), bool))
    o = uncarried(refine_normals=False, refind_from_body=True, refind_carry_steps=2)
    back, fwd = run_cloud(HiddenFrame(7), _views(), clocks, SEED_MS, times, seeds, o, body=_body(times))
    traj = assemble([(0, SEED_MS, np.arange(3, 11), back, fwd)], times, ["a", "b"])
    assert traj.carried[0].tolist() == [False, False, False, False, True, True, False, False]
    assert traj.alive[0].tolist() == [True, True, True, True, False, False, True, True]
    assert np.isnan(traj.X_cm[0, 4:6]).all() and not traj.visible[0, 4:6].any()
