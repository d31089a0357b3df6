"""A seed patch's normal refined photometrically in the cameras that see it.

The normal of a seed (the SVD of its neighbours, :mod:`.seed`) comes from nearby cameras only and is off by ~15 deg
(median; 35 deg at the 90th percentile on the synthetic group): enough to spoil the NCC in cameras far from the
seeding ones. Once the seed's visibility is known, the normal is searched (as PMVS optimises a patch) among tilts
of the current normal by (-s, 0, s) about its two plane axes, ``s`` = 8, 4, 2 deg in turn (the first step is
``normal_refine_reach_deg``, then halved down to 2 deg: 8 reaches 14 deg about each axis, 16 reaches 30), keeping
the tilt whose square looks most alike (mean NCC against the most face-on visible camera, in up to
``REFINE_VIEWS`` - 1 other visible cameras, those most oblique to it first: they tell normals apart). Scores are quantised to 1e-6 and
the untilted normal comes first, so ties keep it. The centre does not move.
"""
from __future__ import annotations

import numpy as np

from dome_calib.recon.patches.frames import FrameSource, GRID_SIDE, ncc, patch_axes, sample
from dome_calib.recon.patches.model import PatchOptions, refine_square_cm
from dome_calib.recon.patches.visibility import Frames
from dome_calib.recon.project import ViewSet, project_points
from dome_calib import ties

REFINE_VIEWS = 6
REFINE_LAST_STEP_DEG = 2.0


def refine_steps_deg(first_deg: float) -> tuple[float, ...]:
    """The tilt steps: ``first_deg``, then halved while at least :data:`REFINE_LAST_STEP_DEG` (8: 8, 4, 2)."""
    steps = [float(first_deg)]
    while steps[-1] / 2.0 >= REFINE_LAST_STEP_DEG - 1e-9:
        steps.append(steps[-1] / 2.0)
    return tuple(steps)


def _tilts(step_deg: float) -> np.ndarray:
    """(9, 2) tangents of the tilts, the untilted one first."""
    t = np.tan(np.radians(step_deg))
    pairs = [(0.0, 0.0)] + [(a, b) for a in (-t, 0.0, t) for b in (-t, 0.0, t) if (a, b) != (0.0, 0.0)]
    return np.array(pairs)


def _score(source: FrameSource, views: ViewSet, frames: Frames, X0: np.ndarray, u: np.ndarray, n: np.ndarray,
           cams: np.ndarray, o: PatchOptions) -> np.ndarray:
    """Mean NCC (N, H) of squares with plane axes u (N, H, 3), normals n (N, H, 3) in each patch's cameras
    ``cams`` (N, K) (first: the reference; -1: none)."""
    N, H = n.shape[:2]
    K = cams.shape[1]
    v = np.cross(n, u)
    g = (np.arange(GRID_SIDE) / (GRID_SIDE - 1) - 0.5) * refine_square_cm(o)
    a, b = (x.ravel() for x in np.meshgrid(g, g))
    grid = X0[:, None, None] + a[:, None] * u[:, :, None] + b[:, None] * v[:, :, None]  # (N, H, G, 3)
    G = grid.shape[2]
    samples = np.zeros((N, K, H, G), np.float32)
    inside = np.zeros((N, K, H), bool)
    for c in np.unique(cams[cams >= 0]):
        rows, ks = np.nonzero(cams == c)
        name = views.names[c]
        p = project_points(views.at([c]), grid[rows].reshape(-1, 3))
        inside[rows, ks] = p.visible[0].reshape(len(rows), H, G).all(-1)
        samples[rows, ks] = sample(source.gray(name, int(frames.frame[c])), p.uv_px[0].reshape(len(rows), H, G, 2))
    corr = ncc(samples[:, 1:], samples[:, :1])  # (N, K - 1, H)
    ok = inside[:, 1:] & inside[:, :1] & (cams[:, 1:, None] >= 0)
    n_ok = ok.sum(1)
    return np.where(n_ok >= 1, np.where(ok, corr, 0.0).sum(1) / np.maximum(n_ok, 1), -1.0)


def refine_normals(source: FrameSource, views: ViewSet, frames: Frames, X: np.ndarray, visible: np.ndarray,
                   o: PatchOptions, chunk: int = 256) -> np.ndarray:
    """Patches (N, 3, 3) at a time, seen by ``visible`` (N, V) -> the patches with refined normals (centre kept,
    plane points turned with the plane). Only cameras with a frame at that very time (``frames``, offset below
    0.5 ms: the seeding stream) take part; with ``o.normal_refine_all_streams`` every stream's cameras do, each at its
    nearest frame with the patch where it is at the reference time (no motion is known at a seed)."""
    out = X.copy()
    C = views.center_cm
    for c0 in range(0, len(X), chunk):
        Xc = X[c0:c0 + chunk]
        at_time = (frames.frame >= 0) & ((np.abs(frames.offset_ms) < 0.5) | o.normal_refine_all_streams)
        vis = visible[c0:c0 + chunk] & at_time[None]
        X0 = Xc[:, 0]
        u, _, n = patch_axes(Xc[:, 0], Xc[:, 1], Xc[:, 2])
        to_cam = C[None] - X0[:, None]
        to_cam /= np.linalg.norm(to_cam, axis=-1, keepdims=True)
        cos = np.sum(to_cam * n[:, None], -1)
        ref, _ = ties.argmax_where(cos, vis, ties.VIEW_COSINE_QUANTUM)
        rows = np.arange(len(Xc))
        # the others, most oblique to the reference first (quantised, ties by position)
        cos_ref = np.sum(to_cam * to_cam[rows, ref][:, None], -1)
        other = vis.copy()
        other[rows, ref] = False
        others = ties.argsort_where(cos_ref, other, ties.VIEW_COSINE_QUANTUM)[:, :REFINE_VIEWS - 1]
        others = np.where(np.take_along_axis(other, others, 1), others, -1)
        cams = np.concatenate([np.where(vis[rows, ref], ref, -1)[:, None], others], 1)
        for step in refine_steps_deg(o.normal_refine_reach_deg):
            tilt = _tilts(step)
            v = np.cross(n, u)
            hyp = n[:, None] + tilt[None, :, 0:1] * u[:, None] + tilt[None, :, 1:2] * v[:, None]
            hyp /= np.linalg.norm(hyp, axis=-1, keepdims=True)
            uh = u[:, None] - np.sum(u[:, None] * hyp, -1, keepdims=True) * hyp
            uh /= np.linalg.norm(uh, axis=-1, keepdims=True)
            best = ties.argmax_first(_score(source, views, frames, X0, uh, hyp, cams, o), ties.NCC_QUANTUM, axis=1)
            n, u = hyp[rows, best], uh[rows, best]
        v = np.cross(n, u)
        out[c0:c0 + chunk, 1] = X0 + o.axis_cm * u
        out[c0:c0 + chunk, 2] = X0 + o.axis_cm * v
    return out
