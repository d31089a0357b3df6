"""The flow started where the patch is going (``PatchOptions.lk_predict``): a point moving at constant velocity is
started at its predicted pixel and followed there with a shallower pyramid than its motion needs from a standing
start (the backward check's start: tests/test_patches_fb.py); without a velocity (a patch's
first step from its seed) the tracks are the ones without the option, bit for bit; from the second step the
stated pyramid levels are used; and any part of a cloud is tracked bit for bit as in the whole."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from dome_calib.bundle import SyncTable
from dome_calib.recon.patches import seed as seed_mod
from dome_calib.recon.patches import track as track_mod
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import clocks_of, imaged_views, run_cloud
from dome_calib.recon.patches.seed import Seeds, seed_patches
from dome_calib.recon.patches.track import Clock, CloudTrack, flow_camera
from dome_calib.synth.textured import TexturedScene, TextureOptions

from .patches_helpers import one_person_capture
from .test_patches import MovingTexture

FAST_PX_MS = np.array([0.45, -0.3])  # 18 / 12 px per 40 ms frame: beyond a 15 px window without a pyramid
P0 = np.array([[150.0, 110.0], [170.3, 130.6], [140.8, 95.2], [120.2, 140.7]])


class FastTexture(MovingTexture):
    """The smooth random texture translating at FAST_PX_MS."""

    def gray(self, camera: str, frame: int) -> np.ndarray:
        shift = FAST_PX_MS * self.clock.table.time_of(frame)
        M = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]], np.float32)
        return cv2.warpAffine(self.base, M, (320, 240), flags=cv2.INTER_CUBIC).astype(np.uint8)


def _clock() -> Clock:
    index = np.arange(0, 40)
    return Clock(table=SyncTable(index=index, univ_time_ms=index * 40.0), frames=index)


def test_a_point_at_constant_velocity_starts_at_its_predicted_pixel_and_lands_there(monkeypatch):
    clock = _clock()
    source = FastTexture(clock)
    t0, t1 = 200.0, 240.0
    start = P0 + FAST_PX_MS * t0
    o = PatchOptions(lk_predict=True, lk_levels_predicted=0)
    calls = []
    real = seed_mod.cv2.calcOpticalFlowPyrLK

    def recording(prev, nxt, pts, guess, **kw):
        calls.append((np.array(pts).reshape(-1, 2), None if guess is None else np.array(guess).reshape(-1, 2),
                      kw["maxLevel"]))
        return real(prev, nxt, pts, guess, **kw)

    monkeypatch.setattr(seed_mod.cv2, "calcOpticalFlowPyrLK", recording)
    q, ok = flow_camera(source, "c", clock, t0, t1, start, o, predict=lambda t: P0 + FAST_PX_MS * t)
    assert ok.all() and np.abs(q - (P0 + FAST_PX_MS * t1)).max() < 0.05
    (fwd_pts, fwd_guess, fwd_levels), (back_pts, back_start, back_levels) = calls[:2]
    assert fwd_levels == back_levels == 0
    assert np.allclose(fwd_guess, P0 + FAST_PX_MS * t1, atol=1e-3)  # the forward flow starts at the predicted pixel
    # the default check's backward flow starts at the answer it must find (lk_fb_strict: tests/test_patches_fb.py)
    assert np.allclose(back_start, fwd_pts, atol=1e-3)
    # without the prediction, the same pyramid (none) does not follow the motion
    calls.clear()
    q0, ok0 = flow_camera(source, "c", clock, t0, t1, start, o)
    assert calls[0][2] == 3  # no prediction: lk_levels
    flat = PatchOptions(lk_levels=0, lk_predict=False)
    q0, ok0 = flow_camera(source, "c", clock, t0, t1, start, flat)
    assert not np.any(ok0 & (np.linalg.norm(q0 - (P0 + FAST_PX_MS * t1), axis=1) < 0.05))


def test_predicted_motion_chooses_each_points_levels():
    o = PatchOptions(lk_predict=True, lk_levels=3, lk_levels_predicted=1, lk_levels_full_px=4.0)
    v = np.array([[0.0, 0.0], [0.05, 0.0], [0.0, -0.1], [np.nan, 0.0]])  # px / ms: 0, 2, 4 px per 40 ms; unknown
    shift, levels = track_mod.predicted_motion(lambda t: np.zeros((4, 2)) + v * t, 40.0, 80.0, o)
    assert np.allclose(shift, [[0, 0], [2, 0], [0, -4], [0, 0]])
    assert list(levels) == [1, 1, 3, 1]
    _, levels = track_mod.predicted_motion(lambda t: v * t, 40.0, 80.0,
                                           PatchOptions(lk_predict=True, lk_levels_predicted=2))
    assert list(levels) == [2, 2, 2, 2]  # lk_levels_full_px 0: no per-point test


@pytest.fixture(scope="module")
def cloud():
    """5 VGA of the tiny dome, one person; a cloud seeded at VGA frame 120 (seeds computed once: the tests track)."""
    bundle, truth = one_person_capture()
    scene = TexturedScene(bundle, truth, TextureOptions())
    cams = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"][:5]
    views = imaged_views(scene, cams)
    seeds = seed_patches(scene, views, {n: 120 for n in cams}, BASE)
    table = bundle.sync.streams["vga"]
    return scene, views, clocks_of(bundle, scene, cams), table.time_of(120), table.times_of(np.arange(118, 123)), seeds


BASE = PatchOptions(seed_features=40, seed_neighbours=3, seed_views=4, lk_predict=False, anchor_flow=False)  # the tracking flow's calls only
PREDICTED = dataclasses.replace(BASE, lk_predict=True, lk_levels_predicted=1, lk_levels_full_px=0.6)


@pytest.fixture(scope="module")
def predicted(cloud):
    """The cloud tracked 2 frames each way with the prediction, and the tracker's optical-flow calls."""
    scene, views, clocks, t_seed, times, seeds = cloud
    got = []
    real = track_mod.optical_flow

    def recording(src, dst, p0, o, guess=None, levels=None, predicted=False):
        got.append((levels, guess is not None, predicted))
        return real(src, dst, p0, o, guess=guess, levels=levels, predicted=predicted)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(track_mod, "optical_flow", recording)
        tracks = run_cloud(scene, views, clocks, t_seed, times, seeds, PREDICTED)
    return tracks, got


def _same_tracks(a, b) -> None:
    assert np.array_equal(a.X_cm, b.X_cm, equal_nan=True)
    assert np.array_equal(a.visible, b.visible) and np.array_equal(a.alive, b.alive)
    assert np.array_equal(a.photometric, b.photometric)


def test_the_first_step_from_the_seed_is_the_flow_without_a_prediction(cloud):
    scene, views, clocks, t_seed, times, seeds = cloud
    one = [run_cloud(scene, views, clocks, t_seed, times[1:4], seeds, o) for o in (BASE, PREDICTED)]
    for a, b in zip(*one):
        _same_tracks(a, b)  # one step each way: no velocity yet, the old flow bit for bit
        assert a.alive[:, -1].sum() > 20


def test_later_steps_use_the_stated_levels(predicted):
    tracks, got = predicted
    # first steps (each way): the old call (lk_levels); second steps: predicted, lk_levels_predicted (1), or
    # lk_levels (3) where the predicted motion in the frame step is at least lk_levels_full_px
    assert set(got) == {(None, False, False), (1, True, True), (3, True, True)}
    assert all(t.alive[:, -1].sum() > 20 for t in tracks)


def test_any_part_of_a_cloud_is_tracked_bit_for_bit_as_in_the_whole_with_the_prediction(cloud, predicted):
    scene, views, clocks, t_seed, times, seeds = cloud
    part = np.arange(len(seeds.X_cm))[1::3]  # every third patch, as one task would get them
    sub = Seeds(X_cm=seeds.X_cm[part], normal=seeds.normal[part], seen=seeds.seen[part])
    for whole, got in zip(predicted[0], run_cloud(scene, views, clocks, t_seed, times, sub, PREDICTED)):
        _same_tracks(CloudTrack(whole.times_ms, whole.X_cm[part], whole.visible[part], whole.photometric[part],
                                whole.alive[part]), got)
