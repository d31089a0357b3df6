"""The anchor flow's seed square as a turned patch is seen now (``PatchOptions.anchor_warp``; used by
:meth:`dome_calib.recon.patches.track.SeedViews.realign`).

The seed image shows a patch's square from its seed-time pose. Once its part turns, the realignment compares the
patch with a square that no longer looks like it and fails or slides (docs/patches.md, "A turned patch"). Here the
seed image is warped first by the patch's seed-to-now map in that camera (:func:`seed_to_now`: the affine map of
its triplet's projections at the seed to those of its current triplet), and the flow runs from the warped squares
(:func:`warped_flow`), each point's answer depending on its own neighbourhood only, as the plain flow's.
"""
from __future__ import annotations

import cv2
import numpy as np

from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.seed import optical_flow
from dome_calib import ties

#: A patch's seed-to-now image map whose area ratio (determinant) lies outside these is not warped by
#: (seen nearly edge-on, or from behind, in one of the two): its seed square is compared as it was at the seed.
WARP_DET_RANGE = (0.2, 5.0)


def _inverse_2x2(M: np.ndarray, det: np.ndarray) -> np.ndarray:
    """(n, 2, 2) matrices and their (n,) determinants -> their inverses, written out."""
    return np.stack([np.stack([M[:, 1, 1], -M[:, 0, 1]], -1), np.stack([-M[:, 1, 0], M[:, 0, 0]], -1)],
                    axis=1) / det[:, None, None]


def seed_to_now(seed: np.ndarray, now: np.ndarray) -> np.ndarray:
    """Patches' triplets (n, 3, 2) in one camera at the seed and now -> (n, 2, 2) the linear part of the affine map
    that takes the seed's triplet to now's (the patch's plane, to first order: its in-plane turn and foreshortening
    since the seed); the identity where either triplet is missing or the map's determinant lies outside
    :data:`WARP_DET_RANGE`. Written out (no LAPACK), so every machine gets the same bits."""
    S = np.stack([seed[:, 1] - seed[:, 0], seed[:, 2] - seed[:, 0]], axis=-1).astype(float)  # columns: the axes
    D = np.stack([now[:, 1] - now[:, 0], now[:, 2] - now[:, 0]], axis=-1).astype(float)
    det_s = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        S_inv = _inverse_2x2(S, det_s)
        A = np.stack([np.stack([D[:, i, 0] * S_inv[:, 0, k] + D[:, i, 1] * S_inv[:, 1, k] for k in (0, 1)], -1)
                      for i in (0, 1)], axis=1)
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    lo, hi = WARP_DET_RANGE
    det = np.nan_to_num(det)
    use = (np.all(np.isfinite(A), axis=(1, 2)) & ties.at_least(det, lo, ties.UNIT_QUANTUM)
           & ties.at_most(det, hi, ties.UNIT_QUANTUM))
    return np.where(use[:, None, None], np.nan_to_num(A), np.eye(2)[None])


def warp_px(A: np.ndarray, window_px: int) -> np.ndarray:
    """(m, 2, 2) seed-to-now maps -> (m,) how far each moves a corner of the flow's window (``window_px`` square
    about the point) from where the identity leaves it, px: how much the seed square differs from a shifted one."""
    h = window_px // 2
    corners = np.array([[h, h], [h, -h]], float)  # the other two are these negated
    D = A - np.eye(2)[None]
    return np.max([np.hypot(D[:, 0, 0] * c[0] + D[:, 0, 1] * c[1], D[:, 1, 0] * c[0] + D[:, 1, 1] * c[1])
                   for c in corners], axis=0)


def warped_flow(seed_gray: np.ndarray, gray: np.ndarray, p0: np.ndarray, A: np.ndarray, guess: np.ndarray,
                o: PatchOptions) -> tuple[np.ndarray, np.ndarray]:
    """Seed pixels ``p0`` (m, 2) of image ``seed_gray`` followed into ``gray`` (:func:`.seed.optical_flow`, started
    at ``guess``, ``anchor_levels`` levels), each point's seed neighbourhood first warped by its map ``A`` (m, 2, 2)
    (:func:`seed_to_now`): the neighbourhoods are resampled (bilinear) into tiles of one image, each tile's centre
    the point's seed pixel, its pixel ``c + d`` the seed's ``p0 + A^-1 d``, and the flow runs from the tiles'
    centres. A tile is wide enough that the flow's windows at every level and the pyramid's filters stay inside it:
    each point's result depends on its own neighbourhood only, as :func:`.seed.optical_flow`'s."""
    m = len(p0)
    r, good = np.zeros((m, 2)), np.zeros(m, bool)
    scale = 2 ** o.anchor_levels
    half = (o.lk_window_px // 2 + 6) * scale  # a tile's side a multiple of the coarsest level's pixel: every
    tile = 2 * half  # tile lies alike on the pyramid's grid, wherever it is
    H, W = gray.shape[:2]
    rows, cols = H // tile, W // tile  # the flow wants two images of one size: the tiles fill one like ``gray``
    if rows * cols == 0:
        return r, good
    inv = _inverse_2x2(A, A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0])
    d = np.arange(tile, dtype=float) - half
    dx, dy = d[None, :], d[:, None]  # (1, tile) columns, (tile, 1) rows
    for lo in range(0, m, rows * cols):
        k = np.arange(lo, min(m, lo + rows * cols))
        used = -(-len(k) // cols)  # the rows of tiles this batch fills (the rest of the image stays 0)
        mx = np.zeros((used * cols, tile, tile), np.float32)
        my = np.full((used * cols, tile, tile), -1.0, np.float32)  # unused tiles: the border (no point reads them)
        mx[:len(k)] = p0[k, 0, None, None] + inv[k, 0, 0, None, None] * dx + inv[k, 0, 1, None, None] * dy
        my[:len(k)] = p0[k, 1, None, None] + inv[k, 1, 0, None, None] * dx + inv[k, 1, 1, None, None] * dy
        maps = [a.reshape(used, cols, tile, tile).transpose(0, 2, 1, 3).reshape(used * tile, cols * tile)
                for a in (mx, my)]
        tiles = np.zeros_like(gray)
        tiles[:used * tile, :cols * tile] = cv2.remap(seed_gray, maps[0], maps[1], cv2.INTER_LINEAR,
                                                      borderMode=cv2.BORDER_REPLICATE)
        j = k - lo
        centres = np.stack([(j % cols) * tile + half, (j // cols) * tile + half], axis=1).astype(float)
        r[k], good[k] = optical_flow(tiles, gray, centres, o, guess=guess[k], levels=o.anchor_levels)
    return r, good
