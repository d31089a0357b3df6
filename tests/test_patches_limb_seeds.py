"""Skeleton seeds on every part the cameras see (issue 49, the few-camera rig's reach): the corners' budget spread
over the parts by their area in the image, each part's corners judged against its own best (a low-contrast forearm
beside a textured torso still gets its share), and each seed compared by a square no wider than its part."""
from __future__ import annotations

import cv2
import numpy as np

from dome_calib.recon.patches.seed_skeleton import CORNER_QUALITY, _squares, part_corners, square_side_cm


def _two_parts(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 160 x 240 image: a strongly textured part (capsule 0, the left two thirds) beside a faint one (capsule 1,
    the right third; a twentieth of the contrast), and a background (-1) round them."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0.0, 1.0, (160, 240)), (0, 0), 1.5)
    tex /= tex.std()
    gray = 128.0 + np.where(np.arange(240)[None] < 160, 60.0, 3.0) * tex
    parts = np.full((160, 240), -1, np.int32)
    parts[10:150, 10:160] = 0
    parts[10:150, 160:230] = 1
    return np.clip(gray, 0, 255).astype(np.uint8), parts


def test_every_part_gets_its_share_of_the_corners_whatever_its_contrast():
    gray, parts = _two_parts()
    n = 200
    corners = part_corners(gray, parts, n, 5.0)
    faint = corners[:, 0] >= 160
    share = (parts == 1).sum() / (parts >= 0).sum()  # 0.318
    assert abs(faint.sum() - np.ceil(n * share)) <= 2
    assert abs((~faint).sum() - np.ceil(n * (1 - share))) <= 2
    lab = parts[corners[:, 1].round().astype(int), corners[:, 0].round().astype(int)]
    assert (lab >= 0).all()  # on the people only
    # one detection over the whole mask (the rule before) leaves the faint part almost nothing
    one = cv2.goodFeaturesToTrack(gray, n, CORNER_QUALITY, 5.0, mask=(parts >= 0).astype(np.uint8) * 255,
                                  blockSize=5).reshape(-1, 2)
    assert (one[:, 0] >= 160).sum() < 0.2 * faint.sum()


def test_no_part_no_corner():
    gray, parts = _two_parts()
    assert part_corners(gray, np.full_like(parts, -1), 100, 5.0).shape == (0, 2)


def test_a_seed_is_compared_by_a_square_no_wider_than_its_part():
    # forearm 4 cm, shin 5, thigh 7, torso 13 against the 6 cm square
    assert np.array_equal(square_side_cm(np.array([4.0, 5.0, 7.0, 13.0]), 6.0), [4.0, 5.0, 6.0, 6.0])
    X0 = np.zeros((2, 3))
    u, v = np.tile([1.0, 0.0, 0.0], (2, 1)), np.tile([0.0, 1.0, 0.0], (2, 1))
    sq = _squares(X0, u, v, np.array([4.0, 6.0]))
    assert np.allclose(np.ptp(sq[0], axis=0)[:2], 4.0) and np.allclose(np.ptp(sq[1], axis=0)[:2], 6.0)
