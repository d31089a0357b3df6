"""A tracked patch pulled back to its seed appearance (recon.patches.track.SeedViews, ``anchor_flow``): a flown
point that slid by less than the forward-backward check can see is realigned to where its seed appearance is; one
that slid farther is rejected in that camera; cameras without a frame at that very time are left alone; and with
the option any part of a cloud is tracked bit for bit as in the whole (slow)."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.bundle import SyncTable
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import clocks_of, imaged_views, patch_stream, run_cloud
from dome_calib.recon.patches.seed import Seeds, seed_patches
from dome_calib.recon.patches.track import Clock, SeedViews, flow_camera
from dome_calib.recon.patches.visibility import Frames
from dome_calib.synth.textured import TexturedScene, TextureOptions

from .patches_helpers import one_person_capture
from .test_patches import VELOCITY_PX_MS, MovingTexture

P0 = np.array([[150.0, 110.0], [170.3, 130.6], [140.8, 95.2]])  # one patch's three points at frame 0


def _setup(anchor_reject: bool = True):
    index = np.arange(0, 40)
    clock = Clock(table=SyncTable(index=index, univ_time_ms=index * 40.0), frames=index)
    source = MovingTexture(clock)
    seeds = SeedViews(uv=P0.astype(np.float32).reshape(1, 3, 1, 2), frame=np.array([0]), gray={})
    o = PatchOptions(anchor_flow=True, anchor_reject=anchor_reject)
    return clock, source, seeds, o


def _truth(frame: int) -> np.ndarray:
    return P0 + VELOCITY_PX_MS * frame * 40.0


def test_a_point_slid_below_the_flow_checks_is_pulled_back_to_its_seed_appearance():
    clock, source, seeds, o = _setup()
    # the flow itself passes its forward-backward check with a slide of this size: nothing per step sees it
    q, ok = flow_camera(source, "c", clock, 360.0, 400.0, _truth(9) + [0.3, -0.25], o)
    assert ok.all() and np.abs(q - _truth(10)).max() > 0.2
    got, good, off = seeds.realign(source, "c", Frames(frame=np.array([10]), offset_ms=np.zeros(1)), 0,
                                   np.array([0]), q.reshape(1, 3, 2), ok.reshape(1, 3), o)
    assert good.all() and not off.any()
    assert np.abs(got.reshape(3, 2) - _truth(10)).max() < 0.05


def test_a_point_slid_farther_is_rejected_in_that_camera_or_kept_as_flown():
    for reject in (True, False):
        clock, source, seeds, o = _setup(anchor_reject=reject)
        q = _truth(10) + [[2.5, 0.0], [0.1, 0.0], [0.0, -2.0]]
        got, good, off = seeds.realign(source, "c", Frames(frame=np.array([10]), offset_ms=np.zeros(1)), 0,
                                       np.array([0]), q.reshape(1, 3, 2), np.ones((1, 3), bool), o)
        assert list(good) == ([False, True, False] if reject else [True, True, True])
        assert list(off) == [reject, False, reject]
        assert np.abs(got[1] - _truth(10)[1]).max() < 0.05  # the near one is realigned
        assert np.array_equal(got[[0, 2]], q[[0, 2]])  # the far ones are not moved


def test_a_point_that_cannot_be_aligned_is_rejected_or_kept_as_flown():
    for unaligned in (True, False):
        clock, source, seeds, _ = _setup()
        o = PatchOptions(anchor_flow=True, anchor_reject_unaligned=unaligned)
        seeds.uv[0, 0, 0] = (-40.0, -40.0)  # its seed window lies outside the seed image: no alignment
        q = _truth(10) + 0.3
        got, good, off = seeds.realign(source, "c", Frames(frame=np.array([10]), offset_ms=np.zeros(1)), 0,
                                       np.array([0]), q.reshape(1, 3, 2), np.ones((1, 3), bool), o)
        assert list(off) == [unaligned, False, False] and list(good) == [not unaligned, True, True]
        assert np.array_equal(got[0], q[0]) and np.abs(got[1:] - _truth(10)[1:]).max() < 0.05


def test_a_camera_without_a_frame_at_that_time_or_a_seed_view_is_left_as_flown():
    clock, source, seeds, o = _setup()
    q = _truth(10) + 0.3
    ok = np.ones((1, 3), bool)
    for frames, s in ((Frames(frame=np.array([10]), offset_ms=np.array([12.0])), seeds),
                      (Frames(frame=np.array([10]), offset_ms=np.zeros(1)),
                       SeedViews(uv=np.full((1, 3, 1, 2), np.nan, np.float32), frame=np.array([0]), gray={}))):
        got, good, off = s.realign(source, "c", frames, 0, np.array([0]), q.reshape(1, 3, 2), ok, o)
        assert np.array_equal(got.reshape(3, 2), q) and good.all() and not off.any()


@pytest.mark.slow
def test_with_anchor_flow_any_part_of_a_cloud_is_tracked_bit_for_bit_as_in_the_whole():
    # each point is realigned on its own (one optical-flow call per camera, per-point results), and a slid patch is
    # ended on its own squares (seed_appearance_end), so a task's cut of the cloud changes no bit
    # (tests/test_patches.py checks the same without the options)
    bundle, truth = one_person_capture()
    scene = TexturedScene(bundle, truth, TextureOptions())
    cams = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"]
    table = bundle.sync.streams["vga"]
    f = 120
    o = PatchOptions(track_frames=2, seed_features=100, seed_neighbours=3, seed_views=4, anchor_flow=True,
                     seed_appearance_end=True)
    traj = patch_stream(bundle, scene, cams, (table.time_of(f - 2), table.time_of(f + 2)), o, seed_frames=[f])
    views = imaged_views(scene, cams)
    seeds = seed_patches(scene, views, {n: f for n in cams}, o)
    part = np.arange(len(seeds.X_cm))[1::3]
    sub = Seeds(X_cm=seeds.X_cm[part], normal=seeds.normal[part], seen=seeds.seen[part])
    back, fwd = run_cloud(scene, views, clocks_of(bundle, scene, cams), table.time_of(f), traj.times_ms, sub, o)
    assert traj.alive[:, -1].sum() > 50
    for track in (back, fwd):
        pos = np.searchsorted(traj.times_ms, track.times_ms)
        assert np.array_equal(np.nan_to_num(track.X_cm, nan=-1.0), np.nan_to_num(traj.X_cm[part][:, pos], nan=-1.0))
        assert np.array_equal(track.visible, traj.visible[part][:, pos])
        assert np.array_equal(track.alive, traj.alive[part][:, pos])
