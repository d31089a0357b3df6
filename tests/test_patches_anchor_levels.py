"""The anchor flow on the image alone (``PatchOptions.anchor_levels`` 0): the realignment starts at the flown point
and keeps only an answer within ``anchor_flow_px`` of it, so the pyramid's coarser level finds nothing it may keep.
On a texture whose flown points slid by 0.1-2.5 px it moves and rejects the same points as the one-level rule
before, to within 0.01 px, and its optical flow runs on the image itself (``maxLevel`` 0)."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from dome_calib.recon.patches.visibility import Frames

from .test_patches_anchor import _setup, _truth

#: Slides of a patch's flown points from their true place at frame 10 (px): realigned (within 1 px) or rejected.
SLIDES = [[[0.1, 0.0], [0.3, -0.25], [-0.6, 0.4]],
          [[0.0, 0.9], [1.6, 0.0], [0.2, 0.2]],
          [[2.5, 0.0], [0.0, -2.0], [-0.7, -0.6]]]


def _realign(levels: int):
    clock, source, seeds, o = _setup()
    o = dataclasses.replace(o, anchor_levels=levels)
    out = []
    for slide in SLIDES:
        q = _truth(10) + slide
        out.append(seeds.realign(source, "c", Frames(frame=np.array([10]), offset_ms=np.zeros(1)), 0,
                                 np.array([0]), q.reshape(1, 3, 2), np.ones((1, 3), bool), o))
    return out


def test_the_image_alone_moves_and_rejects_the_points_the_one_level_rule_did(monkeypatch):
    levels_used = []
    real = cv2.calcOpticalFlowPyrLK

    def spy(*a, **k):
        levels_used.append(k.get("maxLevel"))
        return real(*a, **k)
    monkeypatch.setattr(cv2, "calcOpticalFlowPyrLK", spy)
    before = _realign(1)
    assert set(levels_used) == {1}
    levels_used.clear()
    after = _realign(0)
    assert set(levels_used) == {0}  # forward and backward on the image itself
    moved = 0
    for (q1, ok1, off1), (q0, ok0, off0), slide in zip(before, after, SLIDES):
        assert np.array_equal(ok0, ok1) and np.array_equal(off0, off1)
        assert np.abs(q0 - q1).max() < 0.01
        near = np.linalg.norm(slide, axis=1) <= 1.0
        assert np.array_equal(off0, ~near)  # the far ones rejected, the near ones kept and realigned
        assert np.abs(q0[near] - _truth(10)[near]).max() < 0.05
        moved += int(near.sum())
    assert moved == 6
