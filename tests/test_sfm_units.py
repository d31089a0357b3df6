"""Unit tests of the SfM front-end pieces: descriptor matching, pair selection, similarity alignment,
COLMAP camera conversion, executors."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dome_calib.bundle import Camera, CameraType
from dome_calib.panoptic_io import read_calibration
from dome_calib.rotation import rotvec_to_matrix
from projector.database import intrinsics_from_colmap, to_colmap_camera
from dome_calib.executor import Executor, SerialExecutor
from dome_calib.executor.local import LocalProcessExecutor
from projector.matching import match_descriptors
from projector.merge import chordal_mean, robust_similarity
from projector.pairs import (PairOptions, UnknownStrategy, expand_pairs_from_matches, pairs_exhaustive,
                             pairs_for_unknown, pairs_from_prior)

CALIB = "tests/data/panoptic/calibration_160906_band1.json"


@pytest.fixture(scope="module")
def panoptic() -> dict[str, Camera]:
    cams, _ = read_calibration(CALIB)
    return cams


def _sift_like(rng, n):
    d = rng.random((n, 128)) ** 3
    d /= d.sum(1, keepdims=True)
    return np.sqrt(d)  # L1-root: unit L2 norm


def test_match_descriptors_recovers_a_permutation_and_rejects_ambiguous():
    rng = np.random.default_rng(0)
    a = _sift_like(rng, 300)
    perm = rng.permutation(300)
    b = a[perm] + rng.normal(0, 0.005, (300, 128))
    m = match_descriptors(np.clip(np.round(a * 512), 0, 255).astype(np.uint8), b)
    assert len(m) > 290
    assert np.all(perm[m[:, 1]] == m[:, 0])
    # a duplicated descriptor in b makes its match ambiguous: the ratio test drops it
    b2 = np.concatenate([b, b[:1]])
    m2 = match_descriptors(a, b2)
    assert perm[0] not in m2[:, 0]
    assert len(match_descriptors(a[:1], b)) == 0
    top = match_descriptors(a, b, max_matches=50)
    assert len(top) == 50 and {tuple(r) for r in top} <= {tuple(r) for r in m2.tolist()} | {tuple(r) for r in m.tolist()}


def test_pairs_exhaustive_counts():
    names = [f"c{i:02d}" for i in range(12)]
    pairs = pairs_exhaustive(names)
    assert len(pairs) == 66 and all(a < b for a, b in pairs)


def test_pairs_from_prior_dome_is_sparse_and_keeps_every_camera(panoptic):
    names = sorted(panoptic)
    pairs = pairs_from_prior(panoptic, names, PairOptions())
    assert len(pairs) < 0.1 * len(names) * (len(names) - 1) / 2
    assert len(set(pairs)) == len(pairs) and all(a < b for a, b in pairs)
    degree = {n: 0 for n in names}
    for a, b in pairs:
        degree[a] += 1
        degree[b] += 1
    assert min(degree.values()) >= PairOptions().k_nearest
    # neighbours on the same panel are paired; cameras on opposite sides of the dome are not
    assert ("01_01", "01_02") in pairs
    far = max(names, key=lambda n: np.linalg.norm(panoptic[n].center_cm - panoptic["01_01"].center_cm))
    assert tuple(sorted(("01_01", far))) not in pairs


def test_unknown_cameras_get_fallback_pairs(panoptic):
    names = sorted(panoptic)[:100] + ["99_01"]
    ex = pairs_for_unknown(panoptic, names, PairOptions())
    assert len(ex) == 100 and all("99_01" in p for p in ex)
    opts = PairOptions(unknown_strategy=UnknownStrategy.SUBSET, unknown_subset_size=10)
    sub = pairs_for_unknown(panoptic, names, opts)
    assert len(sub) == 10
    prior_pairs = pairs_from_prior(panoptic, names, opts)
    partner = sub[0][0] if sub[0][1] == "99_01" else sub[0][1]
    extra = expand_pairs_from_matches(panoptic, names, {sub[0]: 500}, prior_pairs, opts)
    neighbours = {b if a == partner else a for a, b in prior_pairs if partner in (a, b)}
    assert {tuple(sorted(("99_01", n))) for n in neighbours} == set(extra)


def test_robust_similarity_recovers_transform_despite_outliers():
    rng = np.random.default_rng(1)
    names = [f"c{i}" for i in range(30)]
    src = {n: rng.normal(0, 1, 3) for n in names}
    R = rotvec_to_matrix(np.array([0.3, -0.2, 0.5]))
    s, t = 27.0, np.array([10.0, -140.0, 3.0])
    tgt = {n: s * R @ x + t for n, x in src.items()}
    src_R = {n: rotvec_to_matrix(rng.normal(0, 1, 3)) for n in names}
    tgt_R = {n: Rn @ R.T for n, Rn in src_R.items()}
    tgt["c0"] = tgt["c0"] + 50.0  # wrong centre
    tgt_R["c1"] = rotvec_to_matrix(np.array([0.0, 0.5, 0.0])) @ tgt_R["c1"]  # wrong orientation (29 deg)
    a = robust_similarity(src, tgt, 1.0, src_R, tgt_R, 5.0)
    assert abs(a.scale - s) < 1e-9 * s and np.allclose(a.rotation, R, atol=1e-9) and np.allclose(a.translation, t, atol=1e-7)
    assert "c0" not in a.inliers and "c1" not in a.inliers and len(a.inliers) == 28
    assert robust_similarity({"a": np.zeros(3)}, {"a": np.zeros(3)}, 1.0) is None


def test_chordal_mean_of_rotations():
    R = rotvec_to_matrix(np.array([0.1, 0.2, -0.3]))
    d = [rotvec_to_matrix(np.array(v)) for v in ([0.01, 0, 0], [-0.01, 0, 0], [0, 0.01, 0], [0, -0.01, 0])]
    M = chordal_mean([R @ x for x in d])
    assert np.allclose(M @ M.T, np.eye(3), atol=1e-12) and np.linalg.norm(M - R) < 1e-4


def test_colmap_camera_round_trip_and_pixel_offset(panoptic):
    cam = panoptic["01_01"]
    c = to_colmap_camera(cam)
    assert c.model_name == "FULL_OPENCV" and c.width == 640 and c.height == 480
    assert c.params[2] == pytest.approx(cam.K[0, 2] + 0.5) and c.params[3] == pytest.approx(cam.K[1, 2] + 0.5)
    K, dist = intrinsics_from_colmap(c)
    assert np.allclose(K, cam.K, atol=1e-12) and np.allclose(dist, cam.dist, atol=1e-15)
    # COLMAP's projection of a camera-frame point equals OpenCV's + 0.5 px
    import cv2

    X = np.array([[0.2, -0.1, 1.0], [-0.3, 0.25, 2.0]])
    uv_colmap = np.asarray(c.img_from_cam(X))
    uv_cv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    assert np.allclose(uv_colmap - 0.5, uv_cv[:, 0], atol=1e-6)


def _square(x: int) -> int:
    return x * x


def test_executors_give_the_same_results():
    items = list(range(20))
    serial = SerialExecutor()
    assert isinstance(serial, Executor)
    assert sorted(serial.map(_square, items)) == [i * i for i in items]
    assert serial.submit(_square, 7).result() == 49
    with LocalProcessExecutor(2, max_in_flight_per_worker=2) as pool:
        assert isinstance(pool, Executor)
        assert sorted(pool.map(_square, items)) == [i * i for i in items]
        assert pool.submit(_square, 9).result() == 81


def test_nominal_camera_types():
    from projector.features import nominal_camera

    hd = nominal_camera("00_03", (1920, 1080))
    vga = nominal_camera("05_07", (640, 480))
    assert hd.type == CameraType.HD and vga.type == CameraType.VGA
    assert 1300 < hd.K[0, 0] < 1700 and 700 < vga.K[0, 0] < 800


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_match_descriptors_do_not_depend_on_the_order_of_summation(seed):
    """Another BLAS kernel sums the descriptor products in another order: permuting the 128 dimensions does the
    same here. uint8 descriptors give exact products, so the matches (and their order) stay the same."""
    rng = np.random.default_rng(seed)
    a = np.clip(np.round(_sift_like(rng, 1500) * 512), 0, 255).astype(np.uint8)
    b = np.clip(np.round((a[rng.permutation(1500)] + rng.normal(0, 6, (1500, 128)))), 0, 255).astype(np.uint8)
    perm = rng.permutation(128)
    m = match_descriptors(a, b, max_matches=400)
    assert len(m) == 400
    assert np.array_equal(m, match_descriptors(a[:, perm], b[:, perm], max_matches=400))


def test_match_descriptors_match_each_keypoint_once_when_rows_tie():
    """Two identical descriptors in the first image tie exactly as the nearest of one in the second: one match."""
    rng = np.random.default_rng(3)
    a = np.clip(np.round(_sift_like(rng, 200) * 512), 0, 255).astype(np.uint8)
    b = a[rng.permutation(200)].copy()
    a[7] = a[3]
    m = match_descriptors(a, b, max_ratio=1.01)  # the ratio test would not drop row 3 or 7: they are not ambiguous
    assert len(np.unique(m[:, 1])) == len(m) and len(np.unique(m[:, 0])) == len(m)
    assert 3 in m[:, 0] and 7 not in m[:, 0]
