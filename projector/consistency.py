"""Which cameras no longer agree with a previous calibration: epipolar consistency of a scene's verified pairs.

For every verified pair of a scene database, the inlier matches are undistorted with the PRIOR's lenses and
tested against the PRIOR's relative pose: the Sampson distance to the epipolar line, in pixels (normalised
distance times the mean focal length of the pair). No reconstruction is needed, and the scene's tent can be
anywhere. A pair of unchanged cameras scores the feature noise (a few tenths of a pixel); a pair with a camera
that turned 1 deg scores ~10 px on a VGA camera, a 2 cm shift ~1-4 px, a 4 % focal change a few px at the edge.

:func:`changed_cameras` turns pair scores into camera verdicts: a camera is changed when most of its pairs are
bad. A pair is bad when either camera changed, so an unchanged camera beside a disturbed panel has bad pairs
too; the cameras are therefore flagged greedily, worst first (the largest fraction of bad pairs among the
partners not flagged yet), and each flag removes that camera's pairs from its partners' counts. Every changed
camera has all of its pairs bad; after they are flagged, their unchanged neighbours are left with good pairs.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pycolmap

from dome_calib.bundle import Camera
from dome_calib.camera import colmap_to_opencv_px, pixels_to_normalized
from projector.database import camera_of_image
from projector.pairs import Pair

#: A pair disagrees with the prior when its median Sampson distance exceeds NOISE_FACTOR times the median over
#: all pairs (most pairs are of unchanged cameras: that median is the feature noise), kept inside the bounds.
NOISE_FACTOR = 6.0
BAD_PAIR_PX_BOUNDS = (0.3, 2.0)
MAX_BAD_FRACTION = 0.5  # a camera with more than this fraction of bad pairs (among unflagged partners) changed
MIN_PAIR_MATCHES = 20


@dataclass(kw_only=True)
class Consistency:
    """Per-pair median Sampson distance (px) under the prior, and the verdict per camera.

    changed: camera -> (fraction of bad pairs when it was flagged, number of those pairs).
    A flag is a suspicion (an unchanged camera whose partners nearly all changed can be flagged): the quick
    recalibration re-estimates flagged cameras and keeps as changed only those the new pose explains better.
    """

    bad_pair_px: float = 0.0
    pair_error_px: dict[Pair, float] = field(default_factory=dict)
    changed: dict[str, tuple[float, int]] = field(default_factory=dict)
    unchecked: list[str] = field(default_factory=list)  # cameras with no usable pair


def _sampson_px(x1: np.ndarray, x2: np.ndarray, a: Camera, b: Camera) -> np.ndarray:
    """(N,) Sampson distance in px of normalised correspondences x1 (in a) <-> x2 (in b) under the poses."""
    R = b.R @ a.R.T
    t = b.t_cm - R @ a.t_cm
    t = t / max(np.linalg.norm(t), 1e-12)
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    Ex1 = h1 @ E.T
    Etx2 = h2 @ E
    num = np.einsum("ij,ij->i", h2, Ex1)
    den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    focal = 0.25 * (a.K[0, 0] + a.K[1, 1] + b.K[0, 0] + b.K[1, 1])
    return focal * np.abs(num) / np.sqrt(np.maximum(den, 1e-300))


def pair_errors(database_path: str | Path, prior: Mapping[str, Camera]) -> dict[Pair, float]:
    """Median Sampson distance (px) under ``prior`` of every verified pair of two cameras the prior knows."""
    out: dict[Pair, float] = {}
    with pycolmap.Database.open(str(database_path)) as db:
        names = {im.image_id: camera_of_image(im.name) for im in db.read_all_images()}
        normalized: dict[int, np.ndarray] = {}

        def xn(image_id: int) -> np.ndarray:
            if image_id not in normalized:
                cam = prior[names[image_id]]
                uv = colmap_to_opencv_px(np.asarray(db.read_keypoints(image_id)[:, :2], float))
                normalized[image_id] = pixels_to_normalized(uv, cam.intr, cam.dist)
            return normalized[image_id]

        pair_ids, geometries = db.read_two_view_geometries()
        for pid, tvg in zip(pair_ids, geometries):
            ia, ib = pycolmap.pair_id_to_image_pair(pid)
            na, nb = names.get(ia), names.get(ib)
            m = np.asarray(tvg.inlier_matches)
            if na not in prior or nb not in prior or len(m) < MIN_PAIR_MATCHES:
                continue
            err = _sampson_px(xn(ia)[m[:, 0]], xn(ib)[m[:, 1]], prior[na], prior[nb])
            key = (na, nb) if na < nb else (nb, na)
            out[key] = float(np.median(err))
    return out


def bad_pair_threshold_px(pair_error_px: Mapping[Pair, float]) -> float:
    """The Sampson distance (px) above which a pair disagrees with the prior (see NOISE_FACTOR)."""
    lo, hi = BAD_PAIR_PX_BOUNDS
    if not pair_error_px:
        return hi
    return float(np.clip(NOISE_FACTOR * np.median(list(pair_error_px.values())), lo, hi))


def changed_cameras(pair_error_px: Mapping[Pair, float], *, bad_px: float | None = None,
                    max_bad_fraction: float = MAX_BAD_FRACTION) -> Consistency:
    """Greedy verdict (module docstring): flag the camera with the largest fraction of bad pairs among its
    unflagged partners while that fraction exceeds ``max_bad_fraction``. ``bad_px`` default:
    :func:`bad_pair_threshold_px`."""
    bad_px = bad_pair_threshold_px(pair_error_px) if bad_px is None else bad_px
    partners: dict[str, dict[str, bool]] = {}
    for (a, b), e in pair_error_px.items():
        partners.setdefault(a, {})[b] = e > bad_px
        partners.setdefault(b, {})[a] = e > bad_px
    flagged: dict[str, tuple[float, int]] = {}
    while True:
        best, best_key = None, (0.0, 0)
        for cam, p in sorted(partners.items()):  # equal fractions: the first name wins, whatever the input order
            if cam in flagged:
                continue
            live = [bad for other, bad in p.items() if other not in flagged]
            n_bad = sum(live)
            if not live or n_bad / len(live) <= max_bad_fraction:
                continue
            key = (n_bad / len(live), n_bad)
            if key > best_key:
                best, best_key = cam, key
        if best is None:
            break
        flagged[best] = best_key
    unchecked = sorted(c for c, p in partners.items()
                       if c not in flagged and not any(o not in flagged for o in p))
    return Consistency(pair_error_px=dict(pair_error_px), changed=flagged, unchecked=unchecked, bad_pair_px=bad_px)
