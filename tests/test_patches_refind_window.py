"""The re-find's own window (``PatchOptions.refind_window_px``, ``refind_levels``; issue 49, branch refind62) and
the one closest point on a bone (:func:`~dome_calib.recon.patches.parts.closest_on_bone`) that the labels, the
tracking's parts and the bone's carry share.

A limb in a camera of a few far apart is a textured band a dozen pixels wide moving over a background that does
not: the flow's 15 px window straddles the band's edges and its forward-backward check fails (or it follows the
background), where a 9 px window inside the band follows the limb, from the body's prediction, to the pixel."""
from __future__ import annotations

import cv2
import numpy as np

from dome_calib.bundle import SyncTable
from dome_calib.errors import OptionsError
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.motion import bone_carry
from dome_calib.recon.patches.parts import _components, PartOptions, closest_on_bone, nearest_part
from dome_calib.recon.patches.track import Clock, refind_flow_options, refind_from_body
from dome_calib.recon.project import ViewSet

from .patches_helpers import uncarried

from .patches_helpers import blurred_texture

DEPTH_CM = 100.0  # f 200 px at 100 cm: 2 px per cm
MOVE_PX = np.array([6.0, -3.0])  # the limb's image motion per 40 ms frame
BAND_HALF_PX = 6  # the band: 13 px across
SEED_FRAME = 5


class LimbScene:
    """Camera ``a`` (320 x 240): a still background and, across it, a horizontal textured band (the limb) centred
    on row 120 at the seed frame, moving MOVE_PX per frame."""

    def __init__(self):
        self.background, self.limb = blurred_texture(1, (240, 320), 1.5), blurred_texture(2, (240, 320), 1.5)

    def gray(self, camera: str, frame: int) -> np.ndarray:
        shift = MOVE_PX * (frame - SEED_FRAME)
        M = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]], np.float32)
        limb = cv2.warpAffine(self.limb, M, (320, 240), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        band = np.clip(BAND_HALF_PX + 0.5 - np.abs(np.arange(240)[:, None] - (120.0 + shift[1])), 0.0, 1.0)
        return (band * limb + (1.0 - band) * self.background).astype(np.uint8)


def _lost_centre(o: PatchOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The patch at the band's centre, its centre's flow lost in camera a, re-found from the body's prediction (the
    truth) -> (q (1, 3, 2), ok (1, 3), the truth (1, 3, 2))."""
    views = ViewSet(names=["a"], R=np.eye(3)[None], t_cm=np.array([[0.0, 0.0, DEPTH_CM]]),
                    intr=np.array([[200.0, 200.0, 160.0, 120.0]]), dist=np.zeros((1, 5)),
                    resolution=np.array([[320, 240]]))
    clock = Clock(table=SyncTable(index=np.arange(20), univ_time_ms=np.arange(20) * 40.0), frames=np.arange(20))
    t0, t1 = 40.0 * SEED_FRAME, 40.0 * (SEED_FRAME + 1)
    X = np.array([[[0.0, 0.0, 0.0], [0.0, 1.5, 0.0], [1.5, 0.0, 0.0]]])  # all three inside the band
    p = X[..., :2] / DEPTH_CM * 200.0 + [160.0, 120.0]
    X_pred = X + np.append(MOVE_PX / 2.0, 0.0)
    q, ok, found = refind_from_body(LimbScene(), views, 0, clock, t0, t1, X, X_pred, p, p.copy(),
                                    np.zeros((1, 3), bool), np.ones(1, bool), o)
    assert np.array_equal(found, ok)
    return q, ok, p + MOVE_PX


def test_a_narrow_window_refinds_a_limb_centre_the_flows_own_window_loses():
    q, ok, _ = _lost_centre(uncarried())
    assert not ok[0, 0]  # the 15 px window: the band's edges, the check fails
    q, ok, true = _lost_centre(uncarried(refind_window_px=9))
    assert ok[0, 0] and np.abs(q[0, 0] - true[0, 0]).max() < 0.05
    # no pyramid: the start is the body's prediction, within a pixel here
    q, ok, true = _lost_centre(uncarried(refind_window_px=9, refind_levels=0))
    assert ok[0, 0] and np.abs(q[0, 0] - true[0, 0]).max() < 0.05


def test_the_options_unset_are_the_flows_own_and_checked():
    o = uncarried()
    assert refind_flow_options(o) is o
    same = uncarried(refind_window_px=o.lk_window_px)
    a, b = _lost_centre(o), _lost_centre(same)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    got = refind_flow_options(uncarried(refind_window_px=9, refind_levels=0, lk_levels_full_px=20.0))
    assert (got.lk_window_px, got.lk_levels_predicted, got.lk_levels_full_px) == (9, 0, 0.0)
    for bad in ({"refind_window_px": 3}, {"refind_levels": -2}):
        try:
            PatchOptions(**bad)
        except OptionsError:
            continue
        raise AssertionError(bad)


def test_one_closest_point_on_a_bone_for_the_labels_the_parts_and_the_carry():
    A, B = np.array([1.0, 2.0, 3.0]), np.array([31.0, -7.0, 11.0])
    rng = np.random.default_rng(0)
    X = A + rng.uniform(-0.3, 1.3, (200, 1)) * (B - A) + rng.normal(0.0, 6.0, (200, 3))
    s_raw, s, out = closest_on_bone(X - A, B - A)
    # the closest point: the offset is orthogonal to the bone inside it, and clamped to its ends outside
    inside = (s_raw > 0) & (s_raw < 1)
    assert np.abs(np.sum(out[inside] * (B - A), -1)).max() < 1e-9
    assert np.array_equal(s, np.clip(s_raw, 0, 1)) and np.allclose(X - out, A + s[:, None] * (B - A))
    assert np.array_equal(closest_on_bone(X - A, 0.0 * A)[2], X - A)  # no length: its closest point is A
    # the labels' distance, the parts' surface gap and the carry's offset are that very point's, to the bit
    J = np.full((1, 1, 19, 3), np.nan)
    J[0, 0, 10], J[0, 0, 11] = A, B  # the right forearm
    k = 7  # r_forearm in BONES
    T = 1
    c = _components(X[:, None], np.tile([0.0, 0.0, 1.0], (200, T, 1)), np.ones((200, T), bool),
                    J[:, :, [10]], J[:, :, [11]], PartOptions(min_frames=2))
    assert np.array_equal(c["dist"][:, 0, 0], np.linalg.norm(out, axis=-1))
    assert np.array_equal(c["interior"][:, 0, 0], inside)
    radius = np.full(12, np.nan)
    radius[k] = 0.0
    person, bone = nearest_part(X, J[0], radius, 1e6)
    assert (bone == k).all() and (person == 0).all()
    moved = bone_carry(X[None], A[None], B[None], A[None], B[None])[0]  # no move: the point itself
    assert np.array_equal(moved, A + s[:, None] * (B - A) + out)
