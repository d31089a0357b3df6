"""A tracked patch held on the surface point it started on: re-anchored to its own first appearance.

Optical flow is checked forward and backward at every step (``lk_fb_px``), but a patch still slides: each step's
flow errs by a fraction of a pixel in the same direction (a flat square on a curved, turning limb; blur; the edge
of another body part entering the window), the errors pass every per-step check, and after 10 frames a tenth of
the patches are more than 1 cm from their point. Nothing measured within one step can see that; the patch's
appearance against its own first appearance can.

So each patch keeps, per camera, its **template**: its square (the 7 x 7 grid of :mod:`.frames`) sampled in that
camera's image at the seed, for the cameras that saw it there (the MAP labels) and whose frame is at the seed time
itself (the reference stream). After every tracking step, the patch is moved to where its square looks most like
those templates, as PMVS refines a patch's position by maximising its photometric consistency: among the shifts of
its three points by ``(a u + b v + c n) s`` (``u``, ``v`` its plane axes, ``n`` its normal, ``a, b, c`` in
{-1, 0, 1}), ``s`` = each of ``anchor_steps_cm`` in turn, the shift whose mean NCC against the templates is highest
wins, in at most ``anchor_views`` of the cameras that have a template and see the patch now (chosen as the flown
views are: most face-on, spread; only cameras with a frame at that very time). The unshifted patch comes first and
scores are quantised to 1e-6, so ties keep it. A patch whose best score is below ``anchor_min_ncc`` has lost its
point (occluded in the views that knew it, or slid beyond the search) and ends.

Each patch's result depends on its own templates and the images only.
"""
from __future__ import annotations

import numpy as np

from dome_calib.recon.patches.frames import GRID_SIDE, FrameSource, ncc, patch_axes, patch_grid_cm, sample
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.visibility import Frames
from dome_calib.recon.project import ViewSet, project_points

#: Frames within this of the reference time (ms) are "at that very time" (the reference stream's own cameras).
SAME_TIME_MS = 0.5


def _shifts(normal: bool) -> np.ndarray:
    """(9 or 27, 3) unit shifts (a, b, c) along (u, v, n), the zero shift first; ``normal`` False: in the plane
    alone (c = 0)."""
    cs = (-1.0, 0.0, 1.0) if normal else (0.0,)
    out = [(0.0, 0.0, 0.0)] + [(a, b, c) for a in (-1.0, 0.0, 1.0) for b in (-1.0, 0.0, 1.0)
                               for c in cs if (a, b, c) != (0.0, 0.0, 0.0)]
    return np.array(out)


def now_frames(frames: Frames) -> np.ndarray:
    """(V,) the cameras with a frame at the reference time itself."""
    return (frames.frame >= 0) & (np.abs(frames.offset_ms) < SAME_TIME_MS)


def _sample_squares(source: FrameSource, views: ViewSet, frames: Frames, grid: np.ndarray, cams: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Squares ``grid`` (N, H, G, 3) sampled in each patch's cameras ``cams`` (N, K) (positions, -1: none) ->
    ((N, K, H, G) float32 samples, (N, K, H) bool: the whole square inside the image)."""
    N, H, G, _ = grid.shape
    K = cams.shape[1]
    out = np.zeros((N, K, H, G), np.float32)
    inside = np.zeros((N, K, H), bool)
    for c in np.unique(cams[cams >= 0]):
        rows, ks = np.nonzero(cams == c)
        name = views.names[c]
        p = project_points(views.subset([name]), grid[rows].reshape(-1, 3))
        inside[rows, ks] = p.visible[0].reshape(len(rows), H, G).all(-1)
        out[rows, ks] = sample(source.gray(name, int(frames.frame[c])), p.uv_px[0].reshape(len(rows), H, G, 2))
    return out, inside


def as_columns(mask: np.ndarray) -> np.ndarray:
    """(N, V) bool -> (N, K) the positions of each row's True cameras in increasing order, -1 padded."""
    N, V = mask.shape
    K = int(mask.sum(1).max()) if N else 0
    order = np.argsort(~mask, axis=1, kind="stable")[:, :K]
    return np.where(np.take_along_axis(mask, order, 1), order, -1)


def templates(source: FrameSource, views: ViewSet, frames: Frames, X: np.ndarray, cams: np.ndarray,
              o: PatchOptions) -> tuple[np.ndarray, np.ndarray]:
    """Patches (N, 3, 3) sampled in the cameras ``cams`` (N, V) bool that have a frame at this very time ->
    ((N, V, G) float32 templates, (N, V) bool: has one, the whole square inside the image)."""
    N, V = cams.shape
    use = cams & now_frames(frames)[None]
    grid = patch_grid_cm(X[:, 0], X[:, 1], X[:, 2], o.ncc_size_cm)[:, None]  # (N, 1, G, 3)
    cols = as_columns(use)
    s, inside = _sample_squares(source, views, frames, grid, cols)
    out = np.zeros((N, V, grid.shape[2]), np.float32)
    has = np.zeros((N, V), bool)
    rows, ks = np.nonzero(cols >= 0)
    out[rows, cols[rows, ks]] = s[rows, ks, 0]
    has[rows, cols[rows, ks]] = inside[rows, ks, 0]
    return out, has


def anchor(source: FrameSource, views: ViewSet, frames: Frames, X: np.ndarray, tmpl: np.ndarray,
           cams: np.ndarray, o: PatchOptions) -> tuple[np.ndarray, np.ndarray]:
    """Patches (N, 3, 3) moved to where their squares look most like their templates ``tmpl`` (N, V, G) in the
    cameras ``cams`` (N, K) (positions, -1: none; see the module) -> (the moved patches, (N,) their mean NCC
    against the templates; -1 where no camera could judge, those patches not moved)."""
    N = len(X)
    score = np.full(N, -1.0)
    X = X.copy()
    if N == 0 or cams.shape[1] == 0:
        return X, score
    rows = np.arange(N)
    unit = _shifts(o.anchor_normal)  # (H, 3)
    ref = tmpl[rows[:, None], np.maximum(cams, 0)][:, :, None]  # (N, K, 1, G)
    for step in o.anchor_steps_cm:
        u, v, n = patch_axes(X[:, 0], X[:, 1], X[:, 2])
        d = step * (unit[None, :, 0:1] * u[:, None] + unit[None, :, 1:2] * v[:, None]
                    + unit[None, :, 2:3] * n[:, None])  # (N, H, 3)
        base = patch_grid_cm(X[:, 0], X[:, 1], X[:, 2], o.ncc_size_cm)  # (N, G, 3)
        s, inside = _sample_squares(source, views, frames, base[:, None] + d[:, :, None], cams)
        corr = ncc(s, ref)  # (N, K, H)
        ok = inside & (cams >= 0)[:, :, None]
        n_ok = ok.sum(1)  # (N, H)
        mean = np.where(n_ok >= 1, np.where(ok, corr, 0.0).sum(1) / np.maximum(n_ok, 1), -1.0)
        # a shift judged in fewer cameras than the unshifted square is not a candidate
        mean = np.where(n_ok >= n_ok[:, :1], mean, -1.0)
        best = np.argmax(np.rint(mean * 1e6), axis=1)
        X = X + d[rows, best][:, None]
        score = mean[rows, best]
    return X, score
