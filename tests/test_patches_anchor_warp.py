"""The anchor flow on a turned patch (recon.patches.track.SeedViews, ``anchor_warp``): a patch whose plane turned
since its seed (here 25 deg in the image, and foreshortened) is realigned to its seed appearance warped by its
triplet's seed-to-now map, where the seed square as it was is not aligned and the point is rejected (the two-view
limb patch then ends); each point's answer depends on its own neighbourhood only; off, the old rule's bits."""
from __future__ import annotations

import cv2
import numpy as np

from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.track import SeedViews
from dome_calib.recon.patches.warp import seed_to_now, warped_flow
from dome_calib.recon.patches.visibility import Frames

CENTRE = np.array([160.0, 120.0])
#: the turn and foreshortening of frame 1 against frame 0 about CENTRE (image pixels)
TURN_DEG, SQUEEZE = 25.0, 0.8


def _turn() -> np.ndarray:
    a = np.radians(TURN_DEG)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ np.diag([1.0, SQUEEZE])


class TurningTexture:
    """A smooth random texture; frame 1 is frame 0 turned and squeezed about CENTRE."""

    def __init__(self):
        rng = np.random.default_rng(3)
        base = cv2.GaussianBlur(rng.uniform(0, 255, (240, 320)).astype(np.float32), (0, 0), 2.0)
        self.base = cv2.normalize(base, None, 20, 235, cv2.NORM_MINMAX)

    def gray(self, camera: str, frame: int) -> np.ndarray:
        M = _turn() if frame else np.eye(2)
        W = np.hstack([M, (CENTRE - M @ CENTRE)[:, None]]).astype(np.float32)
        return cv2.warpAffine(self.base, W, (320, 240), flags=cv2.INTER_CUBIC).astype(np.uint8)


def _patches(n: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """n patches' triplets (centre, two plane points 8 px off) at frame 0 and where they are at frame 1."""
    c = CENTRE + np.array([[-30.0, -20.0], [25.0, -15.0], [-10.0, 30.0], [35.0, 25.0]])[:n]
    seed = np.stack([c, c + [8.0, 0.0], c + [0.0, 8.0]], axis=1)  # (n, 3, 2)
    now = (seed - CENTRE) @ _turn().T + CENTRE
    return seed, now


def _realign(o: PatchOptions, now_given: bool = True):
    seed, now = _patches()
    views = SeedViews(uv=seed.astype(np.float32)[:, :, None], frame=np.array([0]), gray={})
    q = now + 0.3  # flown, slid 0.4 px
    got = views.realign(TurningTexture(), "c", Frames(frame=np.array([1]), offset_ms=np.zeros(1)), 0,
                        np.arange(len(seed)), q, np.ones(q.shape[:2], bool), o, now=now if now_given else None)
    return got, now.reshape(-1, 2)


def test_a_turned_patch_is_kept_and_realigned_with_its_warped_seed_appearance():
    o = PatchOptions(anchor_flow=True, anchor_levels=0, anchor_warp=False)
    (q, ok, off), truth = _realign(o)
    assert off.sum() >= 6  # the old rule: the seed square as it was, most points rejected
    (q, ok, off), truth = _realign(PatchOptions(anchor_flow=True, anchor_levels=0, anchor_warp=True))
    assert ok.all() and not off.any()
    assert np.abs(q - truth).max() < 0.15  # pulled back from the 0.4 px slide


def test_the_warp_is_per_point_and_off_is_the_old_rule():
    seed, now = _patches()
    src, dst = TurningTexture().gray("c", 0), TurningTexture().gray("c", 1)
    A = np.repeat(seed_to_now(seed, now), 3, axis=0)
    p0, guess = seed.reshape(-1, 2), now.reshape(-1, 2) + 0.3
    o = PatchOptions(anchor_levels=1)
    r, good = warped_flow(src, dst, p0, A, guess, o)
    for k in (0, 5, 11):  # alone: the same bits as among the others
        r1, g1 = warped_flow(src, dst, p0[k:k + 1], A[k:k + 1], guess[k:k + 1], o)
        assert np.array_equal(r1[0], r[k]) and g1[0] == good[k]
    # a degenerate map (a triplet seen edge-on) falls back to the identity
    flat = now.copy()
    flat[:, 2] = flat[:, 0] + 0.01 * (flat[:, 1] - flat[:, 0])
    assert np.array_equal(seed_to_now(seed, flat), np.repeat(np.eye(2)[None], len(seed), axis=0))
    # off: the triplets given or not, the old rule's bits
    off = PatchOptions(anchor_flow=True, anchor_levels=0, anchor_warp=False)
    (a, b) = (_realign(off)[0], _realign(off, now_given=False)[0])
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_a_patch_that_did_not_turn_is_aligned_as_without_the_warp():
    seed, _ = _patches()
    views = SeedViews(uv=seed.astype(np.float32)[:, :, None], frame=np.array([0]), gray={})
    q = seed + 0.3
    frames = Frames(frame=np.array([1]), offset_ms=np.zeros(1))
    got = [views.realign(TurningTexture(), "c", frames, 0, np.arange(len(seed)), q, np.ones(q.shape[:2], bool),
                         PatchOptions(anchor_flow=True, anchor_warp=w), now=seed + 0.01) for w in (False, True)]
    assert all(np.array_equal(x, y) for x, y in zip(*got))
