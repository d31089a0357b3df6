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

A panel that moved as a whole keeps the relative poses of its cameras: their pairs with each other stay good,
and most of a VGA camera's partners are on its own panel (a median 3 of its ~13 first-round pairs leave it on
the full dome), so no single camera looks changed. Rigid groups (``group_of``: the VGA panels) are therefore
candidates of the same greedy too, scored by their pairs that leave the group; a flagged group flags all of its
cameras, each then confirmed or cleared by the re-estimation.
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
MIN_GROUP_PAIRS = 5  # a rigid group is judged on at least this many pairs leaving it


@dataclass(kw_only=True)
class Consistency:
    """Per-pair median Sampson distance (px) under the prior, and the verdict per camera.

    changed: camera -> (fraction of bad pairs when it was flagged, number of those pairs); a camera flagged with
    its group carries the group's.
    A flag is a suspicion (an unchanged camera whose partners nearly all changed can be flagged): the quick
    recalibration re-estimates flagged cameras and keeps as changed only those the new pose explains better.
    """

    bad_pair_px: float = 0.0
    pair_error_px: dict[Pair, float] = field(default_factory=dict)
    changed: dict[str, tuple[float, int]] = field(default_factory=dict)
    unchecked: list[str] = field(default_factory=list)  # cameras with no usable pair
    changed_groups: dict[int, tuple[float, int]] = field(default_factory=dict)  # rigid groups flagged as a whole


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
                    max_bad_fraction: float = MAX_BAD_FRACTION,
                    group_of: Mapping[str, int] | None = None) -> Consistency:
    """Greedy verdict (module docstring): flag the candidate with the largest fraction of bad pairs among its
    pairs with unflagged cameras while that fraction exceeds ``max_bad_fraction``. Candidates are the cameras and
    the rigid groups of ``group_of`` (camera -> group; a group is scored on its pairs that leave it, and needs
    MIN_GROUP_PAIRS of them). Equal scores: the larger count of bad pairs, then cameras before groups, then the
    first name (for groups the lowest). ``bad_px`` default: :func:`bad_pair_threshold_px`."""
    bad_px = bad_pair_threshold_px(pair_error_px) if bad_px is None else bad_px
    group_of = group_of or {}
    partners: dict[str, dict[str, bool]] = {}
    for (a, b), e in pair_error_px.items():
        partners.setdefault(a, {})[b] = e > bad_px
        partners.setdefault(b, {})[a] = e > bad_px
    members: dict[int, list[str]] = {}
    for cam in sorted(partners):
        if cam in group_of:
            members.setdefault(group_of[cam], []).append(cam)
    flagged: dict[str, tuple[float, int]] = {}
    flagged_groups: dict[int, tuple[float, int]] = {}

    def score(live: list[bool], minimum: int) -> tuple[float, int] | None:
        n_bad = sum(live)
        if len(live) < minimum or n_bad / len(live) <= max_bad_fraction:
            return None
        return n_bad / len(live), n_bad

    while True:
        best, best_key = None, (0.0, 0, 0)
        for cam, p in sorted(partners.items()):  # equal scores: the first name wins, whatever the input order
            if cam in flagged:
                continue
            key = score([bad for other, bad in p.items() if other not in flagged], 1)
            if key is not None and key + (1,) > best_key:
                best, best_key = cam, key + (1,)
        for group, cams in sorted(members.items()):
            todo = [c for c in cams if c not in flagged]
            if len(todo) < 2:
                continue
            live = [bad for c in todo for other, bad in partners[c].items()
                    if other not in flagged and group_of.get(other) != group]
            key = score(live, MIN_GROUP_PAIRS)
            if key is not None and key + (0,) > best_key:
                best, best_key = group, key + (0,)
        if best is None:
            break
        if best_key[2] == 1:
            flagged[best] = best_key[:2]
        else:
            flagged_groups[best] = best_key[:2]
            for c in members[best]:
                flagged.setdefault(c, best_key[:2])
    unchecked = sorted(c for c, p in partners.items()
                       if c not in flagged and not any(o not in flagged for o in p))
    return Consistency(pair_error_px=dict(pair_error_px), changed=flagged, unchecked=unchecked, bad_pair_px=bad_px,
                       changed_groups=flagged_groups)
