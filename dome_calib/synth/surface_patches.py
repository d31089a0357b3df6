"""Patch trajectories on the true surface of the textured synthetic people (:mod:`dome_calib.synth.textured`), with
the patch stream's error added: the patches' truth for the stages after the stream (part motions, the body refined
with them) without tracking images.

Clouds are seeded every ``every`` reference times: per present person and part, ``per_part`` points drawn uniformly
on the part's capsule, side and end caps (kept where they are on the bodies' outer surface); each becomes a triplet
(the centre and two plane points ``axis_cm`` away along two orthogonal tangents of the surface, in the part's
frame) that moves rigidly with its part. A patch lives from its seed, each way up to ``reach`` times, while at
least ``min_views`` cameras see its centre (:func:`~dome_calib.synth.textured.surface_visibility`), as a tracked
patch ends when too few cameras see it. The normals are the true ones. Error, per point: a constant offset
(``offset_cm`` per axis) and a random walk from the seed (``drift_cm`` per axis and step). The defaults (2.3 mm and
0.6 mm: 3.5 mm median at the seed, 5-6 mm after 10-30 steps; a part motion's residual 1.0 mm median) are a little
worse than the stream's own (bench/patches.py's conversation: 2.7 mm at the seed, 4-5 mm after 10-30 frames; a part
motion's residual 0.6 mm).
"""
from __future__ import annotations

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.synth.group import GroupTruth
from dome_calib.synth.textured import N_PARTS, nearest_surface_points, part_frames, surface_points_cm
from dome_calib.synth.textured import surface_visibility


def _capsule_points(rng: np.random.Generator, r: np.ndarray, L: np.ndarray) -> np.ndarray:
    """(n,) radii and axis lengths -> (n, 3) points drawn uniformly on capsules' surfaces, in their parts' frames
    (z along the axis from 0 to L): the side (area 2 pi r L) or an end cap (4 pi r^2 both)."""
    n = len(r)
    on_cap = rng.uniform(0, 1, n) < 2 * r / (L + 2 * r)
    theta, u = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 1, n)
    side = np.stack([r * np.cos(theta), r * np.sin(theta), u * L], 1)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cap = r[:, None] * d + np.where(d[:, 2:3] > 0, L[:, None], 0.0) * [[0.0, 0.0, 1.0]]
    return np.where(on_cap[:, None], cap, side)


def true_patches(bundle: Bundle, cameras: list[str], truth: GroupTruth, times_ms: np.ndarray, seed: int, *,
                 per_part: int = 40, every: int = 20, reach: int = 30, offset_cm: float = 0.23,
                 drift_cm: float = 0.06, axis_cm: float = 3.0, min_views: int = 2
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Patch trajectories at (T,) reference times (module docstring) -> X_cm (N, T, 3, 3) centre and plane points
    (NaN where not alive), normal (N, T, 3), alive (N, T), the true person (N,) (index in ``truth.plans``) and part
    (N,). Random draws from ``default_rng([seed, 49])``."""
    rng = np.random.default_rng([seed, 49])
    T = len(times_ms)
    Xs, Ns, As, persons, parts = [], [], [], [], []
    for s in range(0, T, every):
        Xj, present = truth.joints_cm(times_ms[s:s + 1])
        live = np.flatnonzero(present[0])
        if not len(live):
            continue
        fr = part_frames(Xj[0])
        n = per_part * N_PARTS * len(live)
        person = np.repeat(live, per_part * N_PARTS)
        part = np.tile(np.repeat(np.arange(N_PARTS), per_part), len(live))
        r, L = fr.radius[person, part], fr.length[person, part]
        local = _capsule_points(rng, r, L)
        P0, _ = surface_points_cm(truth, times_ms[s:s + 1], person, part, local)
        on = nearest_surface_points(truth, float(times_ms[s]), P0[0])
        keep = (on.distance_cm < 1e-6) & (on.person == person) & (on.part == part)
        person, part, local, L = person[keep], part[keep], local[keep], L[keep]
        # plane points: axis_cm along two orthogonal tangents of the surface, in the part's frame
        n_loc = local - np.stack([np.zeros(len(local)), np.zeros(len(local)), np.clip(local[:, 2], 0.0, L)], 1)
        n_loc /= np.linalg.norm(n_loc, axis=1, keepdims=True)
        ref = np.where(np.abs(n_loc[:, 2:3]) > 0.9, [[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]])
        tang = np.cross(ref, n_loc)
        tang /= np.linalg.norm(tang, axis=1, keepdims=True)
        along = np.cross(n_loc, tang)
        lo, hi = max(0, s - reach), min(T, s + reach + 1)
        pts = [surface_points_cm(truth, times_ms[lo:hi], person, part, local + axis_cm * d) for d in (0 * tang, tang,
                                                                                                   along)]
        X = np.stack([p[0] for p in pts], 2).transpose(1, 0, 2, 3)  # (n, t, 3, 3)
        normal = pts[0][1].transpose(1, 0, 2)
        seen = np.stack([surface_visibility(bundle, cameras, truth, float(times_ms[k]), X[:, k - lo, 0],
                                            normal[:, k - lo]).sum(1) for k in range(lo, hi)], 1) >= min_views
        # a patch lives from its seed while it is seen, each way
        rel = s - lo
        ok = seen[:, rel]
        fwd = np.cumprod(seen[:, rel:], axis=1).astype(bool)
        bwd = np.cumprod(seen[:, :rel + 1][:, ::-1], axis=1).astype(bool)[:, ::-1]
        alive_w = np.concatenate([bwd[:, :-1], fwd], 1) & ok[:, None]
        m = len(person)
        noise = rng.normal(0, offset_cm, (m, 1, 3, 3)) + np.concatenate(
            [np.cumsum(rng.normal(0, drift_cm, (m, rel, 3, 3))[:, ::-1], 1)[:, ::-1], np.zeros((m, 1, 3, 3)),
             np.cumsum(rng.normal(0, drift_cm, (m, hi - lo - rel - 1, 3, 3)), 1)], 1)
        Xf, Nf, Af = np.full((m, T, 3, 3), np.nan), np.full((m, T, 3), np.nan), np.zeros((m, T), bool)
        Xf[:, lo:hi] = np.where(alive_w[..., None, None], X + noise, np.nan)
        Nf[:, lo:hi] = np.where(alive_w[..., None], normal, np.nan)
        Af[:, lo:hi] = alive_w
        Xs.append(Xf[ok]), Ns.append(Nf[ok]), As.append(Af[ok])  # the patches seen at their seed
        persons.append(person[ok]), parts.append(part[ok])
    return (np.concatenate(Xs), np.concatenate(Ns), np.concatenate(As), np.concatenate(persons),
            np.concatenate(parts))
