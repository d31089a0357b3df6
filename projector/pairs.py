"""Pair selection: which image pairs of a scene to match.

* :func:`pairs_exhaustive` - every pair (small captures: N (N - 1) / 2 pairs).
* :func:`pairs_from_prior` - for the dome: pair cameras whose views overlap on the tent according to a prior
  calibration (a previous bundle or the nominal layout). Surface samples (points on spheres around the tent
  region, each with an outward normal) are projected into every camera; a sample counts as seen when it is
  inside the image and faces the camera. Cameras sharing enough samples, with viewing directions close enough
  for SIFT to match, are paired; each camera keeps its best ``max_pairs_per_camera`` partners by shared
  samples, plus its ``k_nearest`` cameras by viewing direction (so no camera is left without pairs).
* cameras the prior does not know get :func:`pairs_for_unknown`: exhaustive against every other camera, or
  (``UnknownStrategy.SUBSET``) against a spread subset first, then :func:`expand_pairs_from_matches` adds the
  prior neighbours of the cameras they actually matched (retrieval by matching, no vocabulary tree).

Pairs are ``(name_a, name_b)`` tuples with ``name_a < name_b``, sorted.
"""
from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping

from enum import StrEnum
from typing import Annotated

import numpy as np

from dome_calib.bundle import Camera
from dome_calib.camera import project
from dome_calib.ties import LENGTH_QUANTUM_CM, UNIT_QUANTUM, argmax_first, quantize
from dome_calib.options import AtLeast, Field, Lax, options
from dome_calib.schema import Finite, PosFinite

Pair = tuple[str, str]


class UnknownStrategy(StrEnum):
    EXHAUSTIVE = "exhaustive"  # match an unknown camera against all others
    SUBSET = "subset"  # match against a spread subset, then expand around the matches


@options
class PairOptions:
    """Options of prior-based pair selection (lengths in cm, angles in degrees)."""

    exhaustive_below: AtLeast(0) = 30  # scenes with at most this many images are matched exhaustively
    region_center_cm: tuple[Finite, Finite, Finite] | None = None  # None: where the optical axes meet
    region_radii_cm: Annotated[tuple[PosFinite, ...], Field(min_length=1)] = (40.0, 80.0, 120.0)  # sample spheres around the region centre
    samples_per_sphere: AtLeast(1) = 1500
    max_incidence_deg: Annotated[float, Field(gt=0, le=180)] = 80.0  # a sample is seen only if its normal faces the camera within this angle
    max_view_angle_deg: Annotated[float, Field(gt=0, le=180)] = 60.0  # paired cameras see the region from directions at most this far apart
    min_shared_samples: AtLeast(0) = 20
    max_pairs_per_camera: AtLeast(0) = 25
    k_nearest: AtLeast(0) = 6
    unknown_strategy: Annotated[UnknownStrategy, Lax] = UnknownStrategy.EXHAUSTIVE
    unknown_subset_size: AtLeast(1) = 40
    expand_top_matches: AtLeast(0) = 3  # SUBSET: partners taken from the best verified matches of an unknown camera


def _sorted_pair(a: str, b: str) -> Pair:
    return (a, b) if a < b else (b, a)


def pairs_exhaustive(names: Iterable[str]) -> list[Pair]:
    """Every unordered pair of ``names``."""
    return sorted(_sorted_pair(a, b) for a, b in itertools.combinations(sorted(set(names)), 2))


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere."""
    k = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * k / n)
    theta = np.pi * (1.0 + 5**0.5) * k
    return np.stack([np.cos(theta) * np.sin(phi), np.cos(phi), np.sin(theta) * np.sin(phi)], axis=1)


def optical_axes_meeting_point_cm(cameras: Mapping[str, Camera]) -> np.ndarray:
    """(3,) least-squares point closest to every camera's optical axis (the dome's aim point)."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras.values():
        d = cam.R[2]  # optical axis in the world frame
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.center_cm
    return np.linalg.lstsq(A, b, rcond=None)[0]


def visibility(cameras: Mapping[str, Camera], names: list[str], options: PairOptions) -> tuple[np.ndarray, np.ndarray]:
    """(C, S) bool: sample s seen by camera c; and (C, 3) unit directions from the region centre to each camera."""
    centre = (np.asarray(options.region_center_cm, float) if options.region_center_cm is not None
              else optical_axes_meeting_point_cm({n: cameras[n] for n in names}))
    normals = fibonacci_sphere(options.samples_per_sphere)
    X = np.concatenate([centre + r * normals for r in options.region_radii_cm])
    N = np.concatenate([normals for _ in options.region_radii_cm])
    st = {n: cameras[n] for n in names}
    R = np.stack([c.R for c in st.values()])
    t = np.stack([c.t_cm for c in st.values()])
    proj = project(X, R, t, np.stack([c.intr for c in st.values()]), np.stack([c.dist for c in st.values()]))
    seen = proj.in_image(np.array([c.resolution for c in st.values()]))
    C = np.stack([c.center_cm for c in st.values()])
    to_cam = C[:, None, :] - X[None]
    to_cam /= np.linalg.norm(to_cam, axis=-1, keepdims=True)
    seen &= np.einsum("csk,sk->cs", to_cam, N) > np.cos(np.radians(options.max_incidence_deg))
    dirs = C - centre
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return seen, dirs


def pairs_from_prior(cameras: Mapping[str, Camera], names: Iterable[str], options: PairOptions | None = None) -> list[Pair]:
    """Candidate pairs among ``names`` from the prior ``cameras`` (names missing from the prior are skipped:
    give them :func:`pairs_for_unknown`). Scenes with at most ``exhaustive_below`` images: all known pairs."""
    options = options or PairOptions()
    known = sorted(n for n in set(names) if n in cameras)
    if len(known) < 2:
        return []
    if len(known) <= options.exhaustive_below:
        return pairs_exhaustive(known)
    seen, dirs = visibility(cameras, known, options)
    v = seen.astype(np.float64)
    # (C, C) samples seen by both. A float product goes through BLAS (~100x faster than numpy's integer matmul)
    # and is still exact: sums of 0/1 products stay far below 2**53 in any summation order
    shared = (v @ v.T).astype(np.int64)
    # cosines quantised: cameras at one angle by design compare equal on every machine, then go by name
    cos_q = quantize(dirs @ dirs.T, UNIT_QUANTUM)
    score = np.where(cos_q >= quantize(np.cos(np.radians(options.max_view_angle_deg)), UNIT_QUANTUM), shared, 0)
    np.fill_diagonal(score, 0)
    score[score < options.min_shared_samples] = 0
    angle_order = np.argsort(-cos_q, axis=1, kind="stable")  # `known` is in name order
    pairs: set[Pair] = set()
    for i, name in enumerate(known):
        best = np.argsort(-score[i], kind="stable")[: options.max_pairs_per_camera]
        pairs.update(_sorted_pair(name, known[j]) for j in best if score[i, j] > 0)
        nearest = [j for j in angle_order[i] if j != i][: options.k_nearest]
        pairs.update(_sorted_pair(name, known[j]) for j in nearest)
    return sorted(pairs)


def spread_subset(cameras: Mapping[str, Camera], names: list[str], k: int) -> list[str]:
    """``k`` names spread over viewing directions (farthest-point sampling on camera centres), deterministic:
    distances are compared to 1 um, equal ones by the order of ``names``."""
    if len(names) <= k:
        return list(names)
    C = np.stack([cameras[n].center_cm for n in names])
    chosen = [0]
    d = np.linalg.norm(C - C[0], axis=1)
    while len(chosen) < k:
        j = argmax_first(d, LENGTH_QUANTUM_CM)
        chosen.append(j)
        d = np.minimum(d, np.linalg.norm(C - C[j], axis=1))
    return [names[j] for j in sorted(chosen)]


def pairs_for_unknown(cameras: Mapping[str, Camera], names: Iterable[str], options: PairOptions | None = None) -> list[Pair]:
    """Pairs for the cameras of ``names`` that the prior does not know (first round of the fallback)."""
    options = options or PairOptions()
    names = sorted(set(names))
    unknown = [n for n in names if n not in cameras]
    known = [n for n in names if n in cameras]
    pairs: set[Pair] = set()
    if options.unknown_strategy == UnknownStrategy.EXHAUSTIVE or len(known) <= options.unknown_subset_size:
        partners = names
    else:
        partners = spread_subset(cameras, known, options.unknown_subset_size) + unknown
    for u in unknown:
        pairs.update(_sorted_pair(u, p) for p in partners if p != u)
    return sorted(pairs)


def expand_pairs_from_matches(
    cameras: Mapping[str, Camera], names: Iterable[str], verified_inliers: Mapping[Pair, int],
    prior_pairs: Iterable[Pair], options: PairOptions | None = None,
) -> list[Pair]:
    """Second round of the SUBSET fallback: for each unknown camera, pair it with the prior neighbours of the
    known cameras it matched best (``verified_inliers``: pair -> inlier count of the first round).
    Returns only pairs not matched yet."""
    options = options or PairOptions()
    neighbours: dict[str, set[str]] = {}
    for a, b in prior_pairs:
        neighbours.setdefault(a, set()).add(b)
        neighbours.setdefault(b, set()).add(a)
    unknown = [n for n in set(names) if n not in cameras]
    new: set[Pair] = set()
    for u in unknown:
        scored = sorted(((n, (a if b == u else b)) for (a, b), n in verified_inliers.items() if u in (a, b)
                         and (a if b == u else b) in cameras), reverse=True)
        for _, partner in scored[: options.expand_top_matches]:
            new.update(_sorted_pair(u, m) for m in neighbours.get(partner, ()) | {partner} if m != u)
    return sorted(new - set(verified_inliers))
