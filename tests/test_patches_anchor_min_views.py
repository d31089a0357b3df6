"""The anchor flow only for patches with views to spare (``PatchOptions.anchor_min_views``, track.anchor): a patch
flown in fewer cameras is left as flown (a rejected view would end a two-view patch), the others are realigned and
rejected as before; 0 (the default) is the call as it was, bit for bit."""
from __future__ import annotations

import numpy as np

from dome_calib.bundle import SyncTable
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.track import Clock, SeedViews, anchor
from dome_calib.recon.patches.visibility import Frames

from .test_patches import VELOCITY_PX_MS, MovingTexture
from .test_patches_anchor import P0

FRAMES = Frames(frame=np.array([10, 10, 10]), offset_ms=np.zeros(3))


def _truth(frame: int) -> np.ndarray:
    return P0 + VELOCITY_PX_MS * frame * 40.0


def _setup():
    index = np.arange(0, 40)
    source = MovingTexture(Clock(table=SyncTable(index=index, univ_time_ms=index * 40.0), frames=index))
    # two patches with the same seed view in camera 0
    uv = np.full((2, 3, 3, 2), np.nan, np.float32)
    uv[:, :, 0] = P0
    # each patch: its first point slid 2.5 px (rejected by the anchor), its second 0.3 px (realigned)
    q = np.concatenate([_truth(10) + [[2.5, 0.0], [0.3, -0.25], [0.0, 0.0]]] * 2)
    return source, SeedViews(uv=uv, frame=np.array([0, 0, 0]), gray={}), q


PLAIN = dict(anchor_warp=False, anchor_levels=1)  # the anchor as it was before the warp and the image-only flow


def _anchor(min_views: int):
    source, seeds, q = _setup()
    flown = np.array([[True, True, False], [True, True, True]])  # patch 0 flown in 2 cameras, patch 1 in 3
    slid = np.zeros((2, 3), bool)
    o = PatchOptions(anchor_flow=True, anchor_min_views=min_views, **PLAIN)
    got, ok = anchor(seeds, source, "c", FRAMES, 0, np.array([0, 1]), q, np.ones(6, bool), q.copy(), flown, slid, o)
    return q, got, ok, slid


def test_a_patch_without_views_to_spare_is_left_as_flown_the_others_are_anchored():
    q, got, ok, slid = _anchor(3)
    assert np.array_equal(got[:3], q[:3]) and ok[:3].all() and not slid[0].any()  # two views: as flown
    assert list(ok[3:]) == [False, True, True] and slid[1, 0] and not slid[1, 1:].any()
    assert np.abs(got[4] - _truth(10)[1]).max() < 0.05  # realigned
    assert np.array_equal(got[3], q[3])  # rejected, not moved


def test_zero_anchors_every_patch_and_a_threshold_below_every_count_gives_the_same_bits():
    q, got, ok, slid = _anchor(0)
    assert list(ok) == [False, True, True] * 2 and list(slid[:, 0]) == [True, True]
    source, seeds, _ = _setup()  # the realignment as called before the option
    old, old_ok, _ = seeds.realign(source, "c", FRAMES, 0, np.array([0, 1]), q.reshape(2, 3, 2), np.ones((2, 3), bool),
                                   PatchOptions(anchor_flow=True, anchor_min_views=0, **PLAIN), now=q)
    assert np.array_equal(got, old) and np.array_equal(ok, old_ok)
    for m in (1, 2):
        _, got_m, ok_m, slid_m = _anchor(m)
        assert np.array_equal(got_m, got) and np.array_equal(ok_m, ok) and np.array_equal(slid_m, slid)
