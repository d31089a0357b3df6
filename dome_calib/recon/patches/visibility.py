"""Which cameras see a patch at a time: a binary MAP labelling of the cameras, solved exactly by a minimum cut.

Per patch and camera, the cost of "visible" (the cost of "not visible" is 0):

- **photometric**: ``photometric_weight * (tau - NCC) / (1 - tau)``, NCC of the patch's square (a 7 x 7 grid on its
  plane, bilinear samples) in the camera against the reference camera (the camera that saw the patch at the
  previous time, or at the seed, most face-on; the most face-on candidate if none did), ``tau`` =
  ``ncc_threshold``. With ``neighbour_ncc`` (off by default) NCC is the best of that and the NCC against each of the
  camera's prior neighbours that saw the patch at the previous time and is a candidate now, and ``tau`` =
  ``map_ncc_threshold``: a plane that is a little off (a curved limb, a normal 10-15 deg wrong) looks alike in
  cameras a few degrees apart but not in cameras far from the reference, so a camera agreeing with a neighbour
  that saw the patch is consistent (the largest class of misses on the bench: truly visible views at a good angle
  whose NCC against the reference is below 0.6). Off by default: tracking with the views it adds lets more patches
  drift, and precision falls (docs/benchmarks.md);
- **motion**: for cameras the patch was tracked in, ``motion_weight * (min(r / motion_sigma_px, 3) - 1)``, ``r`` the
  largest distance between a point's optical flow and the reprojection of its triangulated motion (a failed flow
  counts as 3 sigmas); 0 for the others;
- **geometric**: a camera is a candidate only if the normal faces it (cosine above ``min_cos_view``; the others are
  not projected), the square projects into its image (with ``border_squares``, the default, its centre and at least
  :data:`MIN_BORDER_SAMPLES` of its samples, every NCC of it then over the samples inside both images,
  :func:`ncc_partial`; else the whole square) and, with ``body_occlusion`` and the people given, no
  body part lies on the ray from the camera to the patch (:mod:`.occlusion`); then
  ``geometric_weight * max(0, 0.5 - cos) / 0.5`` (grazing views cost).

Prior: ``prior_weight`` for each pair of neighbouring candidate cameras (each camera's ``prior_neighbours``
nearest centres) labelled differently. All patches' graphs go through one cut (:mod:`.mincut`); each gets its own
labels whatever else is solved with it.

Cameras of other streams than the reference are judged at their own nearest frame, the patch moved there with
its last step's velocity (``X(tau) = X(t) + (tau - t) / dt * (X(t) - X(t - dt))``; at the seed, no motion).
The CVPR 2014 paper's baseline, photometric consistency alone, is returned beside it: facing the camera (cosine
above ``min_cos_view``), in the image and NCC at least ``ncc_threshold``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix

from dome_calib.recon.patches.frames import (GRID_SIDE, MIN_STD_DN, FrameSource, centred, ncc, ncc_centred,
                                             patch_axes, patch_grid_cm, sample)
from dome_calib.recon.patches.mincut import min_cut_labels
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.occlusion import BodyPrior, Occluders, occluded_views
from dome_calib.recon.project import ViewSet, project_view, project_view_rows
from dome_calib import ties


#: Cameras whose facing cosines are computed together ((patches, chunk, 3) arrays).
FACING_CHUNK = 64
#: Patch-views whose NCC against the reference is computed together.
NCC_CHUNK = 8192
#: The grid point at the square's centre (``frames.patch_grid_cm``'s order).
CENTRE_SAMPLE = (GRID_SIDE * GRID_SIDE) // 2
#: A square crossing the image border (``border_squares``) is judged on its samples inside the image: at least this
#: many (half the square, rounded up), and a pair of squares on the samples inside both, at least as many.
MIN_BORDER_SAMPLES = (GRID_SIDE * GRID_SIDE + 1) // 2


def ncc_partial(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`~.frames.ncc` of (..., G) samples where NaN marks a sample outside the image: over the samples inside
    both, 0 where fewer than :data:`MIN_BORDER_SAMPLES` are (or either side has no texture there). Rows without a NaN
    get :func:`~.frames.ncc`'s bits."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float32), np.asarray(b, np.float32))
    out = np.asarray(ncc(np.nan_to_num(a), np.nan_to_num(b)), dtype=float)
    both = np.isfinite(a) & np.isfinite(b)
    part = ~both.all(-1)
    if not part.any():
        return out
    m, x, y = both[part], np.where(both[part], a[part], 0.0), np.where(both[part], b[part], 0.0)
    n = m.sum(-1)
    k = np.maximum(n, 1)
    x = np.where(m, x - (x.sum(-1) / k)[..., None], 0.0)
    y = np.where(m, y - (y.sum(-1) / k)[..., None], 0.0)
    vx, vy = (x * x).sum(-1) / k, (y * y).sum(-1) / k
    ok = (n >= MIN_BORDER_SAMPLES) & (vx > MIN_STD_DN ** 2) & (vy > MIN_STD_DN ** 2)
    out[part] = np.where(ok, (x * y).sum(-1) / k / np.sqrt(np.where(ok, vx * vy, 1.0)), 0.0)
    return out


@dataclass(frozen=True)
class Squares:
    """Sampled squares (M, G) (NaN: a sample outside the image, ``border_squares``), each centred once, with its
    variance (M,) (:func:`~.frames.centred`) and whether it crosses its image border (M,)."""

    samples: np.ndarray
    centred: np.ndarray
    variance: np.ndarray
    cut: np.ndarray

    @classmethod
    def of(cls, samples: np.ndarray) -> "Squares":
        c, var = centred(samples)
        return cls(samples=samples, centred=c, variance=var, cut=~np.isfinite(samples).all(-1))

    def ncc(self, ra: np.ndarray, rb: np.ndarray) -> np.ndarray:
        """(P,) float64 NCC of rows ``ra`` against rows ``rb``: :func:`~.frames.ncc_centred`'s bits, over the samples
        inside both images (:func:`ncc_partial`) where either square crosses its border."""
        out = ncc_centred(self.centred[ra], self.variance[ra], self.centred[rb], self.variance[rb]).astype(float)
        cut = np.flatnonzero(self.cut[ra] | self.cut[rb])
        if len(cut):
            out[cut] = ncc_partial(self.samples[ra[cut]], self.samples[rb[cut]])
        return out


#: Patches whose neighbour pairs are found together ((chunk, E) masks; :func:`neighbour_ncc`).
NEIGHBOUR_CHUNK = 1024


def camera_neighbours(views: ViewSet, k: int) -> np.ndarray:
    """(E, 2) pairs i < j: each camera with its ``k`` nearest centres (quantised to 0.1 mm, ties by name)."""
    C = views.center_cm
    pairs = set()
    for i in range(len(C)):
        others = [j for j in range(len(C)) if j != i]
        near = ties.order_by(np.linalg.norm(C - C[i], axis=1)[others], [views.names[j] for j in others],
                             ties.CAMERA_DISTANCE_QUANTUM_CM)
        for j in (others[m] for m in near[:k]):
            pairs.add((min(i, j), max(i, j)))
    return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)


def neighbour_ncc(squares: Squares, row_of: np.ndarray, anchor: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """(N, V) each camera's best NCC against its prior neighbours that are anchors (-1 where it has none; 0 against a
    neighbour where either camera has no square).

    Only the (patch, camera pair) NCCs that can count are computed, from the squares as sampled (a full dome's patch
    is sampled in ~170 of 521 cameras; a dense (N, V, G) block of them was 400 MB per 4000 patches). A pair where
    either square crosses its image border (``border_squares``) is judged on the samples inside both
    (:func:`ncc_partial`).

    Args:
        squares: the sampled squares (:class:`Squares`).
        row_of: (N, V) the row of patch n's square in camera v (-1: not sampled there, as a square of zeros).
        anchor: (N, V) bool, the cameras a camera may be compared with (those that saw the patch before and are
            candidates now).
        neighbours: (E, 2) camera pairs (:func:`camera_neighbours`), both ways.
    """
    N, V = anchor.shape
    best = np.full((N, V), -1.0)
    i, j = neighbours[:, 0], neighbours[:, 1]
    for lo in range(0, N, NEIGHBOUR_CHUNK):  # (chunk, E) pair masks at a time
        a_i, a_j = anchor[lo:lo + NEIGHBOUR_CHUNK][:, i], anchor[lo:lo + NEIGHBOUR_CHUNK][:, j]
        pn, pe = np.nonzero(a_i | a_j)  # the pairs where one end may lift the other
        if len(pn) == 0:
            continue
        n = lo + pn
        ra, rb = row_of[n, i[pe]], row_of[n, j[pe]]
        both = (ra >= 0) & (rb >= 0)
        c = np.zeros(len(pn))  # a missing square has no texture: NCC 0
        c[both] = squares.ncc(ra[both], rb[both])
        up_i, up_j = a_j[pn, pe], a_i[pn, pe]
        np.maximum.at(best, (n[up_i], i[pe[up_i]]), c[up_i])
        np.maximum.at(best, (n[up_j], j[pe[up_j]]), c[up_j])
    return best


@dataclass(frozen=True)
class Frames:
    """The image each camera is judged on at one reference time: frame (V,) index (-1: none near), offset_ms (V,)
    its time minus the reference time; t_ms the reference time (NaN: not given, no body can be placed there)."""

    frame: np.ndarray
    offset_ms: np.ndarray
    t_ms: float = float("nan")


@dataclass(frozen=True)
class Appearance:
    """Patches' squares as sampled in the cameras: samples (M, G) float32 (NaN: a sample outside the image, a square
    crossing the border with ``border_squares``), row_of (N, V) the row of patch n in camera v (-1: not sampled
    there)."""

    samples: np.ndarray
    row_of: np.ndarray

    def keep(self, which: np.ndarray) -> Appearance:
        """Only the (N, V) ``which`` squares (the views a patch's seed appearance is kept in)."""
        rows = np.where(which, self.row_of, -1)
        used = np.flatnonzero(rows >= 0)
        out = np.full(rows.shape, -1, np.int64)
        out.flat[used] = np.arange(len(used))
        return Appearance(samples=self.samples[rows.flat[used]], row_of=out)

    def ncc_against(self, other: Appearance) -> np.ndarray:
        """(N, V) NCC of each square against ``other``'s square of the same patch in the same camera (NaN where
        either has none)."""
        both = (self.row_of >= 0) & (other.row_of >= 0)
        out = np.full(self.row_of.shape, np.nan)
        out[both] = ncc_partial(self.samples[self.row_of[both]], other.samples[other.row_of[both]])
        return out


@dataclass(frozen=True)
class Visibility:
    """visible (N, V) MAP labels; photometric (N, V) NCC-alone baseline; ncc (N, V); candidate (N, V); reference
    (N,) camera position; appearance: the squares sampled (the candidates' cameras); hidden (N, V): the people hide
    the patch from the camera (no candidate there)."""

    visible: np.ndarray
    photometric: np.ndarray
    ncc: np.ndarray
    candidate: np.ndarray
    reference: np.ndarray
    appearance: Appearance | None = None
    hidden: np.ndarray | None = None  # (N, V) the people hide the patch from the camera (body_occlusion)


def estimate_visibility(source: FrameSource, views: ViewSet, frames: Frames, X: np.ndarray, velocity: np.ndarray,
                        previous: np.ndarray, motion_px: np.ndarray | None, neighbours: np.ndarray,
                        o: PatchOptions, body: BodyPrior | None = None) -> Visibility:
    """The MAP visibility of N patches at one reference time.

    Args:
        X: (N, 3, 3) patches (centre, two plane points), world cm.
        velocity: (N, 3, 3) cm per ms (0 at the seed) to move a patch to a camera's own frame time.
        previous: (N, V) bool, the cameras that saw each patch before (choose the reference camera).
        motion_px: (N, V) flow-against-motion residual, NaN where not tracked, inf where the flow failed; None at
            the seed.
        neighbours: (E, 2) camera pairs of the prior (:func:`camera_neighbours`).
        body: the people over time; with ``o.body_occlusion`` a camera they hide the patch from (at its own frame
            time ``frames.t_ms`` + its offset) is no candidate (:mod:`.occlusion`) but keeps its place in the prior
            as a camera labelled "not visible". None: no such term.
    """
    N, V = len(X), len(views.names)
    in_image = np.zeros((N, V), bool)
    cos = np.full((N, V), -1.0)
    hidden = np.zeros((N, V), bool)  # the people hide the patch's centre from the camera (body_occlusion)
    _, _, normal = patch_axes(X[:, 0], X[:, 1], X[:, 2])
    C = views.center_cm
    G = GRID_SIDE * GRID_SIDE
    # the squares are sampled where they are in the image only (a third of a dome's patch-cameras face the patch):
    # one (M, G) block of samples, row row_of[n, v] for patch n in camera v
    row_of = np.full((N, V), -1, np.int64)
    blocks: list[np.ndarray] = []
    row_n: list[np.ndarray] = []  # the patch and camera of each row
    row_v: list[np.ndarray] = []
    M = 0
    moved: dict[float, np.ndarray] = {}  # per time offset: the patches' squares there
    judged = np.flatnonzero(frames.frame >= 0) if N else np.zeros(0, np.int64)
    for dt in sorted({float(frames.offset_ms[v]) for v in judged}):  # a stream's cameras share the offset
        Xt = X + velocity * dt
        moved[dt] = patch_grid_cm(Xt[:, 0], Xt[:, 1], Xt[:, 2], o.ncc_size_cm)  # (N, G, 3)
        cams = judged[frames.offset_ms[judged] == dt]
        for lo in range(0, len(cams), FACING_CHUNK):  # the cosine to each camera, (N, chunk, 3) at a time
            c = cams[lo:lo + FACING_CHUNK]
            to_cam = C[c][None] - Xt[:, None, 0]
            cos[:, c] = np.sum(to_cam * normal[:, None], -1) / np.linalg.norm(to_cam, axis=-1)
        if body is not None and o.body_occlusion:
            occ = Occluders.of(body.at(frames.t_ms + dt), o.occluder_margin_cm)
            # only the cameras the normal faces are judged
            pi, k = np.nonzero(ties.above(cos[:, cams], o.min_cos_view, ties.VIEW_COSINE_QUANTUM))
            hidden[pi, cams[k]] = occluded_views(occ, Xt[:, 0], C, pi, cams[k], o.occlusion_stop_cm)
    facing = ties.above(cos, o.min_cos_view, ties.VIEW_COSINE_QUANTUM)  # (N, V) the normal faces the camera
    for v, name in enumerate(views.names):
        f = int(frames.frame[v])
        if f < 0 or N == 0:
            continue
        grid_all = moved[float(frames.offset_ms[v])]
        # only patches whose normal faces the camera can be candidates: the others are not projected (a dome's
        # camera faces a third of a patch's cameras; their NCC and the photometric baseline are left out there)
        rows = np.flatnonzero(facing[:, v])  # the hidden too: the photometric baseline judges them
        if len(rows) == 0:
            continue
        uv, inside = project_view_rows(views, v, grid_all, rows)
        got = sample(source.gray(name, f), uv[inside]) if inside.any() else np.zeros((0, G), np.float32)
        if o.border_squares and not inside.all():
            got, inside = _with_border_squares(views, v, source.gray(name, f), grid_all, rows, inside, got)
        in_image[rows, v] = inside
        if inside.any():
            blocks.append(got)
            row_of[rows[inside], v] = M + np.arange(len(blocks[-1]))
            row_n.append(rows[inside])
            row_v.append(np.full(len(blocks[-1]), v))
            M += len(blocks[-1])
    samples = np.concatenate(blocks) if blocks else np.zeros((0, G), np.float32)
    candidate = in_image & facing & ~hidden
    prev = previous & candidate
    score = np.where(prev, cos, np.where(candidate, cos - 2.0, -np.inf))
    ref, _ = ties.argmax_where(score, np.isfinite(score), ties.VIEW_COSINE_QUANTUM)  # ties by position
    has_ref = np.isfinite(score[np.arange(N), ref])
    # each row (a patch in the image of a camera) against its patch's reference row, every row centred once
    pi, vi = (np.concatenate(r) if r else np.zeros(0, np.int64) for r in (row_n, row_v))
    judge = has_ref[pi]
    pi, vi, rows_a = pi[judge], vi[judge], np.flatnonzero(judge)
    squares = Squares.of(samples)
    rows_b = row_of[pi, ref[pi]]
    corr = np.full((N, V), -1.0, np.float32)
    for lo in range(0, len(rows_a), NCC_CHUNK):  # the pairs' (chunk, G) blocks stay in the caches
        sl = slice(lo, lo + NCC_CHUNK)
        corr[pi[sl], vi[sl]] = squares.ncc(rows_a[sl], rows_b[sl])
    if o.neighbour_ncc:
        best = np.maximum(corr, neighbour_ncc(squares, row_of, prev, neighbours))
    else:
        best = corr
    best = np.where(in_image & has_ref[:, None], best, -1.0)
    tau = o.map_ncc_threshold if o.neighbour_ncc else o.ncc_threshold
    cost1 = o.photometric_weight * (tau - best) / (1.0 - tau)
    if motion_px is not None:
        r = np.where(np.isnan(motion_px), np.nan, np.minimum(motion_px / o.motion_sigma_px, 3.0))
        cost1 += np.where(np.isnan(r), 0.0, o.motion_weight * (r - 1.0))
    cost1 += o.geometric_weight * np.maximum(0.0, 0.5 - cos) / 0.5
    if hidden.any():
        # a hidden camera is a camera labelled "not visible" for certain: it stays in the prior, so each candidate
        # neighbour of it pays prior_weight for "visible" (its edge to a fixed 0 label), as it would in the graph
        facing_hidden = (hidden & in_image & facing).astype(np.float64)
        ends = np.concatenate([neighbours, neighbours[:, ::-1]])
        adjacent = csr_matrix((np.ones(len(ends)), (ends[:, 0], ends[:, 1])), shape=(V, V))
        pull = np.asarray(adjacent @ facing_hidden.T).T  # (N, V) each camera's hidden neighbours (small integers)
        cost1 = cost1 + o.prior_weight * np.where(candidate, pull, 0.0)
    node = np.full((N, V), -1, np.int64)
    pi, vi = np.nonzero(candidate)
    node[pi, vi] = np.arange(len(pi))
    pe, e = np.nonzero(candidate[:, neighbours[:, 0]] & candidate[:, neighbours[:, 1]])  # (N, E) pairs, by patch
    edges = np.stack([node[pe, neighbours[e, 0]], node[pe, neighbours[e, 1]]], 1)
    cost = np.stack([np.zeros(len(pi)), cost1[pi, vi]], 1)
    labels = min_cut_labels(cost, edges, np.full(len(edges), o.prior_weight))
    visible = np.zeros((N, V), bool)
    visible[pi, vi] = labels == 1
    # the CVPR 2014 baseline is the reference's NCC at ncc_threshold whatever rule the MAP term uses
    photometric = in_image & has_ref[:, None] & ties.at_least(corr, o.ncc_threshold, ties.NCC_QUANTUM)
    return Visibility(visible=visible, photometric=photometric, ncc=corr,
                      candidate=candidate, reference=ref, appearance=Appearance(samples=samples, row_of=row_of),
                      hidden=hidden)


def _with_border_squares(views: ViewSet, v: int, gray: np.ndarray, grid: np.ndarray, rows: np.ndarray,
                         inside: np.ndarray, got: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``border_squares``: the squares ``rows`` of camera ``v`` that cross its image border (``inside`` False) are
    taken too when their centre and at least :data:`MIN_BORDER_SAMPLES` of their samples are in the image; their
    samples outside are NaN. -> (samples of the taken rows in ``rows`` order, (R,) taken)."""
    cross = np.flatnonzero(~inside)
    # the centres first: most squares not wholly inside are wholly outside (a dome camera facing away from them)
    cross = cross[project_view(views, v, grid[rows[cross], CENTRE_SAMPLE])[1]]
    uv, seen = project_view(views, v, grid[rows[cross]].reshape(-1, 3))
    G = grid.shape[1]
    uv, seen = uv.reshape(len(cross), G, 2), seen.reshape(len(cross), G)
    take = seen[:, CENTRE_SAMPLE] & (seen.sum(1) >= MIN_BORDER_SAMPLES)
    if not take.any():
        return got, inside
    part = sample(gray, np.where(seen[take, :, None], uv[take], -100.0))
    part[~seen[take]] = np.nan
    taken = inside.copy()
    taken[cross[take]] = True
    out = np.empty((int(taken.sum()), G), np.float32)
    out[inside[taken]] = got
    out[~inside[taken]] = part
    return out, taken


def off_seed(now: Visibility, seed: Appearance, o: PatchOptions) -> np.ndarray:
    """(N,) bool: patches whose visible views no longer show their seed appearance: the median, over the cameras
    labelled visible now that also saw the patch at the seed, of the NCC of the square now against the square
    there at the seed (same camera: the viewpoint is alike, only the body moved), below ``seed_appearance_ncc``
    (None: ``ncc_threshold``). A patch with no such camera is not judged."""
    got = np.where(now.visible, now.appearance.ncc_against(seed), np.nan)
    judged = np.isfinite(got).any(axis=1)
    med = np.full(len(got), np.inf)
    if judged.any():
        med[judged] = np.nanmedian(got[judged], axis=1)
    tau = o.ncc_threshold if o.seed_appearance_ncc is None else o.seed_appearance_ncc
    return ties.below(med, tau, ties.NCC_QUANTUM)
