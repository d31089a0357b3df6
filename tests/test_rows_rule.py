"""However the work is cut, the same bits, under OpenBLAS's threads (dome_calib.rows): a product whose rows are
items gives each row the same bits alone, in a batch of 7 and in the whole, at 1 and 2 OpenBLAS threads; and so do
the places built on it (a point's camera-frame coordinates and pixels, its DLT triangulation) and the people stage
read one time at a time against all at once. On main (before 8a56f60 and dome_calib.rows) a BLAS product's rows
changed their last bits with the batch's size: one row is gemv, a few rows the gemm kernel's tail."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dome_calib.ba.blas import blas_threads
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people
from dome_calib.recon.people.sources import people_streams
from dome_calib.recon.people.temporal import TemporalOptions
from dome_calib.recon.project import project_points, project_view, project_view_rows, transform_points, view_set
from dome_calib.recon.triangulate import triangulate, triangulate_dlt
from dome_calib.rows import rows_product

from .people_helpers import group_detections
from .recon_helpers import dome_points, real_bundle

THREADS = (1, 2)
CUTS = (1, 7, None)  # a row alone, batches of 7, the whole


def _cut(f, n: int, size: int | None) -> np.ndarray:
    """``f(rows)`` over the rows 0..n-1 in batches of ``size`` (None: all at once), concatenated."""
    size = size or n
    return np.concatenate([f(np.arange(k, min(k + size, n))) for k in range(0, n, size)])


def _alike(f, n: int) -> np.ndarray:
    """``f``'s rows under every cut and thread count: the same bits; returns them."""
    ref = None
    for threads in THREADS:
        with blas_threads(threads):
            for size in CUTS:
                got = _cut(f, n, size)
                if ref is None:
                    ref = got
                assert np.array_equal(got, ref, equal_nan=True), (threads, size)
    return ref


@pytest.fixture(scope="module")
def views():
    return view_set(real_bundle(kinect=False, sync=False, n_vga=31))


def test_rows_product_is_the_product_and_a_row_is_alike_in_any_batch():
    rng = np.random.default_rng(0)
    for K, N in ((3, 93), (124, 16), (3, 1)):
        A, B = rng.normal(size=(300, K)) * 37.1, rng.normal(size=(K, N))
        got = _alike(lambda r: rows_product(A[r], B), len(A))
        np.testing.assert_allclose(got, A @ B, rtol=0, atol=1e-12 * np.abs(A).max() * np.abs(B).max() * K)
    assert rows_product(np.zeros((4, 0)), np.zeros((0, 2))).shape == (4, 2)


def test_a_points_camera_coordinates_and_pixels_are_alike_in_any_batch(views):
    X = dome_points(100, seed=3)
    _alike(lambda r: transform_points(views, X[r]).reshape(len(r), -1), len(X))
    _alike(lambda r: project_points(views, X[r]).uv_px.transpose(1, 0, 2).reshape(len(r), -1), len(X))
    for v in (0, 17):  # one view: the bits of project_points' row, and of the squares' explicit products
        uv = _alike(lambda r: project_view(views, v, X[r])[0], len(X))
        assert np.array_equal(uv, project_points(views, X).uv_px[v], equal_nan=True)
        rows_uv, _ = project_view_rows(views, v, X[:, None], np.arange(len(X)))
        seen = project_view(views, v, X)[1]
        assert np.array_equal(rows_uv[seen, 0], uv[seen])


def test_a_points_dlt_triangulation_is_alike_in_any_batch(views):
    X = dome_points(120, seed=5)
    p = project_points(views, X)
    xn = np.stack([(p.uv_px[..., 0] - views.intr[:, 2:3]) / views.intr[:, 0:1],
                   (p.uv_px[..., 1] - views.intr[:, 3:4]) / views.intr[:, 1:2]], -1).transpose(1, 0, 2)
    w = np.where(p.visible.T, np.random.default_rng(5).uniform(0.3, 1.0, p.visible.T.shape), 0.0)
    xn = np.where(p.visible.T[..., None], xn, 0.0)
    _alike(lambda r: triangulate_dlt(views, xn[r], w[r]), len(X))
    sub = views.subset(views.names[::5])  # and the whole triangulation: RANSAC, each point's few views, refinement
    p = project_points(sub, X)
    uv, conf = p.uv_px.transpose(1, 0, 2), np.where(p.visible.T, 0.8, 0.0)
    conf[:40, 4:] = 0.0
    _alike(lambda r: triangulate(sub, uv[r], conf[r]).X_cm, len(X))
    _alike(lambda r: triangulate(sub, uv[r], conf[r], few_views=4).X_cm, 40)  # each point's own 4 views


def test_the_people_stage_read_one_time_at_a_time_is_the_whole_to_the_last_bit():
    bundle = real_bundle(kinect=False, n_vga=24, start_ms=1000.0, duration_ms=300.0, seed=4)
    cams = sorted(n for n, c in bundle.cameras.items() if c.type in ("vga", "hd"))
    people, _ = group_detections(bundle, cams, 2, seed=5)
    views, streams = view_set(bundle, cams), people_streams(bundle, people)
    times = bundle.sync.streams["vga"].univ_time_ms[1:-1]
    options = PeopleOptions(temporal=TemporalOptions(enabled=False))
    runs = []
    for threads in THREADS:
        with blas_threads(threads):
            for batch in (1, 2, len(times)):
                runs.append(reconstruct_people(views, streams, times, dataclasses.replace(options, batch_times=batch)))
    first = runs[0]
    assert sum(len(b.ids) for b in first.bodies) >= len(times)
    for other in runs[1:]:
        for a, b in zip(first.bodies, other.bodies):
            np.testing.assert_array_equal(a.ids, b.ids)
            np.testing.assert_array_equal(a.X_cm, b.X_cm)
